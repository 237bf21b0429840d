"""Cached, thin readers of the workspace for the pages.

Every loader takes the workspace root and a `stamp` of the folders it reads
(modification times: the store writes by renaming into place, so a new recording,
rejection or analysis changes the folder's mtime). Pages call `stamp(root, ...)` on
every run, so a cached result is reused only while the workspace is unchanged.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd
import streamlit as st

from laneprint.workspace import Workspace
from rl.settings import decision_counts

#: The analysis tables the pages read; one an older analysis lacks is simply absent from `analysis()`.
ANALYSIS_TABLES = (
    "decisions",
    "correlations",
    "fits",
    "fits_by_direction",
    "styles",
    "reference_lines",
    "skipped",
    "k_scores",
    "feature_sets",
    "following",
)


def stamp(root: Path, *parts: str) -> tuple[int, ...]:
    """Modification times [ns] of `root/<part>` (0 when missing): the cache key of a loader."""
    out = []
    for part in parts:
        try:
            out.append((root / part).stat().st_mtime_ns)
        except OSError:
            out.append(0)
    return tuple(out)


def recordings_stamp(root: Path) -> tuple[int, ...]:
    return stamp(root, "recordings", "rejected")


def analysis_stamp(root: Path) -> tuple[int, ...]:
    return stamp(root, "analysis", "analysis/meta.json")


@st.cache_data(show_spinner=False, max_entries=16)
def recordings(root: str, key: tuple[int, ...]) -> pd.DataFrame:
    """The RECORDINGS catalogue."""
    return Workspace(root).recordings()


@st.cache_data(show_spinner=False, max_entries=16)
def fingerprint(root: str, key: tuple[int, ...]) -> str:
    """`Workspace.fingerprint()`: which recordings are stored."""
    return Workspace(root).fingerprint()


def analysis_is_stale(root: Path) -> bool:
    """True when recordings were added or removed since the analysis ran."""
    meta = analysis_meta(str(root), analysis_stamp(root))
    stored = meta.get("data_fingerprint")
    return bool(stored) and stored != fingerprint(str(root), recordings_stamp(root))


@st.cache_data(show_spinner=False, max_entries=16)
def rejected(root: str, key: tuple[int, ...]) -> pd.DataFrame:
    """Files the ingest refused, newest first."""
    return Workspace(root).rejected()


@st.cache_data(show_spinner=False, max_entries=8)
def recording(root: str, recording_id: str) -> tuple[dict[str, Any], pd.DataFrame, pd.DataFrame]:
    """(meta, ego, traffic) of one recording; its id is a content hash, so it never goes stale."""
    return Workspace(root).load_recording(recording_id)


@st.cache_data(show_spinner=False, max_entries=16)
def analysis(root: str, key: tuple[int, ...]) -> dict[str, pd.DataFrame]:
    """The analysis tables that exist (name -> frame); empty when `analyze` has not run."""
    ws = Workspace(root)
    return {name: ws.read_table("analysis", name) for name in ANALYSIS_TABLES if ws.has_table("analysis", name)}


@st.cache_data(show_spinner=False, max_entries=16)
def training_inputs(root: str, key: tuple[int, ...]) -> dict[str, pd.DataFrame]:
    """What the Training page's forms read of the analysis: `reference_lines` and `styles` (when they
    exist) and `decision_counts` (driver_id -> states, presses: what a learning check needs), not the
    whole decisions table (55,000 rows at 100 drivers, copied out of the cache on every run)."""
    ws = Workspace(root)
    out = {
        name: ws.read_table("analysis", name)
        for name in ("reference_lines", "styles")
        if ws.has_table("analysis", name)
    }
    if ws.has_table("analysis", "decisions"):
        dec = ws.read_table("analysis", "decisions")
        out["decision_counts"] = decision_counts(dec)
    return out


@st.cache_data(show_spinner=False, max_entries=16)
def analysis_meta(root: str, key: tuple[int, ...]) -> dict[str, Any]:
    """`analysis/meta.json` (settings, fingerprint), {} when missing."""
    return Workspace(root).read_meta("analysis")


@st.cache_data(show_spinner=False, max_entries=16)
def analysis_fingerprint(root: str, key: tuple[int, ...]) -> str | None:
    """`Workspace.analysis_fingerprint()`: what the current analysis decided (None without one)."""
    return Workspace(root).analysis_fingerprint()


def current_analysis(root: Path) -> str | None:
    """The current analysis's fingerprint, cached until the analysis folder changes."""
    return analysis_fingerprint(str(root), analysis_stamp(Path(root)))


def run_stamp(root: Path, run_id: str) -> tuple[int, ...]:
    return stamp(root / "runs" / run_id, "config.json", "status.json", "metrics.jsonl", "evaluation.json")


@st.cache_data(show_spinner=False, max_entries=32)
def run(root: str, run_id: str, key: tuple[int, ...]) -> dict[str, Any]:
    """`rl.runs.load_run`: config, status, metrics, evaluation and its tables of one run."""
    from rl.runs import load_run

    return load_run(Workspace(root), run_id)


@st.cache_data(show_spinner=False, max_entries=32)
def personalized(root: str, run_id: str, key: tuple[int, ...]) -> dict[str, Any] | None:
    """A personalised run's personalize.json (None for other runs)."""
    from rl.personalize.store import load_personalized

    return load_personalized(Workspace(root), run_id)


def crossvals_stamp(root: Path) -> tuple[int, ...]:
    """Modification times of every stored `crossval/*/result.json` (written last, so a finished one counts)."""
    return tuple(sorted(p.stat().st_mtime_ns for p in (Path(root) / "crossval").glob("*/result.json")))


@st.cache_data(show_spinner=False, max_entries=16)
def crossvals(root: str, key: tuple[int, ...]) -> pd.DataFrame:
    """`rl.evaluation.crossval_store.list_crossvals`: one row per finished cross-validation."""
    from rl.evaluation.crossval_store import list_crossvals

    return list_crossvals(Workspace(root))


@st.cache_data(show_spinner=False, max_entries=16)
def crossval(root: str, crossval_id: str, key: tuple[int, ...]) -> dict[str, Any]:
    """`rl.evaluation.crossval_store.load_crossval`: one stored cross-validation (result dict, states, changes)."""
    from rl.evaluation.crossval_store import load_crossval

    return load_crossval(Workspace(root), crossval_id)


def run_crossval_stamp(root: Path, run_id: str) -> tuple[int, ...]:
    return stamp(Path(root) / "runs" / run_id, "crossval.json")


@st.cache_data(show_spinner=False, max_entries=32)
def run_crossval(root: str, run_id: str, key: tuple[int, ...]) -> dict[str, Any] | None:
    """`runs/<run_id>/crossval.json` (the run's latest cross-validation), None when there is none."""
    try:
        return json.loads((Path(root) / "runs" / run_id / "crossval.json").read_text())
    except (OSError, ValueError):
        return None


def drives_stamp(root: Path) -> tuple[int, ...]:
    """Modification times of every `drives/*/drive.json` (`laneprint drive`'s default folders)."""
    return tuple(sorted(_mtimes((Path(root) / "drives").glob("*/drive.json"))))


@st.cache_data(show_spinner=False, max_entries=8)
def drives(root: str, key: tuple[int, ...]) -> dict[str, dict[str, Any]]:
    """Every readable `drives/<name>/drive.json` of the workspace, by folder name (newest first)."""
    out = {}
    paths = sorted((Path(root) / "drives").glob("*/drive.json"), key=lambda p: p.stat().st_mtime, reverse=True)
    for p in paths:
        try:
            out[p.parent.name] = json.loads(p.read_text())
        except (OSError, ValueError):
            continue
    return out


def _mtimes(paths) -> list[int]:
    out = []
    for p in paths:
        try:
            out.append(p.stat().st_mtime_ns)
        except OSError:
            out.append(0)
    return out


def _fleets_alive(root: Path) -> tuple[bool, ...]:
    """Whether each fleet's trainer lives: a fleet left 'running' by a dead process reads as interrupted."""
    from laneprint.processes import laneprint_process_alive

    out = []
    for path in sorted(Path(root).glob("fleets/*/fleet.json")):
        try:
            fleet = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        out.append(fleet.get("state") == "running" and laneprint_process_alive(fleet.get("pid")))
    return tuple(out)


def fleets_stamp(root: Path) -> tuple:
    """Modification times of every fleet.json and every run's status.json and evaluation.json, and
    which fleets' trainers live."""
    root = Path(root)
    files = [*root.glob("fleets/*/fleet.json"), *root.glob("runs/*/status.json"), *root.glob("runs/*/evaluation.json")]
    return tuple(sorted(_mtimes(files))) + _fleets_alive(root)


@st.cache_data(show_spinner=False, max_entries=16)
def fleets(root: str, key: tuple[int, ...]) -> pd.DataFrame:
    """`rl.fleet.store.list_fleets`: one row per fleet, newest first."""
    from rl.fleet.store import list_fleets

    return list_fleets(Workspace(root))


@st.cache_data(show_spinner=False, max_entries=16)
def fleet_table(root: str, fleet_id: str, key: tuple[int, ...]) -> pd.DataFrame:
    """`rl.fleet.store.fleet_table`: one row per agent of the fleet."""
    from rl.fleet.store import fleet_table as table

    return table(Workspace(root), fleet_id)
