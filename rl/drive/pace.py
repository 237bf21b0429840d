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


def step_advantages(ego: pd.DataFrame, traffic: pd.DataFrame, net: torch.nn.Module, cfg: EnvConfig) -> np.ndarray:
    """Per agent step of a recording: the best advantage over its neighbouring lanes (-inf: none asked)."""
    best = None
    for side in (1, -1):
        steps, scene = decision_steps(ego, traffic, cfg, side=side)
        dec = decide(net, cfg, steps, scene)
        adv = np.nan_to_num((dec["q_change"] - dec["q_keep"]).to_numpy(dtype=float), nan=-np.inf)
        best = adv if best is None else np.maximum(best, adv)
    return best


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


def pace_threshold(workspace: Workspace, drivers: list[str], net: torch.nn.Module, cfg: EnvConfig) -> dict[str, Any]:
    """The threshold for `drivers` (see the module doc) with the figures it rests on."""
    cat = workspace.recordings()
    rids = cat.loc[cat["driver_id"].astype(str).isin(drivers), "recording_id"].astype(str).tolist()
    km, presses, adv = 0.0, 0, []
    for rid in rids:
        _, ego, traffic = workspace.load_recording(rid)
        if len(ego) < 2:
            continue
        a = step_advantages(ego, traffic, net, cfg)
        adv.append(a)
        steps = pd.DataFrame({"t_s": float(ego["t_s"].min()) + cfg.dt_s * np.arange(len(a))})
        presses += len(driver_presses(ego, steps, cfg.dt_s))
        x = ego["ego_x_m"].to_numpy(dtype=float)
        km += float(np.nanmax(x) - np.nanmin(x)) / 1000.0
    if not adv or presses == 0 or km <= 0:
        return {"min_advantage": 0.0, "note": "no recording with presses of the target's drivers: the agent as trained",
                "recordings": len(adv), "presses": presses, "km": km}
    tau, counts = lowest_threshold(adv, presses)
    return {"min_advantage": tau, "recordings": len(adv), "km": round(km, 2), "presses": presses,
            "presses_per_km": presses / km, "onsets_per_km_at_0": counts[0.0] / km, "onsets_per_km": counts[tau] / km,
            "note": (f"replayed along {len(adv)} recordings of {', '.join(drivers)}: the agent starts wanting a change "
                     f"{counts[0.0] / km:.2f} times per km as trained, {counts[tau] / km:.2f} with an advantage of at "
                     f"least {tau:g}; they pressed {presses / km:.2f} times per km"
                     + ("" if tau > 0 or counts[0.0] <= presses else
                        f" (more onsets than presses, {counts[0.0]} against {presses}, but not beyond chance)"))}
