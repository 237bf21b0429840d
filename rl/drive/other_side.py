"""Experiment (issue 19 item 2): teach the per-side agent "keep" about the side the driver did not take.

    python -m rl.drive.other_side BASE_RUN NEW_RUN -w WORKSPACE

An approach carries only the scene of the lane the driver went to, so an agent asked
about each side of a middle lane (`rl.drive.loop.choose_side`) never learnt to keep
about the other one. Here, for every recorded approach of the base run's target from a
middle lane, the other side's scene at each of its states (read from the stored log as
the live loop reads SUMO: `live_scene`) becomes a no-press approach: a change there
costs as a change far too early (-1, the `decisions` reward's floor), a keep earns 0,
and it ends at its last state (no run-on past a press). The agent is trained with the
base run's settings and seed on both; its weights go into a copy of the base run's
folder, so `laneprint drive NEW_RUN --lanes 3` and `python -m rl.drive.sides NEW_RUN`
read it. An experiment, not a formulation: only the `decisions` reward on recorded
scenes, outside `crossval` (measured in SUMO.md, "Three lanes").
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from typing import Any

import numpy as np
import torch

from laneprint.errors import UserError
from laneprint.simulator.sumo.traffic import VehicleState
from laneprint.workspace import Workspace
from rl.drive.loop import live_scene
from rl.learners.dqn import DQNTrainer
from rl.problem.env import Approach, EnvConfig, VecReplayEnv
from rl.problem.rewards import CHANGE
from rl.problem.scene import Scene
from rl.drive.store import load_run_config
from rl.runs import Target, recorded_approaches, run_dir
from rl.settings import DQNSettings

FAR = 1e6  # [s] "the press" of a no-press approach: every change is far too early


class NoPressReplay(VecReplayEnv):
    """VecReplayEnv whose approaches flagged `no_press` end at their last state instead of running on."""

    def __init__(self, config: EnvConfig, approaches: list[Approach], num_envs: int, rng: np.random.Generator,
                 no_press: np.ndarray) -> None:
        super().__init__(config, approaches, num_envs, rng)
        lengths = np.array([len(a) for a in approaches])
        self.no_press_state = np.repeat(no_press, lengths)
        self.t_rel[self.no_press_state] = -FAR  # their press is FAR after every state

    def step(self, actions: np.ndarray) -> dict[str, Any]:
        at_last = (self.late == 0) & (self.index >= self.last[self.index])
        ends = at_last & self.no_press_state[self.index] & (np.asarray(actions) != CHANGE)
        out = super().step(actions)
        if ends.any():  # super() ran these on; the reward of keeping was 0 either way (t_from_press -FAR)
            idx = np.flatnonzero(ends)
            out["truncated"] = out["truncated"] | ends
            self.index[idx] = self._draw_starts(idx)
            self.late[idx] = 0.0
            self.steps[idx] = 0
            self.scene.put(idx, self.states.take(self.index[idx]))
            out["obs"] = self.observe()
        return out


def other_side_approaches(ws: Workspace, approaches: list[Approach]) -> list[Approach]:
    """The other side's scenes of every approach from the middle lane of a three-lane log."""
    dec = ws.read_table("analysis", "decisions")
    times_of = {a.decision_id: set(np.round(a.t_s, 6)) for a in approaches}
    dec = dec[dec["decision_id"].astype(str).isin(times_of) & (dec["ego_lane"] == 1)]
    out = []
    for rid, group in dec.groupby("recording_id"):
        _, ego, traffic = ws.load_recording(rid)
        by_t = {round(t, 6): g for t, g in traffic.groupby(traffic["t_s"].round(6))}
        times = ego["t_s"].to_numpy()
        for did, rows in group.sort_values("t_s").groupby("decision_id"):
            scenes, ts = [], []
            for r in rows.itertuples():
                if round(float(r.t_s), 6) not in times_of[str(did)]:
                    continue  # not a state of the replayed approach
                k = int(np.argmin(np.abs(times - float(r.t_s))))
                e = ego.iloc[k]
                me = VehicleState(float(e["ego_x_m"]), float(e["ego_v_mps"]), 1, float(e["ego_length_m"]))
                g = by_t.get(round(float(times[k]), 6), traffic.iloc[:0])
                others = {str(v.vehicle_id): VehicleState(float(v.x_m), float(v.v_mps), int(v.lane), float(v.length_m))
                          for v in g.itertuples()}
                other = 2 - int(r.target_lane)  # the middle lane's other neighbour
                scenes.append(live_scene(me, others, other)[0])
                ts.append(float(r.t_s))
            if scenes:
                out.append(Approach(f"{did}:other", str(rows["driver_id"].iloc[0]), np.array(ts),
                                    Scene.concat(scenes)))
    return out


def train_other_side(ws: Workspace, base: str, new: str) -> dict[str, Any]:
    """Train `new` on `base`'s approaches plus the other sides' no-press approaches; a summary."""
    config = load_run_config(ws, base)
    cfg = EnvConfig.from_dict(config["env"])
    if cfg.scenes != "recorded" or cfg.reward.name != "decisions":
        raise UserError(f"run {base!r} is not a 'decisions' run on recorded scenes")
    if run_dir(ws, new).exists():
        raise UserError(f"run {new!r} exists already")
    settings = DQNSettings.from_dict(config["dqn"])
    approaches = recorded_approaches(ws, Target(**config["target"]))
    other = other_side_approaches(ws, approaches)
    if not other:
        raise UserError(f"no approach of run {base!r}'s target starts in a middle lane")
    both = approaches + other
    trainer = DQNTrainer(cfg, settings, both)
    s = trainer.settings
    trainer.envs = NoPressReplay(cfg, both, s.num_envs, np.random.default_rng([s.seed, 1]),
                                 np.r_[np.zeros(len(approaches), bool), np.ones(len(other), bool)])
    trainer.obs = trainer.envs.observe()
    trainer.train()
    folder = run_dir(ws, new)
    shutil.copytree(run_dir(ws, base), folder)
    for name in ("checkpoint.pt", "evaluation.json", "eval_states.parquet", "eval_changes.parquet"):
        (folder / name).unlink(missing_ok=True)
    torch.save(trainer.policy_net.state_dict(), folder / "weights.pt")
    experiment = {"base_run": base, "approaches": len(approaches), "other_side_approaches": len(other),
                  "other_side_states": int(sum(len(a) for a in other)), "episodes": trainer.episodes_done}
    (folder / "config.json").write_text(json.dumps({**config, "run_id": new, "other_side": experiment}, indent=1))
    return {"run_id": new, "base_run": base, "approaches": len(approaches), "other_side_approaches": len(other),
            "episodes": trainer.episodes_done, "wall_s": round(trainer.wall_s, 1)}


def main(argv: list[str] | None = None) -> int:
    """Command line: BASE_RUN NEW_RUN -w WORKSPACE."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base_run")
    ap.add_argument("new_run")
    ap.add_argument("-w", "--workspace", default="workspace")
    args = ap.parse_args(argv)
    try:
        print(json.dumps(train_other_side(Workspace(args.workspace), args.base_run, args.new_run)))
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
