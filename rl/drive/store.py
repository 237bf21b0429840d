"""`laneprint drive`'s edges: the run's agent in, MCAP logs and a JSON report out.

`drive_run(workspace, run_id, ...)` loads a trained run (its `EnvConfig` and
weights, as `laneprint evaluate` does), drives the SUMO sections with it
(`rl.drive.loop`), writes one LOG_FORMAT v1 MCAP per section (`ingest.writers`, as the
SUMO study) and summarises: lane changes, SUMO's collision and emergency-braking
counts, and the indicators at the agent's decisions against its target's
reference lines. With `analyze=True` the study of the workspace plus the drive is
analysed in a scratch workspace (the user's analysis, which the run was trained
on, is left alone) and the style it gives the agent is reported.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import asdict
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ingest.writers import write_mcap
from laneprint.errors import UserError
from laneprint.progress import ProgressFn
from laneprint.reference import INDICATORS, SPEED_LIMITS_KPH
from laneprint.workspace import Workspace, atomic_write_json
from rl.drive.loop import QFunction, SectionDrive, drive_sections, recordings
from rl.learners.dqn import q_values
from rl.problem.env import EnvConfig, observation
from rl.problem.rewards import ReferenceLines
from rl.runs import Target, load_weights, run_dir

DEFAULT_STYLE = "Normal"
_ATTR = {"t_f": "t_f_s", "t_nf": "t_nf_s", "dv_nb": "dv_nb_mps"}  # indicator -> `Decision` field


def agent_q(net: Any, cfg: EnvConfig) -> QFunction:
    """The trained agent's Q-values of a batch of scenes (the run's observation), shape (n, 2)."""
    return lambda scene: q_values(net, observation(scene, cfg))


def load_run_config(workspace: Workspace, run_id: str) -> dict[str, Any]:
    """The run's config.json (`UserError` when there is no such run)."""
    path = run_dir(workspace, run_id) / "config.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise UserError(f"no run {run_id!r} in {workspace.root} (see `laneprint train`)") from None
    except (OSError, ValueError) as exc:
        raise UserError(f"{path} is not readable JSON: {exc}") from None


def ego_style(workspace: Workspace, target: Target) -> tuple[str, str]:
    """(SUMO style whose parameters the ego drives with, why): the target's style, else Normal."""
    from laneprint.simulator.sumo.styles import STYLE_PARAMS

    known = {s.lower(): s for s in STYLE_PARAMS}
    if target.kind == "style" and target.name.lower() in known:
        return known[target.name.lower()], "the run's target style"
    if target.kind == "driver" and workspace.has_table("analysis", "styles"):
        styles = workspace.read_table("analysis", "styles")
        row = styles[styles["driver_id"].astype(str) == target.name]
        if len(row) and str(row["style"].iloc[0]).lower() in known:
            return known[str(row["style"].iloc[0]).lower()], f"the analysis's style of driver {target.name}"
    return DEFAULT_STYLE, f"{target.label} has no SUMO style: the {DEFAULT_STYLE} one"


def output_paths(out: Path, session_ids: list[str]) -> list[Path]:
    """Where each section's MCAP goes: `out` itself for one section when it ends in .mcap,
    `<stem>_S<limit>.mcap` beside it for several, `<session_id>.mcap` inside a folder otherwise."""
    if out.suffix == ".mcap":
        if len(session_ids) == 1:
            return [out]
        return [out.with_name(f"{out.stem}_{sid.rsplit('_', 1)[-1]}.mcap") for sid in session_ids]
    return [out / f"{sid}.mcap" for sid in session_ids]


def check_sections(sections: Optional[list[float]]) -> tuple[int, ...]:
    """The sections to drive (`UserError` for a limit the study does not have)."""
    if not sections:
        return tuple(SPEED_LIMITS_KPH)
    bad = [s for s in sections if int(round(s)) not in SPEED_LIMITS_KPH]
    if bad:
        raise UserError(f"--section {bad[0]:g}: the sections are {', '.join(map(str, SPEED_LIMITS_KPH))} km/h")
    return tuple(sorted({int(round(s)) for s in sections}))


def indicators_vs_lines(drives: list[SectionDrive], lines: ReferenceLines) -> dict[str, Any]:
    """Per indicator, at the agent's decisions that started a lane change: how many are defined,
    the median value and the mean absolute and signed difference to the reference line."""
    made = [d for drive in drives for d in drive.decisions if d.started]
    out: dict[str, Any] = {"n_decisions": len(made), "lines": lines.to_dict()}
    for ind in INDICATORS:
        vals = [(getattr(d, _ATTR[ind]), d.v_e_mps) for d in made]
        vals = [(x, v) for x, v in vals if x is not None]
        if not vals:
            out[ind] = {"n": 0, "median": None, "line_median": None, "mae": None, "bias": None}
            continue
        x = np.array([a for a, _ in vals])
        ref = lines.at(np.array([v for _, v in vals]))[ind]
        out[ind] = {"n": len(x), "median": float(np.median(x)), "line_median": float(np.median(ref)),
                    "mae": float(np.mean(np.abs(x - ref))), "bias": float(np.mean(x - ref))}
    return out


def section_rows(drives: list[SectionDrive], paths: list[Path]) -> list[dict[str, Any]]:
    """One JSON-ready row per driven section."""
    rows = []
    for d, path in zip(drives, paths):
        made = [c for c in d.log.lane_changes if c["changed"]]
        by_lane: dict[str, int] = {}
        for c in made:
            key = f"{c['from_lane']}>{c['target_lane']}"
            by_lane[key] = by_lane.get(key, 0) + 1
        rows.append({
            "speed_limit_kph": d.speed_limit_kph, "file": str(path), "sumo_seed": d.log.sumo_seed,
            "duration_s": float(d.log.ego["t_s"].iloc[-1]), "decisions_asked": d.n_asked,
            "change_decisions": len(d.decisions), "lane_changes": len(made),
            "left": sum(c["direction"] == "left" for c in made), "right": sum(c["direction"] == "right" for c in made),
            "not_started": sum(not x.started for x in d.decisions),
            "collisions": d.log.n_collisions, "emergency_brakes": d.log.n_emergency_brakes,
            "changes_by_lane": dict(sorted(by_lane.items())),
        })
    return rows


def _sum_counts(counts: list[dict[str, int]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for c in counts:
        for k, v in c.items():
            out[k] = out.get(k, 0) + v
    return dict(sorted(out.items()))


def assigned_style(workspace: Workspace, files: list[Path], driver_id: str) -> dict[str, Any]:
    """Analyse the workspace's recordings plus `files` (as `driver_id`) in a scratch workspace:
    the style given to `driver_id`, its confidence, and every driver's style."""
    from clustering.pipeline import analyze, stored_settings
    from ingest.pipeline import ingest_paths

    cat = workspace.recordings()
    with tempfile.TemporaryDirectory(prefix="laneprint-drive-analysis-") as tmp:
        scratch = Workspace(Path(tmp) / "ws").ensure()
        for rid, did in zip(cat["recording_id"], cat["driver_id"].astype(str)):
            if did != driver_id:  # a previous drive of the same id is replaced by this one
                (scratch.recordings_dir / rid).symlink_to(workspace.recordings_dir / rid, target_is_directory=True)
        rep = ingest_paths(files, scratch, driver_id=driver_id)
        bad = [f for f in rep.files if f.status not in ("ingested", "warning")]
        if bad:
            raise UserError(f"ingest did not store the drive's {bad[0].source} ({bad[0].status}): {bad[0].reason}")
        analyze(scratch, stored_settings(workspace))
        styles = scratch.read_table("analysis", "styles")
    styles["driver_id"] = styles["driver_id"].astype(str)
    row = styles[styles["driver_id"] == driver_id]
    return {"driver_id": driver_id, "style": str(row["style"].iloc[0]) if len(row) else None,
            "confidence": float(row["confidence"].iloc[0]) if len(row) and "confidence" in row else None,
            "styles": dict(zip(styles["driver_id"], styles["style"].astype(str)))}


def drive_run(workspace: Workspace, run_id: str, *, minutes: float = 10.0, seed: int = 0,
              sections: Optional[list[float]] = None, out: Optional[Path] = None,
              driver_id: Optional[str] = None, analyze: bool = False, lanes: int = 2,
              progress: Optional[ProgressFn] = None) -> dict[str, Any]:
    """Drive the run's agent in SUMO on a road of `lanes` lanes; write the MCAPs; a JSON-ready report."""
    from laneprint.simulator.sumo.backend import check_available
    from laneprint.simulator.sumo.settings import DEFAULT_FAMILY, LANES, family_settings
    from laneprint.simulator.sumo.styles import STYLE_PARAMS

    if lanes not in LANES:
        raise UserError(f"--lanes {lanes}: a SUMO highway has {' or '.join(map(str, LANES))} lanes")
    if not 0 < minutes <= 120:
        raise UserError("--minutes must be more than 0 and at most 120")
    config = load_run_config(workspace, run_id)
    target = Target(**config["target"])
    cfg = EnvConfig.from_dict(config["env"])
    net = load_weights(workspace, run_id)
    limits = check_sections(sections)
    driver_id = driver_id or f"agent-{run_id}"
    out = Path(out) if out is not None else workspace.root / "drives" / f"{run_id}-s{seed}"
    if out.suffix != ".mcap" and out.exists() and not out.is_dir():
        raise UserError(f"--out {out} exists and is not a folder")
    check_available()
    style, why = ego_style(workspace, target)
    settings = family_settings(DEFAULT_FAMILY, lanes, speed_limits_kph=limits, minutes=minutes)
    drives = drive_sections(agent_q(net, cfg), cfg, STYLE_PARAMS[style], settings, seed, progress)
    lanes_opt = "" if lanes == 2 else f", {lanes} lanes"
    simulator = f"Eclipse SUMO {drives[0].log.sumo_version} (laneprint drive {run_id}, seed {seed}{lanes_opt})"
    recs = recordings(drives, driver_id, simulator)
    paths = output_paths(out, [meta["session_id"] for meta, _, _ in recs])
    for path, (meta, ego, traffic) in zip(paths, recs):
        path.parent.mkdir(parents=True, exist_ok=True)
        write_mcap(path, meta, ego, traffic)
    rows = section_rows(drives, paths)
    result: dict[str, Any] = {
        "run_id": run_id, "target": config["target"], "driver_id": driver_id, "seed": seed, "minutes": minutes,
        "sumo_version": drives[0].log.sumo_version, "sumo_api": drives[0].log.api,
        "ego_style": style, "ego_style_reason": why, "decision_every_s": cfg.dt_s, "lanes": lanes,
        "side_input": cfg.observation == "direction",
        "files": [str(p) for p in paths], "sections": rows,
        "totals": {k: sum(r[k] for r in rows) for k in ("decisions_asked", "change_decisions", "lane_changes",
                                                        "left", "right", "not_started", "collisions",
                                                        "emergency_brakes")},
        "changes_by_lane": _sum_counts([r["changes_by_lane"] for r in rows]),
        "indicators": indicators_vs_lines(drives, cfg.lines),
        "decisions": [{"speed_limit_kph": d.speed_limit_kph, **asdict(x)} for d in drives for x in d.decisions],
    }
    if analyze:
        result["analysis"] = assigned_style(workspace, paths, driver_id)
        result["analysis"]["target_style"] = target.name if target.kind == "style" else None
    if out.suffix != ".mcap":
        atomic_write_json(out / "drive.json", result)
    return result
