"""The advantage an agent's own change needs so that it changes lane about as often as its drivers.

An agent judged state by state and asked every 0.5 s changes lane wherever a state reads as a
press. Where drivers follow for tens of seconds and wait for a gap (SUMO's `acceptance` family),
one such state in ten is enough to change 1.5-2.8 times as often as they did (README, issue 19).
So the agent is replayed along the target drivers' own recordings: at every agent step, each
neighbouring lane is asked as `drive` asks it, and the step's advantage is the best
Q(change) - Q(keep). An *onset* is a step whose advantage reaches the threshold after one that
did not: the agent starting to want a change. The threshold is the smallest of `GRID` whose onsets
per km do not exceed the drivers' presses per km; 0 (the agent as trained) when its onsets at 0 do
not exceed the presses beyond chance (`exceeds`: both are counts over the same kilometres, so a
one-sided exact test at `SIGNIFICANCE`). Without that test a 4 % excess at 0 on the shipped study
(156 onsets against 150 Aggressive presses) set the threshold at 1.3, where the curve, which rises
before it falls, next came under the presses, and out of its world the Aggressive agent made almost
none of its changes itself (README, 'Driving like its drivers').

**By side** (`by="side"`, `drive --pace-by side`): each side has its own threshold, its onsets to
that side against the drivers' presses to that side. Pooled, the presses to one side pay for onsets
to the other: along study 647's recordings, at the pooled threshold, the agents start wanting a
change to the left 1.4-1.7 times as often as their drivers pressed left and to the right 0.3-0.6
times as often as they pressed right, while on two lanes every change to the left is followed by one
back, so the side with the faster pace sets the rate (README, issue 19, 'The pace by side'). It is
not the default: out of its world it takes the shipped study's Aggressive agent below half of SUMO's
model's rate on three lanes (0.51 -> 0.44), where the pooled pace stays inside.

It uses the drivers' recordings only (no closed-loop drive, no held-out data), like the rest of
the assistant's numbers (`rl.drive.heldback`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import torch
from scipy.stats import binomtest

from laneprint.workspace import Workspace
from rl.deploy.annotate import decide, decision_steps, driver_presses
from rl.problem.env import EnvConfig

#: Thresholds tried, in units of the agent's Q-values.
GRID: np.ndarray = np.round(np.arange(0.0, 3.0001, 0.05), 2)
#: The agent as trained is held to its drivers' pace only when its onsets exceed their presses at this level.
SIGNIFICANCE = 0.05


#: How the threshold is read: one for both sides ('pooled', the default) or one per side ('side').
PACE_BY: tuple[str, ...] = ("pooled", "side")
SIDES: dict[str, int] = {"left": 1, "right": -1}  # side -> lane offset (lane 0 is the rightmost)


def side_advantages(
    ego: pd.DataFrame, traffic: pd.DataFrame, net: torch.nn.Module, cfg: EnvConfig
) -> dict[str, np.ndarray]:
    """Per agent step of a recording and per side: Q(change) - Q(keep) of the lane on that side (-inf: none)."""
    out = {}
    for name, side in SIDES.items():
        steps, scene = decision_steps(ego, traffic, cfg, side=side)
        dec = decide(net, cfg, steps, scene)
        out[name] = np.nan_to_num((dec["q_change"] - dec["q_keep"]).to_numpy(dtype=float), nan=-np.inf)
    return out


def onsets(advantages: list[np.ndarray], threshold: float) -> int:
    """Steps whose advantage reaches `threshold` after a step (or the start) that did not."""
    n = 0
    for a in advantages:
        want = a >= threshold
        n += int((want & ~np.r_[False, want[:-1]]).sum())
    return n


def exceeds(onsets_n: int, presses: int, level: float = SIGNIFICANCE) -> bool:
    """Whether `onsets_n` exceed `presses` (counts over the same kilometres) beyond chance: under equal
    rates each of the `onsets_n + presses` events is an onset with probability 1/2, and the one-sided
    exact binomial test rejects that at `level`."""
    return onsets_n > presses and binomtest(onsets_n, onsets_n + presses, 0.5, alternative="greater").pvalue < level


def lowest_threshold(advantages: list[np.ndarray], presses: int) -> tuple[float, dict[float, int]]:
    """The smallest threshold of `GRID` with at most `presses` onsets (the largest when none), or 0 when
    the agent as trained does not exceed them beyond chance (`exceeds`); and the onsets at each."""
    counts = {float(t): onsets(advantages, float(t)) for t in GRID}
    if not exceeds(counts[0.0], presses):
        return 0.0, counts
    ok = [t for t, n in counts.items() if n <= presses]
    return (min(ok) if ok else float(GRID[-1])), counts


def pace_threshold(
    workspace: Workspace, drivers: list[str], net: torch.nn.Module, cfg: EnvConfig, by: str = "pooled"
) -> dict[str, Any]:
    """The threshold for `drivers` (see the module doc) with the figures it rests on: `min_advantage`
    (one for both sides) and, by side, `min_advantage_by_side` ('left', 'right'). By side needs every
    press's side (`lc_direction`); where one is missing the threshold is pooled, and the note says so."""
    if by not in PACE_BY:
        raise ValueError(f"pace by {by!r}: choose one of {', '.join(PACE_BY)}")
    cat = workspace.recordings()
    rids = cat.loc[cat["driver_id"].astype(str).isin(drivers), "recording_id"].astype(str).tolist()
    km, adv = 0.0, []
    presses = {"left": 0, "right": 0, "unknown": 0}
    for rid in rids:
        _, ego, traffic = workspace.load_recording(rid)
        if len(ego) < 2:
            continue
        a = side_advantages(ego, traffic, net, cfg)
        adv.append(a)
        steps = pd.DataFrame({"t_s": float(ego["t_s"].min()) + cfg.dt_s * np.arange(len(a["left"]))})
        for d in driver_presses(ego, steps, cfg.dt_s)["direction"]:
            presses[d if d in SIDES else "unknown"] += 1
        x = ego["ego_x_m"].to_numpy(dtype=float)
        km += float(np.nanmax(x) - np.nanmin(x)) / 1000.0
    if not adv or sum(presses.values()) == 0 or km <= 0:
        return {
            "min_advantage": 0.0,
            "by": "pooled",
            "note": "no recording with presses of the target's drivers: the agent as trained",
            "recordings": len(adv),
            "presses": sum(presses.values()),
            "km": km,
        }
    out = thresholds(adv, presses, km, by)
    out["note"] = f"replayed along {len(adv)} recordings of {', '.join(drivers)}: {out['note']}"
    return out


def thresholds(
    adv: list[dict[str, np.ndarray]], presses: dict[str, int], km: float, by: str = "pooled"
) -> dict[str, Any]:
    """The pace from each recording's advantages by side (`side_advantages`) and the presses to each side
    ('left', 'right', 'unknown') over `km`: `min_advantage` pooled and, `by` side, `min_advantage_by_side`."""
    total = sum(presses.values())
    tau, counts = lowest_threshold([np.maximum(a["left"], a["right"]) for a in adv], total)
    out: dict[str, Any] = {
        "min_advantage": tau,
        "by": "pooled",
        "recordings": len(adv),
        "km": round(km, 2),
        "presses": total,
        "presses_per_km": total / km,
        "onsets_per_km_at_0": counts[0.0] / km,
        "onsets_per_km": counts[tau] / km,
    }
    note = (
        f"the agent starts wanting a change {counts[0.0] / km:.2f} times per km as trained, "
        f"{counts[tau] / km:.2f} with an advantage of at least {tau:g}; they pressed {total / km:.2f} times per km"
        + (
            ""
            if tau > 0 or counts[0.0] <= total
            else f" (more onsets than presses, {counts[0.0]} against {total}, but not beyond chance)"
        )
    )
    if by == "side" and presses.get("unknown"):
        note += f"; pooled: {presses['unknown']} of the presses have no side (lc_direction)"
    elif by == "side":
        out["by"], out["min_advantage_by_side"], parts = "side", {}, []
        for side in SIDES:
            t_side, c_side = lowest_threshold([a[side] for a in adv], presses[side])
            out["min_advantage_by_side"][side] = t_side
            parts.append(
                f"to the {side} {c_side[0.0] / km:.2f} as trained, {c_side[t_side] / km:.2f} with at least "
                f"{t_side:g}, against {presses[side] / km:.2f} presses"
            )
        note = "by side, onsets per km " + "; ".join(parts)
    out["note"] = note
    return out
