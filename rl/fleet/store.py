"""Reading fleets back from the workspace: `fleets/<fleet_id>/fleet.json` and its runs.

A fleet (`laneprint train --drivers all|IDS | --styles all [--seeds N]`) trains one
agent per (target, seed) in one process. The trainer writes, atomically:

- ``fleets/<fleet_id>/fleet.json``: ``fleet_id``, ``created_at``, ``targets`` (list of
  ``{"kind": "driver"|"style", "name": ...}``), ``seeds``, ``runs`` (run ids),
  ``backend`` ('local'|'ray'), ``state`` ('created'|'running'|'done'|'failed'|'cancelled'),
  ``pid``, ``updated_at``, ``message``;
- for each run, an ordinary run folder ``runs/<run_id>/`` (see `rl.runs`), whose
  config.json also names the ``fleet_id``.

This module only reads (no torch, no streamlit): what the dashboard's fleet views
and `laneprint` summaries show. A fleet or run left 'running' by a process that is
gone reads as 'interrupted'; a run listed in fleet.json that has no folder yet
reads as 'pending'.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from laneprint.errors import UserError
from laneprint.processes import laneprint_process_alive
from laneprint.workspace import Workspace

FLEET_STATES = ("created", "running", "done", "failed", "cancelled", "interrupted")
ACTIVE_FLEET_STATES = ("created", "running")
POLICIES = ("agent", "greedy", "imitation")
#: An agent meets its target when its recall is at least this (fraction) ...
TARGET_RECALL = 0.95
#: ... and its balanced accuracy beats the greedy benchmark's by at least this (fraction).
TARGET_BA_MARGIN = 0.05

FLEETS_COLUMNS = [
    "fleet_id",
    "created_at",
    "targets",
    "n_targets",
    "n_seeds",
    "n_runs",
    "n_done",
    "n_evaluated",
    "state",
    "backend",
    "updated_at",
    "message",
]
TABLE_COLUMNS = (
    ["run_id", "target_kind", "target", "seed", "state", "episode", "episodes"]
    + [f"{who}_{m}" for m in ("balanced_accuracy", "recall") for who in POLICIES]
    + ["agent_minus_greedy", "meets_target", "timing_mae_s"]
)


def fleet_dir(workspace: Workspace) -> Path:
    """`<workspace>/fleets`: one folder per fleet."""
    return workspace.root / "fleets"


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        out = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return out if isinstance(out, dict) else None


def fleet_state(fleet: dict[str, Any]) -> str:
    """The fleet's state as a reader should see it: 'created' (runs set up, training not begun) or
    'running' only while its process lives, else 'interrupted'."""
    state = str(fleet.get("state") or "running")
    if state in ACTIVE_FLEET_STATES and not laneprint_process_alive(fleet.get("pid")):
        return "interrupted"
    return state


def targets_summary(targets: list[dict[str, Any]]) -> str:
    """'100 drivers', '3 styles', 'drivers D01, D02' or '2 drivers, 1 style'."""
    kinds: dict[str, list[str]] = {}
    for t in targets:
        kinds.setdefault(str(t.get("kind")), []).append(str(t.get("name")))
    parts = []
    for kind, names in kinds.items():
        plural = kind + ("s" if len(names) != 1 else "")
        parts.append(
            f"{plural} {', '.join(names)}" if len(kinds) == 1 and len(names) <= 3 else f"{len(names)} {plural}"
        )
    return ", ".join(parts) or "no targets"


def load_fleet(workspace: Workspace, fleet_id: str) -> dict[str, Any]:
    """fleet.json plus `state_read` (the state as seen now), `folder`, `n_runs`."""
    folder = fleet_dir(workspace) / fleet_id
    fleet = _read_json(folder / "fleet.json")
    if fleet is None:
        raise UserError(f"no fleet {fleet_id!r} in {workspace.root} (no fleets/{fleet_id}/fleet.json)")
    return {**fleet, "state_read": fleet_state(fleet), "folder": folder, "n_runs": len(fleet.get("runs") or [])}


def _run_files(workspace: Workspace, run_id: str) -> tuple[dict | None, dict | None, dict | None]:
    folder = workspace.runs_dir / run_id
    return (
        _read_json(folder / "config.json"),
        _read_json(folder / "status.json"),
        _read_json(folder / "evaluation.json"),
    )


def _run_state(config: dict | None, status: dict | None, fleet_alive: bool) -> str:
    if config is None and status is None:
        return "pending" if fleet_alive else "not started"
    state = str((status or {}).get("state") or "pending")
    if state == "running" and not fleet_alive and not laneprint_process_alive((status or {}).get("pid")):
        return "interrupted"
    return state


def _summary_rows(evaluation: dict | None) -> dict[str, dict[str, Any]]:
    return {str(r.get("who")): r for r in (evaluation or {}).get("summary") or [] if isinstance(r, dict)}


def _number(row: dict | None, key: str) -> float:
    v = (row or {}).get(key)
    try:
        return float(v) if v is not None else np.nan
    except (TypeError, ValueError):
        return np.nan


def meets_target(recall: float, balanced_accuracy: float, greedy_balanced_accuracy: float) -> bool:
    """The fleet's target: recall >= 95 % and balanced accuracy >= greedy's + 5 points (NaN: not met)."""
    return bool(recall >= TARGET_RECALL and balanced_accuracy >= greedy_balanced_accuracy + TARGET_BA_MARGIN - 1e-12)


def fleet_table(workspace: Workspace, fleet_id: str) -> pd.DataFrame:
    """One row per agent of the fleet, in fleet.json's order.

    Columns: run_id, target_kind, target, seed, state, episode, episodes, then
    `<who>_balanced_accuracy` and `<who>_recall` for agent, greedy and imitation
    (fractions, NaN until evaluated), `agent_minus_greedy` (balanced accuracy,
    fraction), `meets_target` (None until evaluated) and the agent's `timing_mae_s` [s].
    """
    fleet = load_fleet(workspace, fleet_id)
    alive = fleet["state_read"] in ACTIVE_FLEET_STATES
    rows = []
    for run_id in fleet.get("runs") or []:
        config, status, evaluation = _run_files(workspace, str(run_id))
        target = (config or {}).get("target") or {}
        by = _summary_rows(evaluation)
        row: dict[str, Any] = {
            "run_id": str(run_id),
            "target_kind": target.get("kind"),
            "target": target.get("name"),
            "seed": (config or {}).get("seed"),
            "state": _run_state(config, status, alive),
            "episode": (status or {}).get("episode", 0),
            "episodes": (status or {}).get("episodes", ((config or {}).get("dqn") or {}).get("episodes")),
        }
        for m in ("balanced_accuracy", "recall"):
            for who in POLICIES:
                row[f"{who}_{m}"] = _number(by.get(who), m)
        row["agent_minus_greedy"] = row["agent_balanced_accuracy"] - row["greedy_balanced_accuracy"]
        row["meets_target"] = (
            meets_target(row["agent_recall"], row["agent_balanced_accuracy"], row["greedy_balanced_accuracy"])
            if "agent" in by
            else None
        )
        row["timing_mae_s"] = _number(by.get("agent"), "timing_mae_s")
        rows.append(row)
    table = pd.DataFrame(rows, columns=TABLE_COLUMNS)
    for col in ("episode", "episodes"):
        table[col] = pd.to_numeric(table[col], errors="coerce").fillna(0).astype(int)
    return table


def fleet_progress(table: pd.DataFrame) -> dict[str, int]:
    """Agents finished (done, evaluated) and episodes summed over the runs' status.json."""
    return {
        "n_runs": len(table),
        "n_done": int((table["state"] == "done").sum()),
        "n_evaluated": int(table["agent_balanced_accuracy"].notna().sum()),
        "n_meeting_target": int((table["meets_target"] == True).sum()),  # noqa: E712 (None: not yet)
        "episode": int(table["episode"].sum()),
        "episodes": int(table["episodes"].sum()),
    }


def fleet_ids(workspace: Workspace) -> list[str]:
    """Fleets with a fleet.json, newest first (by created_at, then id)."""
    found = []
    root = fleet_dir(workspace)
    for path in root.glob("*/fleet.json") if root.exists() else []:
        fleet = _read_json(path) or {}
        found.append((str(fleet.get("created_at") or ""), path.parent.name))
    return [fid for _, fid in sorted(found, reverse=True)]


def list_fleets(workspace: Workspace) -> pd.DataFrame:
    """One row per fleet, newest first: id, created, targets summary, runs, runs done and evaluated, state."""
    rows = []
    for fid in fleet_ids(workspace):
        try:
            fleet = load_fleet(workspace, fid)
        except UserError:  # removed while listing
            continue
        done = evaluated = 0
        for run_id in fleet.get("runs") or []:
            folder = workspace.runs_dir / str(run_id)
            done += (_read_json(folder / "status.json") or {}).get("state") == "done"
            evaluated += (folder / "evaluation.json").exists()
        targets = fleet.get("targets") or []
        rows.append(
            {
                "fleet_id": fid,
                "created_at": fleet.get("created_at"),
                "targets": targets_summary(targets),
                "n_targets": len(targets),
                "n_seeds": len(fleet.get("seeds") or []),
                "n_runs": fleet["n_runs"],
                "n_done": done,
                "n_evaluated": evaluated,
                "state": fleet["state_read"],
                "backend": fleet.get("backend"),
                "updated_at": fleet.get("updated_at"),
                "message": fleet.get("message"),
            }
        )
    return pd.DataFrame(rows, columns=FLEETS_COLUMNS)


def fleet_of_pid(workspace: Workspace, pid: int | None) -> str | None:
    """The fleet whose trainer process is `pid` (a launcher knows the pid before the fleet's id)."""
    if pid is None:  # a job without a pid is no fleet's (a fleet.json without one would match it)
        return None
    for fid in fleet_ids(workspace):
        fleet = _read_json(fleet_dir(workspace) / fid / "fleet.json") or {}
        if fleet.get("pid") == pid:
            return fid
    return None
