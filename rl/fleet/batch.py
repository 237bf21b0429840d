"""Fleet training: many DQN agents trained together as one batched computation.

`FleetTrainer` runs `DQNTrainer`'s loop for K agents at once. Each agent keeps
everything that makes it itself: its settings and seed, its environments (its own
recorded approaches or lines), its random generator (drawn from in the same order
as `DQNTrainer` draws), its replay memory, epsilon and learning-rate schedules,
target copies and policy averaging, all counted in its own finished episodes.
Only the arithmetic is shared: the K networks are stacked (`rl.learners.batched`) so a
forward pass, a TD loss and an Adam step are a few batched tensor operations
instead of K small ones. An agent that reaches its episodes leaves the stack.

Per agent, a fleet computes what `DQNTrainer` computes with the same settings and
seed, up to floating-point summation order (`tests/rl/test_rl_fleet.py`), and its
checkpoints are `DQNTrainer.state_dict()`s: a fleet's agent resumes alone, and a
fleet resumes from its agents' checkpoints.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import torch

from rl.learners import batched
from rl.learners.dqn import (EpisodeStats, average_due, checkpoint_due, episode_row, episode_state, epsilon_at,
                             learning_rate_at, load_episode_state)
from rl.problem.env import Approach, EnvConfig, make_vec_env, observation_names, replayed_approaches
from rl.fleet.envs import stack_envs
from rl.problem.rewards import KEEP, TERMS
from rl.settings import DQNSettings

#: Settings that must be equal across a fleet (they fix tensor shapes or the shared update).
SHARED_SETTINGS = ("hidden", "num_envs", "batch_size", "gradient_steps", "buffer_size", "loss", "double_q",
                   "gamma", "max_grad_norm", "average_tau")


@dataclass
class FleetMember:
    """One agent of a fleet: what `DQNTrainer(env_config, settings, approaches)` would take."""

    env_config: EnvConfig
    settings: DQNSettings
    approaches: list[Approach] | None = None


@dataclass
class AgentState:
    """The per-agent half of a fleet: everything but the stacked tensors."""

    member: int  # index in the fleet's members
    settings: DQNSettings
    envs: Any
    rng: np.random.Generator
    stats: EpisodeStats
    obs: np.ndarray
    episodes_done: int = 0
    env_steps: int = 0
    updates: int = 0
    wall_s: float = 0.0
    averaging: bool = False
    losses: list[float] = field(default_factory=list)

    @property
    def finished(self) -> bool:
        return self.episodes_done >= self.settings.episodes

    def epsilon(self) -> float:
        return epsilon_at(self.settings, self.episodes_done)

    def learning_rate(self) -> float:
        return learning_rate_at(self.settings, self.episodes_done)

    def average_due(self) -> bool:
        return average_due(self.settings, self.episodes_done)


class StackedReplay:
    """K replay memories in (K, size, ...) arrays, each with its own write position."""

    def __init__(self, k: int, size: int, n_obs: int) -> None:
        self.size = size
        self.obs = np.zeros((k, size, n_obs), np.float32)
        self.next_obs = np.zeros((k, size, n_obs), np.float32)
        self.actions = np.zeros((k, size), np.int64)
        self.rewards = np.zeros((k, size), np.float32)
        self.terminated = np.zeros((k, size), np.float32)
        self.pos = np.zeros(k, np.int64)
        self.full = np.zeros(k, bool)

    def __len__(self) -> int:
        return len(self.pos)

    def filled(self, j: int) -> int:
        return self.size if self.full[j] else int(self.pos[j])

    def filled_all(self) -> np.ndarray:
        """Transitions held by each memory (K,)."""
        return np.where(self.full, self.size, self.pos)

    def add(self, obs, next_obs, actions, rewards, terminated) -> None:
        """Add n transitions (K, n, ...) to every memory, each at its own write position."""
        n = actions.shape[1]
        idx = (self.pos[:, None] + np.arange(n)) % self.size
        rows = np.arange(len(self.pos))[:, None]
        self.obs[rows, idx], self.next_obs[rows, idx] = obs, next_obs
        self.actions[rows, idx], self.rewards[rows, idx], self.terminated[rows, idx] = actions, rewards, terminated
        self.full |= self.pos + n >= self.size
        self.pos = (self.pos + n) % self.size

    def sample(self, idx: np.ndarray) -> tuple[torch.Tensor, ...]:
        """The transitions idx (K, B) of each memory, as tensors (K, B, ...)."""
        rows = np.arange(idx.shape[0])[:, None]
        return (torch.from_numpy(self.obs[rows, idx]), torch.from_numpy(self.actions[rows, idx]),
                torch.from_numpy(self.rewards[rows, idx]), torch.from_numpy(self.next_obs[rows, idx]),
                torch.from_numpy(self.terminated[rows, idx]))

    def select(self, keep: np.ndarray) -> None:
        for name in ("obs", "next_obs", "actions", "rewards", "terminated", "pos", "full"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name)[keep]))

    def agent_state_dict(self, j: int) -> dict[str, Any]:
        """Memory j in `ReplayBuffer.state_dict()`'s format."""
        n = self.filled(j)
        return {"obs": torch.from_numpy(self.obs[j, :n].copy()), "next_obs": torch.from_numpy(self.next_obs[j, :n].copy()),
                "actions": torch.from_numpy(self.actions[j, :n].copy()),
                "rewards": torch.from_numpy(self.rewards[j, :n].copy()),
                "terminated": torch.from_numpy(self.terminated[j, :n].copy()),
                "pos": int(self.pos[j]), "full": bool(self.full[j])}

    def load_agent(self, j: int, s: dict[str, Any]) -> None:
        n = len(s["actions"])
        self.obs[j, :n], self.next_obs[j, :n] = s["obs"].numpy(), s["next_obs"].numpy()
        self.actions[j, :n], self.rewards[j, :n] = s["actions"].numpy(), s["rewards"].numpy()
        self.terminated[j, :n] = s["terminated"].numpy()
        self.pos[j], self.full[j] = int(s["pos"]), bool(s["full"])


def check_compatible(members: list[FleetMember]) -> None:
    """Raise ValueError unless the members can share one stack (same shapes, same update)."""
    first = members[0].settings
    n_obs = len(observation_names(members[0].env_config))
    for m in members[1:]:
        for name in SHARED_SETTINGS:
            if getattr(m.settings, name) != getattr(first, name):
                raise ValueError(f"a fleet's agents must share {name!r}: {getattr(m.settings, name)} vs {getattr(first, name)}")
        if len(observation_names(m.env_config)) != n_obs:
            raise ValueError("a fleet's agents must share the observation")


class FleetTrainer:
    """Trains `members` together; each agent's run is `DQNTrainer`'s (see the module doc).

    `train(on_episode, on_checkpoint, on_finish, should_stop, on_vector_step)`: the
    callbacks get the member index first: `on_episode(i, row)`, `on_checkpoint(i,
    state)` with a `DQNTrainer.state_dict()`, `on_finish(i, policy_state_dict,
    state)` once when agent i reaches its episodes; `on_vector_step(fleet)` returning
    True stops training.
    """

    def __init__(self, members: list[FleetMember], threads: int = 1,
                 states: list[dict[str, Any] | None] | None = None) -> None:
        if not members:
            raise ValueError("a fleet needs at least one agent")
        check_compatible(members)
        self.members = members
        self.threads = threads
        s0 = members[0].settings
        self.n_obs = len(observation_names(members[0].env_config))
        self.hidden = s0.hidden
        self.agents: list[AgentState] = []  # still training, in stack order
        self._finished: list[AgentState] = []
        for i, m in enumerate(members):
            s = m.settings.resolved_episodes(replayed_approaches(m.approaches, m.env_config) if m.approaches else 0) \
                if m.env_config.scenes == "recorded" else m.settings
            envs = make_vec_env(m.env_config, s.num_envs, np.random.default_rng([s.seed, 1]), m.approaches)
            self.agents.append(AgentState(i, s, envs, np.random.default_rng(s.seed), EpisodeStats(s.num_envs),
                                          envs.observe()))
        seeds = [a.settings.seed for a in self.agents]
        self.q = [p.requires_grad_(True) for p in batched.init_params(seeds, self.hidden, self.n_obs)]
        self.target = [p.detach().clone() for p in self.q]
        self.q_avg = [p.detach().clone() for p in self.q]
        self.adam = batched.StackedAdam(self.q)
        self.buffer = StackedReplay(len(members), s0.buffer_size, self.n_obs)
        self.env_steps = 0
        self.wall_s = 0.0
        self._stack_agents()
        for j, state in enumerate(states or []):
            if state is not None:
                self.load_agent_state(j, state)

    @property
    def settings(self) -> list[DQNSettings]:
        """Each member's settings, episodes resolved (in member order, finished agents included)."""
        return [a.settings for a in self._all]

    @property
    def episodes_done(self) -> list[int]:
        """Each member's finished episodes (in member order, finished and dropped agents included)."""
        return [a.episodes_done for a in self._all]

    @property
    def _all(self) -> list[AgentState]:
        return sorted(self.agents + self._finished, key=lambda a: a.member)

    # --- the loop ---------------------------------------------------------------------

    def train(self, on_episode: Callable[[int, dict], None] | None = None,
              on_checkpoint: Callable[[int, dict], None] | None = None,
              on_finish: Callable[[int, dict, dict], None] | None = None,
              should_stop: Callable[[], bool] | None = None,
              on_vector_step: Callable[["FleetTrainer"], bool] | None = None) -> "FleetTrainer":
        """Run until every agent has its episodes or `should_stop()` (see the class doc)."""
        torch.set_num_threads(self.threads)
        torch.set_flush_denormal(True)  # as DQNTrainer: Adam's decaying moments go denormal
        try:
            self._finish_done(on_finish)
            start = time.perf_counter() - self.wall_s
            while self.agents:
                if should_stop is not None and should_stop():
                    break
                self._vector_step(start, on_episode, on_checkpoint)
                self._finish_done(on_finish)
                self.wall_s = time.perf_counter() - start
                if on_vector_step is not None and on_vector_step(self):
                    break
        finally:
            torch.set_flush_denormal(False)
        return self

    def _stack_agents(self) -> None:
        """The training agents' environments, observations and running sums as (K, n) batches.

        Each agent's `stats` become views of its row, so the per-episode book-keeping and
        checkpoints read and reset them in place; `_sync_agents` hands back the rest.
        """
        self._envs = stack_envs([a.envs for a in self.agents])
        self._obs = np.stack([a.obs for a in self.agents]) if self.agents else None
        self._ret = np.stack([a.stats.ret for a in self.agents]) if self.agents else None
        self._length = np.stack([a.stats.length for a in self.agents]) if self.agents else None
        self._terms = {k: np.stack([a.stats.terms[k] for a in self.agents]) for k in TERMS} if self.agents else {}
        for j, a in enumerate(self.agents):
            a.stats.ret, a.stats.length = self._ret[j], self._length[j]
            a.stats.terms = {k: v[j] for k, v in self._terms.items()}

    def _sync_agents(self, only: int | None = None) -> None:
        """Write the batches' environment state and observations back into each training agent (or `only`)."""
        agents = range(len(self.agents)) if only is None else [only]
        self._envs.scatter(list(agents))
        for j in agents:
            self.agents[j].obs = self._obs[j].copy()

    def _vector_step(self, start: float, on_episode, on_checkpoint) -> None:
        s0 = self.agents[0].settings
        n = s0.num_envs
        # 1. act: greedy actions of all agents in one pass, then each agent's epsilon draws
        obs = self._obs
        with torch.inference_mode():
            greedy = batched.forward(self.q, torch.from_numpy(obs)).argmax(dim=2).numpy()
        starts = np.array([a.settings.learning_starts for a in self.agents])
        greedy[self.buffer.filled_all() < starts] = KEEP  # untrained: keep, as DQNTrainer
        epsilons = [a.epsilon() for a in self.agents]
        actions = np.empty(greedy.shape, np.int64)
        for j, a in enumerate(self.agents):
            explore = a.rng.random(n) < epsilons[j]
            actions[j] = np.where(explore, a.rng.integers(0, 2, n), greedy[j])
        # 2. step every agent's environments together, and store (the true last observation
        # of finished episodes, as DQNTrainer)
        out = self._envs.step(actions)
        self.buffer.add(obs, out["final_obs"], actions, out["reward"], out["terminated"].astype(np.float32))
        self._obs = out["obs"]
        for a in self.agents:
            a.env_steps += n
        self._ret += out["reward"]
        self._length += 1
        for k in TERMS:
            self._terms[k] += out["terms"][k]
        self.env_steps += n * len(self.agents)
        # 3. learn: agents whose memory holds `learning_starts` transitions
        learning = self.buffer.filled_all() >= starts
        if learning.any():
            for _ in range(s0.gradient_steps):
                self._update(learning)
        # 4. book-keeping of finished episodes, per agent
        wall = time.perf_counter() - start
        done = out["terminated"] | out["truncated"]
        for j in np.flatnonzero(done.any(axis=1)):
            self._episodes(j, self.agents[j], {k: out[k][j] for k in ("terminated", "truncated", "reached_leader")},
                           actions[j], epsilons[j], wall, on_episode, on_checkpoint)

    def _update(self, learning: np.ndarray) -> None:
        s0 = self.agents[0].settings
        k = len(self.agents)
        idx = np.zeros((k, s0.batch_size), np.int64)
        for j in np.flatnonzero(learning):  # each agent draws its batch from its own generator
            idx[j] = self.agents[j].rng.integers(0, self.buffer.filled(j), s0.batch_size)
        batch = self.buffer.sample(idx)
        losses = batched.td_losses(self.q, self.target, batch, s0.gamma, s0.loss, s0.double_q)
        mask = torch.from_numpy(learning)
        # weight gradients come back as transposed views (`batched.forward` multiplies by W^T): made
        # contiguous once, clipping and Adam's ~10 elementwise passes over them ran twice as fast
        grads = [g.contiguous() for g in torch.autograd.grad((losses * mask).sum(), self.q)]
        if s0.max_grad_norm:
            batched.clip_grad_norms(grads, s0.max_grad_norm)
        lr = torch.tensor([a.learning_rate() for a in self.agents], dtype=torch.float64)
        self.adam.step(self.q, grads, lr, mask)
        averaging = torch.tensor([a.averaging for a in self.agents]) & mask
        if bool(averaging.any()):
            w = (averaging.to(torch.float32) * s0.average_tau)
            with torch.no_grad():
                for p_avg, p in zip(self.q_avg, self.q):
                    p_avg.lerp_(p, w.reshape((-1,) + (1,) * (p.dim() - 1)))
        values = losses.detach().numpy()
        for j in np.flatnonzero(learning):
            a = self.agents[j]
            a.updates += 1
            a.losses.append(float(values[j]))

    def _episodes(self, j: int, a: AgentState, out: dict, actions: np.ndarray, eps: float, wall: float,
                  on_episode, on_checkpoint) -> None:
        s = a.settings
        st = a.stats
        done = out["terminated"] | out["truncated"]
        before = a.episodes_done
        for i in np.flatnonzero(done):
            if a.episodes_done >= s.episodes:
                break
            a.episodes_done += 1
            a.wall_s = wall
            if on_episode is not None:
                on_episode(a.member, episode_row(a.episodes_done, a.losses, st, i, eps, actions, out,
                                                 a.env_steps, wall))
                a.losses = []
            st.ret[i] = 0.0
            st.length[i] = 0
            for k in TERMS:
                st.terms[k][i] = 0.0
            if not a.averaging and a.average_due():
                self._copy(self.q_avg, self.q, j)
                a.averaging = True
            if a.episodes_done % s.target_update_episodes == 0:
                self._copy(self.target, self.q, j)
        if on_checkpoint is not None and checkpoint_due(s, before, a.episodes_done):  # as `DQNTrainer`: at the
            on_checkpoint(a.member, self.agent_state_dict(j))  # end of the step, its finished episodes all booked

    @staticmethod
    def _copy(dst: list[torch.Tensor], src: list[torch.Tensor], j: int) -> None:
        with torch.no_grad():
            for d, s in zip(dst, src):
                d[j].copy_(s[j])

    def _finish_done(self, on_finish) -> None:
        """Hand finished agents to `on_finish` and take them out of the stack."""
        done = [j for j, a in enumerate(self.agents) if a.finished]
        if not done:
            return
        self._sync_agents()
        for j in done:
            a = self.agents[j]
            if on_finish is not None:
                on_finish(a.member, self.policy_state_dict(j), self.agent_state_dict(j))
        self._remove(done)

    def drop(self, members: set[int]) -> None:
        """Stop the training agents of these member indices now, without `on_finish` (their work is not
        wanted any more: `rl.learners.choice` stops what cannot win); the others go on unchanged."""
        gone = [j for j, a in enumerate(self.agents) if a.member in members]
        if gone:
            self._sync_agents()
            self._remove(gone)

    def position(self, member: int) -> int | None:
        """Where member `member` sits in the stack of training agents (None: finished or dropped)."""
        return next((j for j, a in enumerate(self.agents) if a.member == member), None)

    def _remove(self, done: list[int]) -> None:
        """Take the agents at stack positions `done` out of the stack."""
        keep_list = [j for j in range(len(self.agents)) if j not in done]
        self._finished += [self.agents[j] for j in done]
        keep = torch.tensor(keep_list, dtype=torch.long)
        with torch.no_grad():
            self.q = [p.requires_grad_(True) for p in batched.select([p.detach() for p in self.q], keep)]
        self.target = batched.select(self.target, keep)
        self.q_avg = batched.select(self.q_avg, keep)
        self.adam.select(keep)
        self.buffer.select(np.array(keep_list, dtype=np.int64))
        self.agents = [self.agents[j] for j in keep_list]
        self._stack_agents()

    # --- per-agent views in DQNTrainer's formats ------------------------------------------

    def policy_state_dict(self, j: int) -> dict[str, torch.Tensor]:
        """Agent j's policy network (the averaged one once averaging started), as `q_network`'s state dict."""
        return batched.agent_state_dict(self.q_avg if self.agents[j].averaging else self.q, j)

    def agent_state_dict(self, j: int) -> dict[str, Any]:
        """Agent j's complete state as `DQNTrainer.state_dict()` (resumable alone or in a fleet)."""
        a = self.agents[j]
        self._sync_agents(j)
        return {
            "q": batched.agent_state_dict(self.q, j),
            "target": batched.agent_state_dict(self.target, j),
            "q_avg": batched.agent_state_dict(self.q_avg, j),
            "optimizer": self.adam.agent_state_dict(j, a.learning_rate(), self.hidden, self.n_obs),
            "buffer": self.buffer.agent_state_dict(j),
            **episode_state(a.envs, a.obs, a.stats, a.rng),
            "torch_rng": torch.get_rng_state(),
            "counters": {"episodes_done": a.episodes_done, "env_steps": a.env_steps, "updates": a.updates,
                         "wall_s": a.wall_s, "averaging": a.averaging},
            "losses": list(a.losses),
            "settings": json.dumps(a.settings.to_dict()),
        }

    def load_agent_state(self, j: int, state: dict[str, Any]) -> None:
        """Continue agent j from a `DQNTrainer.state_dict()` (its checkpoint)."""
        a = self.agents[j]
        self._sync_agents()
        batched.load_agent(self.q, j, state["q"])
        batched.load_agent(self.target, j, state["target"])
        batched.load_agent(self.q_avg, j, state["q_avg"])
        self.adam.load_agent(j, state["optimizer"])
        self.buffer.load_agent(j, state["buffer"])
        a.obs = load_episode_state(state, a.envs, a.stats, a.rng)
        c = state["counters"]
        a.episodes_done, a.env_steps = int(c["episodes_done"]), int(c["env_steps"])
        a.updates, a.wall_s = int(c["updates"]), float(c["wall_s"])
        a.averaging = bool(c.get("averaging", a.average_due()))
        a.losses = [float(x) for x in state["losses"]]
        self._stack_agents()
