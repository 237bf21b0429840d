"""Evaluation against the drivers' recorded decisions (not the training distribution).

For each policy (the trained agent, the greedy benchmark) and for the driver:

1. ``recall``: share of presses at which the policy says TO CHANGE (the study's
   "accuracy" compares decisions at the drivers' lane-change states);
2. ``balanced_accuracy``: mean of recall and of the share of not-yet states at
   which it says NOT TO CHANGE;
3. timing: each recorded approach is replayed in time order and the first state
   where the policy says TO CHANGE is its change; if it has not changed by the
   press, the press scene moves on at constant speeds every ``dt_s`` (as in the
   environment) until it changes, reaches the leader or ``max_steps`` pass
   (then it "never" changes). ``timing_mae_s`` is the mean absolute difference to
   the press over the decisions where it changed, ``never_rate`` the share where it
   did not. A change at the first recorded state is censored: its error is at most
   the recorded window before the press.
4. ``medae_<indicator>``: median absolute difference between the indicator at the
   policy's change and the reference line at that speed (the study's Fig. 10),
   over the changes where the indicator is defined. The median, because the TTCs
   (t_f, t_nf) of slowly closing leaders run to minutes and a handful of them set the
   mean: ``mae_<indicator>`` (the mean) stays in the JSON beside it. `FIELDS` defines
   every figure; `evaluate --json` and evaluation.json carry it as ``fields``.

Decisions are skipped by the rule of `rl.problem.env.approaches_from_decisions`, counted
in ``skipped``. Pure functions: tables in, tables and dicts out.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import pandas as pd
import torch

from laneprint.reference import INDICATORS
from rl.learners.dqn import greedy_actions as q_greedy_actions
from rl.problem.env import Approach, EnvConfig, observation
from rl.baselines.greedy import greedy_actions
from rl.problem.rewards import CHANGE
from rl.problem.scene import Scene, indicators

Policy = Callable[[Scene], np.ndarray]


def agent_policy(net: torch.nn.Module, cfg: EnvConfig) -> Policy:
    """The trained agent: argmax Q over the study's normalised observation."""
    return lambda scene: q_greedy_actions(net, observation(scene, cfg))


def greedy_policy(cfg: EnvConfig) -> Policy:
    """The study's greedy benchmark with the same reference lines."""
    return lambda scene: greedy_actions(indicators(scene, cfg.far_follower_m, cfg.range_m), cfg.lines, dt=cfg.dt_s)


def _indicator_frame(scene: Scene, cfg: EnvConfig) -> pd.DataFrame:
    ind = indicators(scene, cfg.far_follower_m, cfg.range_m)
    ref = cfg.lines.at(ind.v_e)
    df = pd.DataFrame({"v_e_mps": ind.v_e, "t_f_s": ind.t_f, "t_nf_s": ind.t_nf, "dv_nb_mps": ind.dv_nb})
    for k, _col in zip(INDICATORS, ("t_f_s", "t_nf_s", "dv_nb_mps")):
        df[f"{k}_ref"] = ref[k]
    return df


def replay_changes(policy: Policy, approaches: list[Approach], cfg: EnvConfig) -> pd.DataFrame:
    """When the policy first changes in each replayed approach, and the scene then.

    One row per approach: decision_id, driver_id, press_t_s, change_t_s (NaN if never),
    recorded (bool: the change falls on a recorded state), and the indicators there.
    """
    if not approaches:
        return pd.DataFrame(columns=["decision_id", "driver_id", "press_t_s", "change_t_s", "recorded"])
    all_scenes = Scene.concat([a.scene for a in approaches])
    acts = policy(all_scenes)
    bounds = np.cumsum([0] + [len(a) for a in approaches])
    change_t = np.full(len(approaches), np.nan)
    recorded = np.zeros(len(approaches), bool)
    at_change: list[Scene | None] = [None] * len(approaches)
    for j, a in enumerate(approaches):
        hits = np.flatnonzero(acts[bounds[j] : bounds[j + 1]] == CHANGE)
        if len(hits):
            change_t[j] = a.t_s[hits[0]]
            recorded[j] = True
            at_change[j] = a.scene.take(slice(hits[0], hits[0] + 1))
    # extrapolate the press scene of every approach not yet changed
    todo = np.flatnonzero(~recorded)
    if len(todo):
        scene = Scene.concat([approaches[j].scene.take(slice(-1, None)) for j in todo])
        alive = np.ones(len(todo), bool)
        for k in range(1, cfg.max_steps + 1):
            scene.advance(cfg.dt_s)
            gap_f = np.where(scene.f_present, scene.x_f - scene.x_e - scene.hl_f, np.inf)
            alive &= gap_f > 0
            if not alive.any():
                break
            idx = np.flatnonzero(alive)
            hit = policy(scene.take(idx)) == CHANGE
            for i in idx[hit]:
                j = todo[i]
                change_t[j] = approaches[j].press_t_s + k * cfg.dt_s
                at_change[j] = scene.take(slice(i, i + 1))
            alive[idx[hit]] = False
    rows = pd.DataFrame(
        {
            "decision_id": [a.decision_id for a in approaches],
            "driver_id": [a.driver_id for a in approaches],
            "press_t_s": [a.press_t_s for a in approaches],
            "change_t_s": change_t,
            "recorded": recorded,
        }
    )
    changed = [s for s in at_change if s is not None]
    ind = _indicator_frame(Scene.concat(changed), cfg) if changed else None
    cols = ["v_e_mps", "t_f_s", "t_nf_s", "dv_nb_mps", "t_f_ref", "t_nf_ref", "dv_nb_ref"]
    for c in cols:
        rows[c] = np.nan
    if ind is not None:
        mask = np.array([s is not None for s in at_change])
        rows.loc[mask, cols] = ind[cols].to_numpy()
    rows["timing_error_s"] = rows["change_t_s"] - rows["press_t_s"]
    return rows


#: What each figure of an evaluation summary row is (the Results page and `--json` show these definitions).
FIELDS = {
    "recall": "share of the driver's presses at which the policy says to change",
    "specificity": "share of the not-yet states before a press at which the policy keeps its lane",
    "balanced_accuracy": "mean of recall and specificity",
    "timing_mae_s": "mean |time of the policy's first change - time of the driver's press| [s], over the "
    "decisions where it changed",
    "timing_bias_s": "mean (time of the policy's first change - time of the press) [s]; negative: earlier",
    "never_rate": "share of the decisions where the policy never changed",
    **{
        f"medae_{k}": f"median |{k} at the policy's change - the reference line's {k} at that speed| [{u}], over "
        "the changes where it is defined; a median because TTCs of slowly closing leaders run to "
        "minutes and a few of them would set a mean"
        for k, u in (("t_f", "s"), ("t_nf", "s"), ("dv_nb", "m/s"))
    },
    **{
        f"mae_{k}": f"mean |{k} at the change - the reference line's {k}| [{u}] (dominated by minutes-long TTCs; "
        f"see medae_{k})"
        for k, u in (("t_f", "s"), ("t_nf", "s"), ("dv_nb", "m/s"))
    },
}


def _mae(rows: pd.DataFrame) -> dict[str, float | None]:
    out = {}
    for k, col in zip(INDICATORS, ("t_f_s", "t_nf_s", "dv_nb_mps")):
        err = (rows[col] - rows[f"{k}_ref"]).abs().dropna()
        out[f"medae_{k}"] = float(err.median()) if len(err) else None
        out[f"mae_{k}"] = float(err.mean()) if len(err) else None
        out[f"n_mae_{k}"] = int(len(err))
    return out


def state_table(approaches: list[Approach], cfg: EnvConfig) -> pd.DataFrame:
    """Every recorded state (not-yet and press) with its label and indicators."""
    if not approaches:
        return pd.DataFrame()
    scene = Scene.concat([a.scene for a in approaches])
    df = _indicator_frame(scene, cfg)
    df.insert(0, "decision_id", np.concatenate([[a.decision_id] * len(a) for a in approaches]))
    df.insert(1, "driver_id", np.concatenate([[a.driver_id] * len(a) for a in approaches]))
    df.insert(2, "t_s", np.concatenate([a.t_s for a in approaches]))
    df.insert(3, "press_t_s", np.concatenate([[a.press_t_s] * len(a) for a in approaches]))
    df.insert(4, "label", np.concatenate([["keep"] * (len(a) - 1) + ["change"] for a in approaches]))
    return df


def evaluate_policies(
    policies: dict[str, Policy], approaches: list[Approach], cfg: EnvConfig, skipped: dict[str, int] | None = None
) -> dict:
    """Side-by-side figures for each policy and for the driver.

    Returns {"summary": [one dict per policy + 'driver'], "states": DataFrame with an
    ``action_<name>`` column per policy (0 change / 1 keep), "changes": DataFrame of
    `replay_changes` rows with a ``who`` column, "skipped": counts}.
    """
    states = state_table(approaches, cfg)
    scene = Scene.concat([a.scene for a in approaches]) if approaches else None
    is_press = (states["label"] == "change").to_numpy() if len(states) else np.zeros(0, bool)
    summary, changes = [], []
    for name, policy in policies.items():
        acts = policy(scene) if scene is not None else np.zeros(0, int)
        states[f"action_{name}"] = acts
        said_change = acts == CHANGE
        recall = float(said_change[is_press].mean()) if is_press.any() else None
        spec = float((~said_change[~is_press]).mean()) if (~is_press).any() else None
        rows = replay_changes(policy, approaches, cfg)
        rows.insert(0, "who", name)
        changes.append(rows)
        err = rows["timing_error_s"].dropna()
        summary.append(
            {
                "who": name,
                "recall": recall,
                "specificity": spec,
                "balanced_accuracy": None if recall is None or spec is None else (recall + spec) / 2,
                "timing_mae_s": float(err.abs().mean()) if len(err) else None,
                "timing_bias_s": float(err.mean()) if len(err) else None,
                "never_rate": float(rows["change_t_s"].isna().mean()) if len(rows) else None,
                **_mae(rows),
            }
        )
    # the driver: changes exactly at the presses
    if approaches:
        press = Scene.concat([a.scene.take(slice(-1, None)) for a in approaches])
        drv = _indicator_frame(press, cfg)
        drv.insert(0, "decision_id", [a.decision_id for a in approaches])
        drv.insert(1, "driver_id", [a.driver_id for a in approaches])
        drv.insert(2, "press_t_s", [a.press_t_s for a in approaches])
        drv.insert(3, "change_t_s", drv["press_t_s"])
        drv.insert(4, "recorded", True)
        drv["timing_error_s"] = 0.0
        drv.insert(0, "who", "driver")
        changes.append(drv)
        summary.append(
            {
                "who": "driver",
                "recall": 1.0,
                "specificity": 1.0,
                "balanced_accuracy": 1.0,
                "timing_mae_s": 0.0,
                "timing_bias_s": 0.0,
                "never_rate": 0.0,
                **_mae(drv),
            }
        )
    return {
        "summary": summary,
        "states": states,
        "changes": pd.concat(changes, ignore_index=True) if changes else pd.DataFrame(),
        "skipped": dict(skipped or {}),
        "n_decisions": len(approaches),
        "n_states": int(len(states)),
    }
