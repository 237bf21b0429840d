"""Held-out evaluations in the workspace: `crossval/<crossval_id>/`.

Files: ``result.json`` (settings, per-policy summary with intervals, per fold,
unscored decisions and why), ``states.parquet`` and ``changes.parquet`` (the
out-of-fold actions of every policy at every scored state, and each policy's
first change per decision). A cross-validation of a run also leaves
``runs/<run_id>/crossval.json``, so the dashboard shows it beside the run's
in-sample figures. The folds may run on Ray's workers (`--backend ray`); they
return their tables and this process writes the folder aside and renames it
into place, so a reader sees all of it or none.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import asdict, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pandas as pd

from clustering.pipeline import stored_settings
from laneprint.errors import UserError
from laneprint.progress import ProgressFn
from laneprint.provenance import analysis_mark
from laneprint.workspace import Workspace, atomic_write_json
from rl.evaluation.crossval import CrossvalSettings, crossvalidate
from rl.problem.env import EnvConfig
from rl.problem.rewards import ReferenceLines
from rl.runs import Target, target_drivers, now_iso, resolve_lines, run_dir
from rl.settings import DQNSettings, LearnerSettings, stored_learner


def crossval_dir(workspace: Workspace) -> Path:
    return workspace.root / "crossval"


def style_names(workspace: Workspace) -> list[str]:
    """Styles of the analysis, in cluster order."""
    if not workspace.has_table("analysis", "styles"):
        raise UserError(f"no analysis in {workspace.root}: run `laneprint analyze` first")
    st = workspace.read_table("analysis", "styles")
    st = st[st["cluster"] >= 0].sort_values("cluster")
    return list(dict.fromkeys(st["style"].astype(str)))


def run_crossval(
    workspace: Workspace,
    target: Target,
    env: EnvConfig,
    dqn: LearnerSettings,
    settings: CrossvalSettings,
    lines_source: str = "analysis",
    run_id: str | None = None,
    progress: ProgressFn | None = None,
    backend: str = "local",
    ray_address: str | None = None,
) -> dict[str, Any]:
    """Cross-validate one target (its folds on `backend`) and store the result; returns its JSON-ready summary."""
    if not workspace.has_table("analysis", "decisions"):
        raise UserError(f"no analysis in {workspace.root}: run `laneprint analyze` first")
    decisions = workspace.read_table("analysis", "decisions")
    drivers, typical = target_drivers(workspace, target)
    if target.kind == "driver" or settings.lines_from == "typical":
        line_drivers = [typical] if typical else drivers
    else:
        line_drivers = drivers
    res = crossvalidate(
        decisions,
        drivers,
        line_drivers,
        env,
        dqn,
        settings,
        stored_settings(workspace),
        refit_lines=lines_source == "analysis",
        progress=progress,
        backend=backend,
        ray_address=ray_address,
    )
    states, changes = res.pop("states"), res.pop("changes")
    cv_id = _new_id(target, env.reward.name, settings.seed)
    res = {
        "crossval_id": cv_id,
        "target": asdict(target),
        "run_id": run_id,
        "lines_source": lines_source,
        "created_at": now_iso(),
        "data_fingerprint": workspace.fingerprint(),
        "analysis_fingerprint": workspace.analysis_fingerprint(),
        **res,
    }
    folder = crossval_dir(workspace) / cv_id
    with workspace.staging() as box:  # the whole folder appears at once, or not at all
        for name, df in (("states", states), ("changes", changes)):
            df.to_parquet(box / f"{name}.parquet", index=False)
        atomic_write_json(box / "result.json", res)
        folder.parent.mkdir(parents=True, exist_ok=True)
        os.rename(box, folder)
    if run_id:
        atomic_write_json(run_dir(workspace, run_id) / "crossval.json", res)
    return res


def crossval_run(
    workspace: Workspace,
    run_id: str,
    settings: CrossvalSettings,
    episodes: int | None = None,
    progress: ProgressFn | None = None,
    backend: str = "local",
    ray_address: str | None = None,
) -> dict[str, Any]:
    """Cross-validate with a trained run's target and settings (its reward, scenes, trainer)."""
    folder = run_dir(workspace, run_id)
    try:
        config = json.loads((folder / "config.json").read_text())
    except (OSError, ValueError):
        raise UserError(f"no run {run_id!r} in {workspace.root}") from None
    env = EnvConfig.from_dict(config["env"])
    dqn = stored_learner(config)
    if episodes is not None and isinstance(dqn, DQNSettings):
        dqn = replace(dqn, episodes=episodes)
    return run_crossval(
        workspace,
        Target(**config["target"]),
        env,
        dqn,
        settings,
        config.get("lines_source", "analysis"),
        run_id=run_id,
        progress=progress,
        backend=backend,
        ray_address=ray_address,
    )


def target_env(workspace: Workspace, target: Target, env: EnvConfig, lines_source: str) -> EnvConfig:
    """`env` with the target's full-analysis lines (the fallback of every fold)."""
    lines: ReferenceLines = resolve_lines(workspace, target, lines_source)
    return replace(env, lines=lines)


def _new_id(target: Target, reward: str, seed: int) -> str:
    slug = re.sub(r"[^a-z0-9]+", "-", target.name.lower()).strip("-") or "cv"
    return f"{datetime.now(timezone.utc):%Y%m%d-%H%M%S-%f}-{slug}-{reward}-s{seed}"


def list_crossvals(workspace: Workspace) -> pd.DataFrame:
    """One row per finished cross-validation: id, target, run, reward, and each policy's balanced accuracy."""
    rows = []
    root = crossval_dir(workspace)
    current = workspace.analysis_fingerprint()
    for folder in sorted(root.glob("*")) if root.exists() else []:
        try:
            res = json.loads((folder / "result.json").read_text())
        except (OSError, ValueError):
            continue
        row = {
            "crossval_id": folder.name,
            "target_kind": res["target"]["kind"],
            "target": res["target"]["name"],
            "run_id": res.get("run_id"),
            "reward": res["env"]["reward"]["name"],
            "scenes": res["env"].get("scenes"),
            "folds": res.get("folds"),
            "created_at": res.get("created_at"),
            "analysis": analysis_mark(res.get("analysis_fingerprint"), current)["analysis_label"],
        }
        for r in res.get("summary", []):
            row[f"{r['who']}_balanced_accuracy"] = r["balanced_accuracy"]
        rows.append(row)
    return pd.DataFrame(rows)


def load_crossval(workspace: Workspace, crossval_id: str) -> dict[str, Any]:
    """A stored cross-validation: its result dict plus the ``states`` and ``changes`` frames."""
    folder = crossval_dir(workspace) / crossval_id
    try:
        res = json.loads((folder / "result.json").read_text())
    except (OSError, ValueError):
        raise UserError(f"no cross-validation {crossval_id!r} in {workspace.root}") from None
    for name in ("states", "changes"):
        path = folder / f"{name}.parquet"
        res[name] = pd.read_parquet(path) if path.exists() else None
    res["analysis_mark"] = analysis_mark(res.get("analysis_fingerprint"), workspace.analysis_fingerprint())
    return res
