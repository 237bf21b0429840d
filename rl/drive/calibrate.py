"""The dwell and the follower's headway calibrated in closed loop (`drive --dwell-calibrated`, `--lag-calibrated`).

Why (README, issue 19, 'The dwell calibrated'): an agent without memory that wants back at once comes
back exactly when the dwell allows, so a fixed dwell gives stays all of one length; a dwell drawn from
the drivers' own times (`drive --dwell-draw`) gives stays that are the longer of the draw and the agent's
own wait, and the drivers' times already hold their waits: too long wherever the agent does not want
back at once. The agent's own wait shows only in closed loop. So:

1. drive the agent with the default dwell (the drivers' floor) on calibration seeds (`CALIBRATION_SEEDS`,
   never the seeds a drive is judged on) in the study family's traffic: its stays per kind of pair
   ('left>right': from a change to the left to the next change, to the right), W;
2. the drivers' stays of the same kinds along their recordings, D;
3. if the drawn dwell X and the agent's wait are independent, a stay is max(X, W), whose distribution is
   F_X F_W; so F_X = F_D / F_W, taken as the largest non-decreasing function with F_X F_W <= F_D (where
   the agent already stays longer than the drivers, no dwell is needed: F_X = 1 there);
4. each lane change draws the next dwell from F_X (`HeldBackRule.dwell_draws`), never under the floor.

The same drives calibrate the **follower's headway** the agent's own changes need (`drive
--lag-calibrated`, `HeldBackRule.lag_draws`): per side, the follower time headways (thw_nb) at the
agent's own lane changes with a follower within `far_follower_m` are W, those at its drivers' presses to
that side are D (`rl.drive.heldback.lag_headways`), and F_X = F_D / F_W as above. This comes first: where
a side is calibrated, the calibration seeds are driven again with its headways drawn, and those drives'
stays calibrate the dwell (waiting for a headway lengthens a stay, which the dwell must not add again). Returning right past
a car it overtook, the headway only grows, so the agent's change comes at max(X, W). Where the agent
already takes headways like its drivers', X is 0 and nothing changes; on study 723 the Defensive agent
returned at a median 0.81 s where its drivers did at 2.45 s (README, 'The follower's headway
calibrated'). Headways drawn from the drivers' own presses instead (`drive --lag-draw`) take the
Normal and Aggressive agents there, whose headways were already their drivers', under 0.8 of their
drivers' rate.

The calibration is kept in the run's folder (`dwell_calibration.json`, per traffic and drive settings:
family, lanes, minutes, pace and undo check) and reused. Out of its world there are no drivers in the
traffic to calibrate against: the default dwell stays, and the floors alone hold the agent's changes.
"""

from __future__ import annotations

import json
import tempfile
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np
import pandas as pd

from laneprint.workspace import Workspace, atomic_write_json
from rl.drive.fidelity import driver_egos
from rl.runs import Target, run_dir, target_drivers

#: Drive seeds of the calibration drives (the seeds a drive is judged on are others).
CALIBRATION_SEEDS: tuple[int, ...] = (1001, 1002)
#: The dwell's distribution is read on this grid [s] (the headway's on `LAG_GRID_S`) and drawn from this many quantiles.
GRID_S = 0.5
LAG_GRID_S = 0.05
QUANTILES = 200
MIN_STAYS = 5  # stays of a kind, of the drivers and of the agent, needed to calibrate that kind
MIN_HEADWAYS = 10  # lane changes to a side with a near follower, of the agent, needed to calibrate that side
CALIBRATION_FILE = "dwell_calibration.json"


def stays_by_kind(egos: list[pd.DataFrame]) -> dict[str, list[float]]:
    """Per kind of consecutive lane changes ('left>right' etc.), the times [s] from one change to the next
    within a recording (lane 0 is the rightmost; a higher lane is to the left)."""
    out: dict[str, list[float]] = defaultdict(list)
    for ego in egos:
        lane = ego["ego_lane"].to_numpy()
        t = ego["t_s"].to_numpy(dtype=float)
        changes = np.flatnonzero(np.diff(lane) != 0) + 1
        side = ["left" if lane[i] > lane[i - 1] else "right" for i in changes]
        for k in range(len(changes) - 1):
            out[f"{side[k]}>{side[k + 1]}"].append(float(t[changes[k + 1]] - t[changes[k]]))
    return dict(sorted(out.items()))


def _ecdf(x: list[float], grid: np.ndarray) -> np.ndarray:
    return np.searchsorted(np.sort(np.asarray(x, dtype=float)), grid, side="right") / len(x)


def deconvolved_dwell(
    drivers: list[float], agent: list[float], n: int = QUANTILES, step: float = GRID_S
) -> list[float]:
    """`n` quantiles of the dwell X whose max with the agent's own stays (`agent`, driven with the floor
    dwell) is distributed like the drivers' stays (`drivers`): F_X = F_D / F_W, the largest non-decreasing
    function with F_X F_W <= F_D, read on a grid of `step`."""
    grid = np.arange(0.0, max(max(drivers), max(agent)) + step, step)
    f_d, f_w = _ecdf(drivers, grid), _ecdf(agent, grid)
    ratio = np.where(f_w > 0, np.minimum(f_d / np.maximum(f_w, 1e-12), 1.0), 1.0)
    f_x = np.minimum.accumulate(ratio[::-1])[::-1]
    u = (np.arange(n) + 0.5) / n
    return [float(v) for v in grid[np.minimum(np.searchsorted(f_x, u, side="left"), len(grid) - 1)]]


def calibration_key(setting: dict[str, Any]) -> str:
    """The key of a calibration's traffic and drive settings, e.g. 'family=acceptance,lanes=2,...'."""
    return ",".join(f"{k}={v}" for k, v in setting.items())


def load_calibration(workspace: Workspace, run_id: str, setting: dict[str, Any]) -> Optional[dict[str, Any]]:
    """The run's stored calibration for this traffic and these drive settings, or None."""
    path = run_dir(workspace, run_id) / CALIBRATION_FILE
    if not path.exists():
        return None
    return json.loads(path.read_text()).get(calibration_key(setting))


def agent_headways(decisions: list[dict[str, Any]]) -> dict[str, list[float]]:
    """Per side, the follower time headways at a drive's own lane changes of the agent (`Decision` rows
    as in a drive's report: started, asked by the agent, with a follower within far_follower_m)."""
    out: dict[str, list[float]] = defaultdict(list)
    for d in decisions:
        if d["started"] and d["source"] == "agent" and d.get("thw_nb_s") is not None:
            out["left" if d["target_lane"] > d["from_lane"] else "right"].append(float(d["thw_nb_s"]))
    return dict(sorted(out.items()))


def calibrated_headways(drivers: dict[str, list[float]], agent: dict[str, list[float]]) -> dict[str, list[float]]:
    """Per side with enough of both (`MIN_HEADWAYS` of the agent's; the drivers' as `lag_headways` gives
    them) where the agent's median headway is under its drivers' lower quartile, the headways to draw
    (`HeldBackRule.lag_draws`): X with max(X, agent's) distributed like the drivers'. Within their spread
    waiting for a draw only costs lane changes (study 723's Aggressive agent, median 0.77 s against its
    drivers' 1.13 and lower quartile 0.56: rate 0.84 of theirs without the draw, 0.77 with it)."""
    return {
        side: deconvolved_dwell(d, agent[side], step=LAG_GRID_S)
        for side, d in drivers.items()
        if len(agent.get(side, [])) >= MIN_HEADWAYS and np.median(agent[side]) < np.percentile(d, 25)
    }


def calibrate(
    workspace: Workspace,
    run_id: str,
    target: Target,
    drive: Callable[[int, Path, dict[str, list[float]]], dict[str, Any]],
    setting: dict[str, Any],
    seeds: tuple[int, ...] = CALIBRATION_SEEDS,
) -> dict[str, Any]:
    """Calibrate the follower's headway, then the dwell (see the module doc) with `drive(seed, out, lag)`,
    a drive of the run with the default dwell and the headways `lag` to draw (`HeldBackRule.lag_draws`;
    empty: the floors alone) that returns its report, in the traffic and drive settings `setting`
    (family, lanes, minutes, ...); store the result in the run's folder and return it."""
    from ingest.mapping import IDENTITY
    from ingest.pipeline import read_log
    from ingest.validate import canonicalise
    from rl.drive.heldback import lag_headways

    def driven(lag: dict[str, list[float]]) -> tuple[list[pd.DataFrame], list[dict[str, Any]]]:
        egos, decisions = [], []
        with tempfile.TemporaryDirectory(prefix="laneprint-calibrate-") as tmp:
            for seed in seeds:
                report = drive(seed, Path(tmp) / f"s{seed}", lag)
                decisions += report["decisions"]
                egos += [
                    canonicalise(read_log(Path(f).read_bytes(), "mcap", IDENTITY), IDENTITY, "x", None).ego
                    for f in report["files"]
                ]
        return egos, decisions

    drivers, _ = target_drivers(workspace, target)
    their_egos = [ego for _, ego in driver_egos(workspace, drivers)]
    theirs = stays_by_kind(their_egos)
    decisions = workspace.read_table("analysis", "decisions")
    their_headways = lag_headways(decisions[decisions["driver_id"].astype(str).isin(drivers)])
    egos, my_decisions = driven({})
    my_headways = agent_headways(my_decisions)
    lag = calibrated_headways(their_headways, my_headways)
    if lag:  # the stays with the headway drawn: waiting for it lengthens them, and the dwell must not count that twice
        egos, _ = driven(lag)
    mine = stays_by_kind(egos)
    kinds = [k for k in theirs if len(theirs[k]) >= MIN_STAYS and len(mine.get(k, [])) >= MIN_STAYS]
    result = {
        **setting,
        "seeds": list(seeds),
        "draws": {k: deconvolved_dwell(theirs[k], mine[k]) for k in kinds},
        "stays": {
            k: {
                "drivers": len(theirs[k]),
                "drivers_median_s": float(np.median(theirs[k])),
                "agent": len(mine[k]),
                "agent_median_s": float(np.median(mine[k])),
            }
            for k in kinds
        },
        "lag_draws": lag,
        "headways": {
            side: {
                "drivers": len(their_headways[side]),
                "drivers_median_s": float(np.median(their_headways[side])),
                "agent": len(my_headways.get(side, [])),
                "agent_median_s": float(np.median(my_headways[side])) if my_headways.get(side) else None,
            }
            for side in their_headways
        },
        "note": (
            f"calibrated on drive seeds {', '.join(map(str, seeds))} ({calibration_key(setting)}) against "
            f"{len(their_egos)} recordings of {', '.join(drivers)}; kinds with fewer than {MIN_STAYS} stays of "
            f"either keep the floor, sides with fewer than {MIN_HEADWAYS} of the agent's changes in front of a "
            f"near follower (or too few of the drivers' presses) the floors alone"
        ),
    }
    path = run_dir(workspace, run_id) / CALIBRATION_FILE
    stored = json.loads(path.read_text()) if path.exists() else {}
    stored[calibration_key(setting)] = result
    atomic_write_json(path, stored)
    return result
