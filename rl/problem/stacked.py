"""A fleet's environments stepped together: K agents' vectorised environments as one batch.

`stack_envs` takes each agent's own environments (`rl.problem.env.make_vec_env`) and
returns one object whose `step` takes actions (K, n) and returns arrays (K, n, ...).
Recorded scenes (`VecReplayEnv`, the default formulation) are stepped as one numpy
batch of K x n environments (`StackedReplayEnvs`): one transition, one reward, one
observation for the whole fleet instead of K. Each agent keeps its own recorded
approaches, generator and episode counters, and computes exactly what it computes
alone: every operation is row by row, and each agent's generator draws the same
numbers in the same order (its finished environments' new starts, in environment
order, once per step). Other formulations (synthetic scenes, whose reward reads
each agent's own lines) are stepped agent by agent (`LoopedEnvs`).

The agents' environment objects stay the source of their checkpoints: `scatter()`
writes the batch's state back into them (`rl.learners.dqn.episode_state` reads them). A single agent (the
fleet of one, `DQNTrainer`) steps its own environments (`OneAgentEnvs`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from rl.problem.env import VecLaneChangeEnv, VecReplayEnv
from rl.problem.rewards import TERMS
from rl.problem.scene import Scene

#: What `step` returns per environment, besides the named reward terms.
STEP_KEYS = ("obs", "final_obs", "reward", "terminated", "truncated", "reached_leader")


def _split(out: dict[str, Any], k: int) -> dict[str, Any]:
    """A step's flat (K * n, ...) arrays as (K, n, ...)."""
    res = {key: out[key].reshape((k, -1) + out[key].shape[1:]) for key in STEP_KEYS}
    res["terms"] = {t: np.asarray(out["terms"][t]).reshape(k, -1) for t in TERMS}
    return res


class LoopedEnvs:
    """Each agent's environments stepped in turn (any formulation)."""

    def __init__(self, envs: list[VecLaneChangeEnv | VecReplayEnv]) -> None:
        self.envs = envs

    def step(self, actions: np.ndarray) -> dict[str, Any]:
        outs = [e.step(a) for e, a in zip(self.envs, actions)]
        res: dict[str, Any] = {key: np.stack([o[key] for o in outs]) for key in STEP_KEYS}
        res["terms"] = {t: np.stack([np.broadcast_to(o["terms"][t], o["reward"].shape) for o in outs]) for t in TERMS}
        return res

    def scatter(self, agents: list[int] | None = None) -> None:
        """Nothing to do: the agents' environments are stepped themselves."""


class OneAgentEnvs:
    """One agent's environments with the agent axis added (K = 1): its arrays as (1, n, ...) views.

    The reward terms are passed on as they are (a number or (n,)): they broadcast over (1, n).
    """

    def __init__(self, env: VecLaneChangeEnv | VecReplayEnv) -> None:
        self.env = env

    def step(self, actions: np.ndarray) -> dict[str, Any]:
        out = self.env.step(actions[0])
        res: dict[str, Any] = {key: out[key][None] for key in STEP_KEYS}
        res["terms"] = out["terms"]
        return res

    def scatter(self, agents: list[int] | None = None) -> None:
        """Nothing to do: the agent's environments are stepped themselves."""


class StackedReplayEnvs(VecReplayEnv):
    """K agents' `VecReplayEnv`s as one `VecReplayEnv` over K x n environments.

    The agents' recorded states are concatenated, each agent's indices offset into
    its own block; only starting afresh differs from one agent's environments: each
    agent's finished environments draw their starts from that agent's generator.
    """

    def __init__(self, envs: list[VecReplayEnv]) -> None:
        self.envs = envs
        self.config = envs[0].config
        self.n = envs[0].num_envs
        self.num_envs = self.n * len(envs)
        self.sizes = np.array([len(e.t_rel) for e in envs])
        self.offset = np.r_[0, np.cumsum(self.sizes)[:-1]]
        self.states = Scene.concat([e.states for e in envs])
        self.t_rel = np.concatenate([e.t_rel for e in envs])
        self.no_press = np.concatenate([e.no_press for e in envs])
        self.last = np.concatenate([e.last + o for e, o in zip(envs, self.offset)])
        self.index = np.concatenate([e.index + o for e, o in zip(envs, self.offset)])
        self.late = np.concatenate([e.late for e in envs])
        self.steps = np.concatenate([e.steps for e in envs])
        self.scene = Scene.concat([e.scene for e in envs])

    @staticmethod
    def supports(envs: list[Any]) -> bool:
        """Whether `envs` can share one batch: all replaying, same settings but the lines, which
        the `decisions` reward does not read."""
        if not envs or not all(type(e) is VecReplayEnv for e in envs):
            return False
        first = envs[0].config
        return first.reward.name == "decisions" and all(
            replace(e.config, lines=first.lines) == first and e.num_envs == envs[0].num_envs for e in envs
        )

    def _draw_starts(self, idx: np.ndarray) -> np.ndarray:
        agent = idx // self.n
        starts = np.empty(len(idx), np.int64)
        bounds = np.r_[0, np.flatnonzero(np.diff(agent)) + 1, len(idx)]  # idx is sorted: one run per agent
        for lo, hi in zip(bounds[:-1], bounds[1:]):
            k = agent[lo]
            starts[lo:hi] = self.envs[k].rng.integers(self.sizes[k], size=hi - lo) + self.offset[k]
        return starts

    def step(self, actions: np.ndarray) -> dict[str, Any]:
        return _split(super().step(np.asarray(actions).reshape(-1)), len(self.envs))

    def scatter(self, agents: list[int] | None = None) -> None:
        """Write each agent's (or `agents`') slice of the batch back into its own environments."""
        for k in range(len(self.envs)) if agents is None else agents:
            e = self.envs[k]
            rows = slice(k * self.n, (k + 1) * self.n)
            e.index = self.index[rows] - self.offset[k]
            e.late, e.steps = self.late[rows].copy(), self.steps[rows].copy()
            e.scene = self.scene.take(rows)


def stack_envs(envs: list[Any]) -> StackedReplayEnvs | LoopedEnvs | OneAgentEnvs:
    """One batch over the agents' environments where they allow it, else a loop over them (one agent's as they are)."""
    if len(envs) == 1:
        return OneAgentEnvs(envs[0])
    return StackedReplayEnvs(envs) if StackedReplayEnvs.supports(envs) else LoopedEnvs(envs)
