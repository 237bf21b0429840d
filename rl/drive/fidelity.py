"""Does the agent drive like its drivers? A drive beside the target drivers' own recordings.

Both sides are read the same way, from logs:

- **lane changes per km**: flips of the ego's lane over the distance driven, and the share
  to each side (lane 0 is the rightmost: a higher lane is a change to the left), with an
  exact Poisson interval for the agent's rate and the drivers' pooled rate;
- **by lane**: the share of time in each lane and the lane changes per km by 'from>to' pair
  (`lane_use`), beside the drivers';
- **the indicators at the presses**: `indicators.decisions.extract_decisions` (the analysis's
  own reading) on the drive's recordings, against the target drivers' presses in the
  workspace's decisions table. Per indicator, over the presses where it is defined: the
  median (with a bootstrap interval) and interquartile range of each side, the Wasserstein
  distance and the two-sample Kolmogorov-Smirnov statistic and p-value.

`fidelity(...)` returns the JSON-ready comparison; `met` says whether the rate is within
`RATE_TOLERANCE` of the drivers' and every compared median lies inside the drivers'
interquartile range. The drivers drove the study's traffic, the agent the drive's: the same
kind of road and traffic when both come from the same SUMO family, not the same vehicles.
"""

from __future__ import annotations

from typing import Any, Iterable, Iterator, Optional

import numpy as np
import pandas as pd
from scipy import stats

from indicators.acceptance import add_acceptance
from indicators.decisions import extract_decisions
from indicators.settings import AnalysisSettings
from indicators.stats import INDICATOR_COLUMNS
from laneprint.simulator.sumo.settings import study_traffic
from laneprint.workspace import Workspace

#: The indicators compared at the presses: the paper's three, then what the driver accepts.
COMPARED = ("t_f", "t_nf", "dv_nb", "gap_f", "thw_f", "gap_nf", "gap_nb", "thw_nb")
#: Agent's lane changes per km within this fraction of the drivers' (issue 19's acceptance).
RATE_TOLERANCE = 0.2
N_BOOT = 1000
ALPHA = 0.05


def lane_change_pairs(ego: pd.DataFrame) -> dict[str, int]:
    """Lane changes (flips of `ego_lane`) of one ego log, counted by 'from>to' lane."""
    lane = ego.sort_values("t_s")["ego_lane"].to_numpy()
    flips = np.flatnonzero(lane[1:] != lane[:-1])
    out: dict[str, int] = {}
    for k in flips:
        key = f"{lane[k]}>{lane[k + 1]}"
        out[key] = out.get(key, 0) + 1
    return out


def driven_km(ego: pd.DataFrame) -> float:
    """Distance driven in one ego log [km]."""
    x = ego.sort_values("t_s")["ego_x_m"].to_numpy(dtype=float)
    return float(x[-1] - x[0]) / 1000.0 if len(x) else 0.0


def lane_changes(ego: pd.DataFrame) -> dict[str, float]:
    """Lane changes, to the left (to a higher lane) and right, and km driven of one ego log."""
    pairs = [(tuple(map(int, k.split(">"))), n) for k, n in lane_change_pairs(ego).items()]
    return {
        "changes": sum(n for _, n in pairs),
        "left": sum(n for (a, b), n in pairs if b > a),
        "right": sum(n for (a, b), n in pairs if b < a),
        "km": driven_km(ego),
    }


def lane_seconds(ego: pd.DataFrame) -> dict[int, float]:
    """Seconds spent in each lane of one ego log (a sample's lane holds until the next sample)."""
    e = ego.sort_values("t_s")
    lane, dt = e["ego_lane"].to_numpy()[:-1], np.diff(e["t_s"].to_numpy(dtype=float))
    return {int(k): float(dt[lane == k].sum()) for k in np.unique(lane)}


def lane_use(egos: Iterable[pd.DataFrame]) -> dict[str, dict[str, float]]:
    """Where a set of ego logs drove: the share of time in each lane, and lane changes per km by
    'from>to' pair (on three lanes the total rate can hide a shuttle between two of them)."""
    seconds: dict[int, float] = {}
    pairs: dict[str, int] = {}
    km = 0.0
    for ego in egos:
        for k, v in lane_seconds(ego).items():
            seconds[k] = seconds.get(k, 0.0) + v
        for pair, n in lane_change_pairs(ego).items():
            pairs[pair] = pairs.get(pair, 0) + n
        km += driven_km(ego)
    total = sum(seconds.values())
    return {
        "time_share": {str(k): v / total for k, v in sorted(seconds.items())} if total > 0 else {},
        "pairs_per_km": {k: n / km for k, n in sorted(pairs.items())} if km > 0 else {},
    }


def driver_egos(workspace: Workspace, drivers: Iterable[str]) -> Iterator[tuple[str, pd.DataFrame]]:
    """(driver id, ego log with t_s, ego_lane, ego_x_m) of each stored recording of `drivers`."""
    want = set(map(str, drivers))
    cat = workspace.recordings()
    for rid, did in zip(cat["recording_id"], cat["driver_id"].astype(str)):
        if did in want:
            yield (
                did,
                pd.read_parquet(workspace.recordings_dir / rid / "ego.parquet", columns=["t_s", "ego_lane", "ego_x_m"]),
            )


def drivers_traffic(workspace: Workspace, drivers: Iterable[str]) -> Optional[tuple[str, int]]:
    """(family, lanes) of the laneprint SUMO traffic every stored recording of `drivers` was driven in
    (`laneprint.simulator.sumo.settings.study_traffic`), or None when they were not all driven in one such
    traffic (another simulator, or a mix)."""
    want = set(map(str, drivers))
    cat = workspace.recordings()
    worlds = {study_traffic(s) for s, d in zip(cat["simulator"], cat["driver_id"].astype(str)) if d in want}
    return worlds.pop() if len(worlds) == 1 else None


def driver_rates(egos: Iterable[tuple[str, pd.DataFrame]]) -> pd.DataFrame:
    """One row per driver: lane changes, left, right and km over its ego logs (`driver_egos`)."""
    rows: dict[str, dict[str, float]] = {}
    for did, ego in egos:
        one = lane_changes(ego)
        acc = rows.setdefault(did, {"changes": 0, "left": 0, "right": 0, "km": 0.0})
        for k, v in one.items():
            acc[k] += v
    return pd.DataFrame(
        [{"driver_id": d, **v} for d, v in sorted(rows.items())],
        columns=["driver_id", "changes", "left", "right", "km"],
    )


def press_values(decisions: pd.DataFrame) -> dict[str, np.ndarray]:
    """Per compared indicator, its defined values at the presses of a decisions table."""
    if "thw_f_s" not in decisions.columns:
        decisions = add_acceptance(decisions)
    press = decisions[decisions["label"].astype(str) == "change"]
    out = {}
    for name in COMPARED:
        col, status, _ = INDICATOR_COLUMNS[name]
        if col in press.columns and status in press.columns:
            ok = press[status].astype(str) == "ok"
            out[name] = press.loc[ok, col].to_numpy(dtype=float)
        else:
            out[name] = np.zeros(0)
    return out


def drive_decisions(
    recordings: list[tuple[dict, pd.DataFrame, pd.DataFrame]], settings: Optional[AnalysisSettings] = None
) -> pd.DataFrame:
    """The drive's decisions read as the analysis reads a study's recordings."""
    settings = settings or AnalysisSettings()
    parts = []
    for j, (meta, ego, traffic) in enumerate(recordings):
        meta = {"recording_id": meta.get("recording_id", f"drive-{j}"), **meta}
        table, _ = extract_decisions(meta, ego, traffic, settings)
        parts.append(table)
    parts = [p for p in parts if len(p)]
    return add_acceptance(pd.concat(parts, ignore_index=True), settings) if parts else pd.DataFrame()


def poisson_interval(count: int, exposure: float, alpha: float = ALPHA) -> tuple[Optional[float], Optional[float]]:
    """Exact (Garwood) interval of a rate count / exposure."""
    if exposure <= 0:
        return None, None
    lo = stats.chi2.ppf(alpha / 2, 2 * count) / 2 if count > 0 else 0.0
    hi = stats.chi2.ppf(1 - alpha / 2, 2 * count + 2) / 2
    return float(lo / exposure), float(hi / exposure)


def median_interval(
    x: np.ndarray, rng: np.random.Generator, n_boot: int = N_BOOT, alpha: float = ALPHA
) -> tuple[Optional[float], Optional[float]]:
    """Percentile bootstrap interval of the median (None with fewer than 2 values)."""
    if len(x) < 2:
        return None, None
    meds = np.median(rng.choice(x, size=(n_boot, len(x)), replace=True), axis=1)
    return float(np.quantile(meds, alpha / 2)), float(np.quantile(meds, 1 - alpha / 2))


def compare_values(agent: np.ndarray, drivers: np.ndarray, rng: np.random.Generator) -> dict[str, Any]:
    """Median, interval and quartiles of each side, distances, and whether the agent's median lies
    inside the drivers' interquartile range (None when either side has no value)."""

    def side(x: np.ndarray) -> dict[str, Any]:
        if not len(x):
            return {"n": 0, "median": None, "median_ci": [None, None], "q1": None, "q3": None}
        q1, med, q3 = np.quantile(x, [0.25, 0.5, 0.75])
        return {
            "n": int(len(x)),
            "median": float(med),
            "median_ci": list(median_interval(x, rng)),
            "q1": float(q1),
            "q3": float(q3),
        }

    a, d = side(agent), side(drivers)
    out: dict[str, Any] = {
        "agent": a,
        "drivers": d,
        "wasserstein": None,
        "ks": None,
        "ks_p": None,
        "median_in_iqr": None,
    }
    if len(agent) and len(drivers):
        out["wasserstein"] = float(stats.wasserstein_distance(agent, drivers))
        ks = stats.ks_2samp(agent, drivers)
        out["ks"], out["ks_p"] = float(ks.statistic), float(ks.pvalue)
        out["median_in_iqr"] = bool(d["q1"] <= a["median"] <= d["q3"])
    return out


def rate_comparison(agent: dict[str, float], drivers: pd.DataFrame) -> dict[str, Any]:
    """Lane changes per km and the share to the left, the agent's against the drivers' pooled."""
    d_changes, d_km = int(drivers["changes"].sum()), float(drivers["km"].sum())
    a_rate = agent["changes"] / agent["km"] if agent["km"] > 0 else None
    d_rate = d_changes / d_km if d_km > 0 else None
    per_driver = (drivers["changes"] / drivers["km"]).replace([np.inf], np.nan).dropna()
    ratio = a_rate / d_rate if a_rate is not None and d_rate else None
    return {
        "agent": {
            "changes": int(agent["changes"]),
            "km": agent["km"],
            "per_km": a_rate,
            "per_km_ci": list(poisson_interval(int(agent["changes"]), agent["km"])),
            "left_share": agent["left"] / agent["changes"] if agent["changes"] else None,
        },
        "drivers": {
            "n": int(len(drivers)),
            "changes": d_changes,
            "km": d_km,
            "per_km": d_rate,
            "per_km_ci": list(poisson_interval(d_changes, d_km)),
            "per_km_range": [float(per_driver.min()), float(per_driver.max())] if len(per_driver) else None,
            "left_share": float(drivers["left"].sum()) / d_changes if d_changes else None,
        },
        "ratio": ratio,
        "within_tolerance": None if ratio is None else bool(abs(ratio - 1.0) <= RATE_TOLERANCE),
    }


def fidelity(
    workspace: Workspace,
    drivers: list[str],
    recordings: list[tuple[dict, pd.DataFrame, pd.DataFrame]],
    settings: Optional[AnalysisSettings] = None,
    seed: int = 0,
) -> dict[str, Any]:
    """The drive (`recordings`, as `rl.drive.loop.recordings` gives them) beside `drivers`' own logs and presses."""
    rng = np.random.default_rng(seed)
    agent = {"changes": 0, "left": 0, "right": 0, "km": 0.0}
    for _, ego, _ in recordings:
        for k, v in lane_changes(ego).items():
            agent[k] += v
    their_egos = list(driver_egos(workspace, drivers))
    out: dict[str, Any] = {
        "drivers": list(drivers),
        "tolerance": RATE_TOLERANCE,
        "rate": rate_comparison(agent, driver_rates(their_egos)),
    }
    theirs = workspace.read_table("analysis", "decisions")
    theirs = theirs[theirs["driver_id"].astype(str).isin(set(drivers))]
    mine = drive_decisions(recordings, settings)
    a_vals = press_values(mine) if len(mine) else {k: np.zeros(0) for k in COMPARED}
    d_vals = press_values(theirs)
    out["indicators"] = {k: compare_values(a_vals[k], d_vals[k], rng) for k in COMPARED}
    out["agent_presses"] = int((mine["label"].astype(str) == "change").sum()) if len(mine) else 0
    inside = [v["median_in_iqr"] for v in out["indicators"].values() if v["median_in_iqr"] is not None]
    out["medians_in_iqr"] = f"{sum(inside)} of {len(inside)}"
    out["lanes"] = {
        "agent": lane_use(ego for _, ego, _ in recordings),
        "drivers": lane_use(ego for _, ego in their_egos),
    }
    out["met"] = bool(out["rate"]["within_tolerance"]) and bool(inside) and all(inside)
    return out
