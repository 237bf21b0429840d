"""DQN in torch, CleanRL-style: one settings dataclass, a loop that reads top to bottom.

Defaults are the study's Table 2 and network (8-128-128-128-2, ReLU). Two things
the study leaves open are settled here: the optimiser is Adam and the loss the
squared TD error of its eq. 5 (``loss="huber"`` for SB3's smooth L1).

Vectorised collection (``num_envs > 1``): the loop steps ``num_envs`` copies of
the environment together (`VecLaneChangeEnv`) and, per vector step, makes
``gradient_steps`` updates of ``batch_size`` transitions. With ``num_envs=1,
batch_size=32, gradient_steps=1`` this is the study's DQN (one update of 32 per
environment step). With N envs it changes three things, all measurable:
(1) the replay ratio, gradient samples per collected transition, becomes
``gradient_steps * batch_size / num_envs`` (32 in the study); (2) each update
averages over a larger batch, so fewer, larger, less noisy steps at the same
learning rate; (3) the data is collected by a policy that is up to N
transitions staler. Epsilon still decays per finished episode and the target
network is still copied every `target_update_episodes` finished episodes;
replay memory and learning start stay in transitions.

Two stabilisers of ours, both settings (the updates themselves are unchanged):
the learning rate falls linearly from Table 2's 0.005 to ``learning_rate_end``,
and over the second half of the run (``average_from``) the policy is a Polyak
average of the online weights (``average_tau``), started afresh from them. The
press states sit on the policy's decision boundary, so the online net's greedy
policy swings from update to update until the end (one run ended at 85 % recall
where its averaged policy held 100 %). Averaging from the start instead doubled
the median steps to the accuracy target: early on, the average of quickly moving
weights is a worse policy than either end (rl/README.md, "Speed").

One loop (`DQNLoop`) trains one agent or many: a fleet's K agents step their
environments together and share one batched update, each keeping its own
settings, seed, generator, memory and schedules, and computing what it would
alone. The loop reads top to bottom in `DQNLoop._vector_step`: act, step and
store, learn, book-keep the finished episodes. Only the arithmetic differs:
`DQNTrainer` is the loop's agent of one with torch modules and fused Adam
(`OneNet`), `rl.fleet.batch.FleetTrainer` the loop over K stacked networks
(`rl.learners.batched.StackedNets`); the two agree up to floating-point
summation order (`tests/rl/test_rl_fleet.py`), and their checkpoints are one format.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, Sequence

import numpy as np
import torch
from torch import nn

from rl.problem.env import Approach, EnvConfig, make_vec_env, observation_names, replayed_approaches
from rl.problem.rewards import CHANGE, KEEP, TERMS
from rl.problem.stacked import stack_envs
from rl.settings import DQNSettings

__all__ = ["DQNLoop", "DQNSettings", "DQNTrainer", "FleetMember", "greedy_actions", "q_network", "q_values"]


def q_network(hidden: tuple[int, ...] = (128, 128, 128), n_obs: int = 8, n_actions: int = 2) -> nn.Sequential:
    """The study's fully connected Q network: 8 -> 128 -> 128 -> 128 -> 2, ReLU."""
    layers: list[nn.Module] = []
    width = n_obs
    for h in hidden:
        layers += [nn.Linear(width, h), nn.ReLU()]
        width = h
    layers.append(nn.Linear(width, n_actions))
    return nn.Sequential(*layers)


def mlp_forward(params: Sequence[torch.Tensor], x: torch.Tensor) -> torch.Tensor:
    """`q_network`'s forward from its parameter list [w1, b1, w2, b2, ...].

    The same maths as calling the module, without nn.Module's per-layer call
    machinery: the trainer calls it three times per step on a net this small.
    """
    last = len(params) - 2
    for i in range(0, len(params), 2):
        x = nn.functional.linear(x, params[i], params[i + 1])
        if i < last:
            x = torch.relu(x)
    return x


def greedy_actions(net: nn.Module, obs: np.ndarray) -> np.ndarray:
    """argmax_a Q(obs, a) for a batch of observations (ties go to TO CHANGE, index 0)."""
    with torch.no_grad():
        q = net(torch.as_tensor(obs, dtype=torch.float32))
    return q.argmax(dim=1).numpy()


def q_values(net: nn.Module, obs: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return net(torch.as_tensor(obs, dtype=torch.float32)).numpy()


@dataclass
class EpisodeStats:
    """Running sums of the episodes in progress, one slot per environment."""

    n: int
    ret: np.ndarray = field(init=False)
    length: np.ndarray = field(init=False)
    terms: dict[str, np.ndarray] = field(init=False)

    def __post_init__(self) -> None:
        self.ret = np.zeros(self.n)
        self.length = np.zeros(self.n, np.int64)
        self.terms = {k: np.zeros(self.n) for k in TERMS}


def epsilon_at(s: DQNSettings, episodes_done: int) -> float:
    """Exploration after `episodes_done` finished episodes: linear from eps_start to eps_end."""
    frac = min(1.0, episodes_done / max(1.0, s.exploration_fraction * s.episodes))
    return s.eps_start + frac * (s.eps_end - s.eps_start)


def learning_rate_at(s: DQNSettings, episodes_done: int) -> float:
    """Adam's step size after `episodes_done` episodes: linear to `learning_rate_end` (None: constant)."""
    if s.learning_rate_end is None:
        return s.learning_rate
    frac = min(1.0, episodes_done / max(1, s.episodes))
    return s.learning_rate + frac * (s.learning_rate_end - s.learning_rate)


def average_due(s: DQNSettings, episodes_done: int) -> bool:
    """Whether a run has reached `average_from` of its episodes (and averages at all)."""
    return s.average_tau > 0 and episodes_done >= int(s.average_from * s.episodes)


def episode_row(
    episode: int,
    losses: list[float],
    stats: EpisodeStats,
    i: int,
    eps: float,
    actions: np.ndarray,
    out: dict[str, Any],
    env_steps: int,
    wall_s: float,
) -> dict[str, Any]:
    """The metrics line of environment i's finished episode."""
    length = int(stats.length[i])
    return {
        "episode": episode,
        "loss": float(np.mean(losses)) if losses else None,
        "mean_step_reward": float(stats.ret[i] / length),
        "epsilon": eps,
        "length": length,
        "changed": bool(actions[i] == CHANGE and out["terminated"][i] and not out["reached_leader"][i]),
        "reached_leader": bool(out["reached_leader"][i]),
        "return": float(stats.ret[i]),
        **{f"term_{k}": float(stats.terms[k][i]) for k in TERMS},
        "env_steps": env_steps,
        "wall_s": round(wall_s, 4),
    }


def checkpoint_due(s: DQNSettings, before: int, episodes_done: int) -> bool:
    """Whether a vector step that took the finished episodes from `before` to `episodes_done` passed a
    multiple of `checkpoint_every` (the checkpoint is taken at the end of that step)."""
    return bool(s.checkpoint_every) and episodes_done // s.checkpoint_every > before // s.checkpoint_every


def episode_state(envs: Any, obs: np.ndarray, stats: EpisodeStats, rng: np.random.Generator) -> dict[str, Any]:
    """The environments' half of a checkpoint: scenes, observations, running sums, generators."""
    env_state = envs.state_dict()
    return {
        "env_scene": {k: torch.from_numpy(np.asarray(v).copy()) for k, v in env_state["scene"].items()},
        "env_steps_in_episode": torch.from_numpy(env_state["steps"]),
        "env_replay": {k: torch.from_numpy(env_state[k]) for k in ("index", "late") if k in env_state},
        "obs": torch.from_numpy(obs.copy()),
        "stats": {
            "ret": torch.from_numpy(stats.ret.copy()),
            "length": torch.from_numpy(stats.length.copy()),
            **{f"term_{k}": torch.from_numpy(v.copy()) for k, v in stats.terms.items()},
        },
        "rng": json.dumps(rng.bit_generator.state),
        "env_rng": json.dumps(envs.rng.bit_generator.state),
    }


def load_episode_state(state: dict[str, Any], envs: Any, stats: EpisodeStats, rng: np.random.Generator) -> np.ndarray:
    """Restore `episode_state` into `envs`, `stats` and `rng`; returns the observations."""
    envs.load_state_dict(
        {
            "scene": {k: v.numpy() for k, v in state["env_scene"].items()},
            "steps": state["env_steps_in_episode"].numpy(),
            **{k: v.numpy() for k, v in state.get("env_replay", {}).items()},
        }
    )
    st = state["stats"]
    stats.ret, stats.length = st["ret"].numpy().copy(), st["length"].numpy().copy()
    stats.terms = {k: st[f"term_{k}"].numpy().copy() if f"term_{k}" in st else np.zeros(stats.n) for k in TERMS}
    rng.bit_generator.state = json.loads(state["rng"])
    envs.rng.bit_generator.state = json.loads(state["env_rng"])
    return state["obs"].numpy().copy()


# --- the agents: what each one keeps for itself ----------------------------------------------------------


@dataclass
class FleetMember:
    """One agent to train: what `DQNTrainer(env_config, settings, approaches)` takes."""

    env_config: EnvConfig
    settings: DQNSettings
    approaches: list[Approach] | None = None


@dataclass
class AgentState:
    """Everything of one agent but its networks: settings, environments, generator, counters."""

    member: int  # index in the loop's members
    settings: DQNSettings
    envs: Any
    rng: np.random.Generator
    stats: EpisodeStats
    obs: np.ndarray
    episodes_done: int = 0
    env_steps: int = 0
    updates: int = 0
    wall_s: float = 0.0
    averaging: bool = False  # True once the policy is the averaged net (started afresh from the online one)
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
    """K replay memories (ring buffers) in (K, size, ...) arrays, each with its own write position."""

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

    def add(
        self, obs: np.ndarray, next_obs: np.ndarray, actions: np.ndarray, rewards: np.ndarray, terminated: np.ndarray
    ) -> None:
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
        return (
            torch.from_numpy(self.obs[rows, idx]),
            torch.from_numpy(self.actions[rows, idx]),
            torch.from_numpy(self.rewards[rows, idx]),
            torch.from_numpy(self.next_obs[rows, idx]),
            torch.from_numpy(self.terminated[rows, idx]),
        )

    def select(self, keep: np.ndarray) -> None:
        for name in ("obs", "next_obs", "actions", "rewards", "terminated", "pos", "full"):
            setattr(self, name, np.ascontiguousarray(getattr(self, name)[keep]))

    def agent_state_dict(self, j: int) -> dict[str, Any]:
        """Memory j as a checkpoint's "buffer": its filled part, write position and whether it wrapped."""
        n = self.filled(j)
        return {
            "obs": torch.from_numpy(self.obs[j, :n].copy()),
            "next_obs": torch.from_numpy(self.next_obs[j, :n].copy()),
            "actions": torch.from_numpy(self.actions[j, :n].copy()),
            "rewards": torch.from_numpy(self.rewards[j, :n].copy()),
            "terminated": torch.from_numpy(self.terminated[j, :n].copy()),
            "pos": int(self.pos[j]),
            "full": bool(self.full[j]),
        }

    def load_agent(self, j: int, s: dict[str, Any]) -> None:
        n = len(s["actions"])
        self.obs[j, :n], self.next_obs[j, :n] = s["obs"].numpy(), s["next_obs"].numpy()
        self.actions[j, :n], self.rewards[j, :n] = s["actions"].numpy(), s["rewards"].numpy()
        self.terminated[j, :n] = s["terminated"].numpy()
        self.pos[j], self.full[j] = int(s["pos"]), bool(s["full"])


# --- the arithmetic: the agents' networks and optimisers -------------------------------------------------


class Nets(Protocol):
    """The K agents' Q networks, target copies, averaged copies and optimisers, as the loop uses them.

    Two implementations: `OneNet` (one agent, torch modules and torch's fused Adam: `DQNTrainer`)
    and `rl.learners.batched.StackedNets` (K agents' weights stacked: `rl.fleet.batch.FleetTrainer`).
    They compute the same update up to floating-point summation order (`tests/rl/test_rl_fleet.py`).
    """

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        """argmax_a Q(obs, a) of each agent's online net for observations (K, n, obs): (K, n)."""
        ...

    def update(
        self,
        batch: tuple[torch.Tensor, ...],
        learning: np.ndarray,
        lr: list[float],
        averaging: np.ndarray,
        s: DQNSettings,
    ) -> np.ndarray:
        """One TD update of the agents where `learning` (K,), on `batch` (K, B, ...); returns the losses (K,)."""
        ...

    def copy_target(self, j: int) -> None:
        """Agent j's target net := its online net."""
        ...

    def start_average(self, j: int) -> None:
        """Agent j's averaged net := its online net (the average starts afresh)."""
        ...

    def policy_state_dict(self, j: int, averaging: bool) -> dict[str, torch.Tensor]:
        """Agent j's policy (averaged or online) as a `q_network` state dict."""
        ...

    def policy_actions(self, j: int, averaging: bool, x: np.ndarray) -> np.ndarray:
        """Agent j's policy's greedy actions for observations x (n, obs)."""
        ...

    def agent_state_dict(self, j: int, lr: float) -> dict[str, Any]:
        """Agent j's "q", "target", "q_avg" and "optimizer" as a checkpoint holds them."""
        ...

    def load_agent(self, j: int, state: dict[str, Any]) -> None:
        """Agent j's nets and optimiser from a checkpoint."""
        ...

    def select(self, keep: list[int]) -> None:
        """Keep the agents at positions `keep` only."""
        ...


class OneNet:
    """One agent's nets as torch modules, its optimiser torch's fused Adam: the study's DQN."""

    def __init__(self, settings: list[DQNSettings], n_obs: int) -> None:
        if len(settings) != 1:
            raise ValueError("OneNet trains one agent")
        s = settings[0]
        torch.manual_seed(s.seed)
        self.q = q_network(s.hidden, n_obs)
        self.target = q_network(s.hidden, n_obs)
        self.target.load_state_dict(self.q.state_dict())
        self.q_avg = q_network(s.hidden, n_obs)
        self.q_avg.load_state_dict(self.q.state_dict())
        # parameter lists cached, multi-tensor kernels and Adam's fused kernel: for a net this
        # small the per-tensor Python loops of Adam, clipping and averaging cost as much as the maths
        self._params: list[torch.Tensor] = list(self.q.parameters())
        self._avg_params: list[torch.Tensor] = list(self.q_avg.parameters())
        self._target_params: list[torch.Tensor] = list(self.target.parameters())
        self.optimizer = torch.optim.Adam(self._params, lr=s.learning_rate, fused=True)

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return mlp_forward(self._params, torch.from_numpy(obs[0])).argmax(dim=1).numpy()[None]

    def update(
        self,
        batch: tuple[torch.Tensor, ...],
        learning: np.ndarray,
        lr: list[float],
        averaging: np.ndarray,
        s: DQNSettings,
    ) -> np.ndarray:
        obs, actions, rewards, next_obs, terminated = (x[0] for x in batch)
        for group in self.optimizer.param_groups:
            group["lr"] = lr[0]
        with torch.no_grad():
            target_q = mlp_forward(self._target_params, next_obs)
            if s.double_q:
                best = mlp_forward(self._params, next_obs).argmax(dim=1, keepdim=True)
                target_max = target_q.gather(1, best).squeeze(1)
            else:
                target_max = target_q.max(dim=1).values
            td_target = rewards + s.gamma * target_max * (1.0 - terminated)
        q = mlp_forward(self._params, obs).gather(1, actions[:, None]).squeeze(1)
        loss = nn.functional.mse_loss(q, td_target) if s.loss == "mse" else nn.functional.smooth_l1_loss(q, td_target)
        for p in self._params:  # = optimizer.zero_grad(set_to_none=True), without its per-call bookkeeping
            p.grad = None
        loss.backward()
        if s.max_grad_norm:  # clip_grad_norm_, but rescaling only when it clips (the timing reward never does)
            norm = nn.utils.get_total_norm([p.grad for p in self._params if p.grad is not None], foreach=True)
            if norm + 1e-6 > s.max_grad_norm:
                nn.utils.clip_grads_with_norm_(self._params, s.max_grad_norm, norm, foreach=True)
        self.optimizer.step()
        if averaging[0]:
            with torch.no_grad():
                torch._foreach_lerp_(self._avg_params, self._params, s.average_tau)
        return np.array([float(loss.detach())])

    def copy_target(self, j: int) -> None:
        self.target.load_state_dict(self.q.state_dict())

    def start_average(self, j: int) -> None:
        self.q_avg.load_state_dict(self.q.state_dict())

    def policy(self, averaging: bool) -> nn.Module:
        return self.q_avg if averaging else self.q

    def policy_state_dict(self, j: int, averaging: bool) -> dict[str, torch.Tensor]:
        return self.policy(averaging).state_dict()

    def policy_actions(self, j: int, averaging: bool, x: np.ndarray) -> np.ndarray:
        return greedy_actions(self.policy(averaging), x)

    def agent_state_dict(self, j: int, lr: float) -> dict[str, Any]:
        return {
            "q": self.q.state_dict(),
            "target": self.target.state_dict(),
            "q_avg": self.q_avg.state_dict(),
            "optimizer": self.optimizer.state_dict(),
        }

    def load_agent(self, j: int, state: dict[str, Any]) -> None:
        self.q.load_state_dict(state["q"])
        self.target.load_state_dict(state["target"])
        self.q_avg.load_state_dict(state["q_avg"])
        self.optimizer.load_state_dict(state["optimizer"])

    def select(self, keep: list[int]) -> None:
        if keep != [0]:
            raise ValueError("one agent's nets cannot be split")


# --- the loop -----------------------------------------------------------------------------------------------


class DQNLoop:
    """The DQN training loop, for K agents at once (one: `DQNTrainer`; many: `FleetTrainer`).

    Each agent keeps everything that makes it itself (`AgentState`: its settings and seed,
    its environments, its generator, its replay memory, its schedules, all counted in its own
    finished episodes); the loop steps all agents' environments together and makes one update
    of all their networks (`nets`). With `drop_finished`, an agent that reaches its episodes
    leaves the stack (a fleet); else it stays, for its trainer to read and train further.

    `run` calls `on_episode(member, row)` per finished episode, `on_checkpoint(j)` every
    `checkpoint_every` episodes of the agent at stack position j, `on_finish(j)` once when it has
    its episodes (before it leaves), and `on_vector_step()` after every step (True stops).
    """

    # the training agents' environments, observations and running sums as (K, n) batches (`_stack_agents`)
    _envs: Any
    _obs: np.ndarray
    _ret: np.ndarray
    _length: np.ndarray
    _terms: dict[str, np.ndarray]

    def __init__(
        self,
        members: list[FleetMember],
        nets: Callable[[list[DQNSettings], int], Nets],
        threads: int,
        states: list[dict[str, Any] | None] | None = None,
        drop_finished: bool = True,
    ) -> None:
        if not members:
            raise ValueError("a fleet needs at least one agent")
        self.members = members
        self.threads = threads
        self.drop_finished = drop_finished
        self.n_obs = len(observation_names(members[0].env_config))
        self.hidden = members[0].settings.hidden
        self.agents: list[AgentState] = []  # still training, in stack order
        self._finished: list[AgentState] = []
        for i, m in enumerate(members):
            s = m.settings
            if m.env_config.scenes == "recorded":
                s = s.resolved_episodes(replayed_approaches(m.approaches, m.env_config) if m.approaches else 0)
            envs = make_vec_env(m.env_config, s.num_envs, np.random.default_rng([s.seed, 1]), m.approaches)
            self.agents.append(
                AgentState(i, s, envs, np.random.default_rng(s.seed), EpisodeStats(s.num_envs), envs.observe())
            )
        self.nets = nets([a.settings for a in self.agents], self.n_obs)
        self.buffer = StackedReplay(len(members), members[0].settings.buffer_size, self.n_obs)
        self.env_steps = 0
        self.wall_s = 0.0
        self._stack_agents()
        for j, state in enumerate(states or []):
            if state is not None:
                self.load_agent_state(j, state)

    def run(
        self,
        on_episode: Callable[[int, dict], None] | None = None,
        on_checkpoint: Callable[[int], None] | None = None,
        on_finish: Callable[[int], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
        on_vector_step: Callable[[], bool] | None = None,
    ) -> None:
        """Train until every agent has its episodes, `should_stop()` or `on_vector_step()` (see the class doc)."""
        torch.set_num_threads(self.threads)
        # Adam's second moments of rarely active weights decay into denormal floats, which
        # the CPU handles many times slower: flushing them to zero makes an update ~6 % cheaper
        torch.set_flush_denormal(True)
        try:
            self._finish_done(on_finish)
            start = time.perf_counter() - self.wall_s
            while any(not a.finished for a in self.agents):
                if should_stop is not None and should_stop():
                    break
                self._vector_step(start, on_episode, on_checkpoint)
                self._finish_done(on_finish)
                self.wall_s = time.perf_counter() - start
                if on_vector_step is not None and on_vector_step():
                    break
        finally:
            torch.set_flush_denormal(False)

    def _vector_step(
        self, start: float, on_episode: Callable[[int, dict], None] | None, on_checkpoint: Callable[[int], None] | None
    ) -> None:
        s0 = self.agents[0].settings  # the settings every agent shares (`rl.fleet.batch.SHARED_SETTINGS`)
        n = s0.num_envs
        starts = np.array([a.settings.learning_starts for a in self.agents])
        # 1. act: epsilon-greedy, each agent over its n environments
        obs = self._obs
        learning = self.buffer.filled_all() >= starts
        if learning.any():
            greedy = self.nets.greedy(obs)
            # an untrained network's argmax is arbitrary (with some observations it says 'change'
            # almost everywhere and ends every episode at once): keep, as the learning check assumes
            greedy[~learning] = KEEP
        else:
            greedy = np.full((len(self.agents), n), KEEP, np.int64)
        epsilons = [a.epsilon() for a in self.agents]
        actions = np.empty(greedy.shape, np.int64)
        for j, a in enumerate(self.agents):
            explore = a.rng.random(n) < epsilons[j]
            actions[j] = np.where(explore, a.rng.integers(0, 2, n), greedy[j])
        # 2. step, store (bootstrapping through truncation: store the true last observation)
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
        # 3. learn: the agents whose memory holds `learning_starts` transitions
        learning = self.buffer.filled_all() >= starts
        if learning.any():
            for _ in range(s0.gradient_steps):
                self._update(learning, s0)
        # 4. book-keeping of finished episodes, per agent
        wall = time.perf_counter() - start
        done = out["terminated"] | out["truncated"]
        for j in np.flatnonzero(done.any(axis=1)).tolist():
            self._episodes(
                j,
                {k: out[k][j] for k in ("terminated", "truncated", "reached_leader")},
                actions[j],
                epsilons[j],
                wall,
                on_episode,
                on_checkpoint,
            )

    def _update(self, learning: np.ndarray, s0: DQNSettings) -> None:
        idx = np.zeros((len(self.agents), s0.batch_size), np.int64)
        for j in np.flatnonzero(learning).tolist():  # each agent draws its batch from its own generator
            idx[j] = self.agents[j].rng.integers(0, self.buffer.filled(j), s0.batch_size)
        losses = self.nets.update(
            self.buffer.sample(idx),
            learning,
            [a.learning_rate() for a in self.agents],
            np.array([a.averaging for a in self.agents]),
            s0,
        )
        for j in np.flatnonzero(learning).tolist():
            a = self.agents[j]
            a.updates += 1
            a.losses.append(float(losses[j]))

    def _episodes(
        self,
        j: int,
        out: dict[str, np.ndarray],
        actions: np.ndarray,
        eps: float,
        wall: float,
        on_episode: Callable[[int, dict], None] | None,
        on_checkpoint: Callable[[int], None] | None,
    ) -> None:
        a = self.agents[j]
        s, st = a.settings, a.stats
        before = a.episodes_done
        for i in np.flatnonzero(out["terminated"] | out["truncated"]).tolist():
            if a.episodes_done >= s.episodes:
                break
            a.episodes_done += 1
            a.wall_s = wall
            if on_episode is not None:
                on_episode(
                    a.member, episode_row(a.episodes_done, a.losses, st, i, eps, actions, out, a.env_steps, wall)
                )
                a.losses = []
            st.ret[i] = 0.0
            st.length[i] = 0
            for k in TERMS:
                st.terms[k][i] = 0.0
            if not a.averaging and a.average_due():
                # a flag, not a test of the episode count: a resume may change `episodes`, and
                # the average must still start from the online net, not from stale weights
                self.nets.start_average(j)
                a.averaging = True
            if a.episodes_done % s.target_update_episodes == 0:
                self.nets.copy_target(j)
        # a checkpoint once the step's finished episodes are all booked (one taken among them would resume
        # with the later ones' sums not reset and their count lost: another run than the uninterrupted one)
        if on_checkpoint is not None and checkpoint_due(s, before, a.episodes_done):
            on_checkpoint(j)

    # --- the stack of agents ------------------------------------------------------------------------

    def _stack_agents(self) -> None:
        """The training agents' environments, observations and running sums as (K, n) batches.

        Each agent's `stats` become views of its row, so the per-episode book-keeping and
        checkpoints read and reset them in place; `_sync_agents` hands back the rest.
        """
        self._envs = stack_envs([a.envs for a in self.agents])
        self._obs = np.stack([a.obs for a in self.agents]) if self.agents else np.zeros((0, 0, self.n_obs))
        self._ret = np.stack([a.stats.ret for a in self.agents]) if self.agents else np.zeros((0, 0))
        self._length = np.stack([a.stats.length for a in self.agents]) if self.agents else np.zeros((0, 0), np.int64)
        self._terms = {k: np.stack([a.stats.terms[k] for a in self.agents]) for k in TERMS} if self.agents else {}
        for j, a in enumerate(self.agents):
            a.stats.ret, a.stats.length = self._ret[j], self._length[j]
            a.stats.terms = {k: v[j] for k, v in self._terms.items()}

    def _sync_agents(self, only: int | None = None) -> None:
        """Write the batches' environment state and observations back into each training agent (or `only`)."""
        agents = list(range(len(self.agents))) if only is None else [only]
        self._envs.scatter(agents)
        for j in agents:
            self.agents[j].obs = self._obs[j].copy()

    def _finish_done(self, on_finish: Callable[[int], None] | None) -> None:
        """Hand finished agents to `on_finish` and (`drop_finished`) take them out of the stack."""
        if not self.drop_finished:
            return
        done = [j for j, a in enumerate(self.agents) if a.finished]
        if not done:
            return
        self._sync_agents()
        for j in done:
            if on_finish is not None:
                on_finish(j)
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
        keep = [j for j in range(len(self.agents)) if j not in done]
        self._finished += [self.agents[j] for j in done]
        self.nets.select(keep)
        self.buffer.select(np.array(keep, dtype=np.int64))
        self.agents = [self.agents[j] for j in keep]
        self._stack_agents()

    # --- each agent in `DQNTrainer`'s formats ---------------------------------------------------------

    def policy_state_dict(self, j: int) -> dict[str, torch.Tensor]:
        """Agent j's policy network (the averaged one once averaging started), as `q_network`'s state dict."""
        return self.nets.policy_state_dict(j, self.agents[j].averaging)

    def policy_actions(self, member: int, x: np.ndarray) -> np.ndarray:
        """The greedy actions of training member `member`'s policy for observations x (n, obs)."""
        j = self.position(member)
        if j is None:
            raise ValueError(f"member {member} is not training")
        return self.nets.policy_actions(j, self.agents[j].averaging, x)

    def agent_state_dict(self, j: int) -> dict[str, Any]:
        """Agent j's complete state, a checkpoint (everything as tensors / plain values: loadable with
        weights_only=True), resumable alone (`DQNTrainer`) or in a fleet."""
        a = self.agents[j]
        self._sync_agents(j)
        return {
            **self.nets.agent_state_dict(j, a.learning_rate()),
            "buffer": self.buffer.agent_state_dict(j),
            **episode_state(a.envs, a.obs, a.stats, a.rng),
            "torch_rng": torch.get_rng_state(),
            "counters": {
                "episodes_done": a.episodes_done,
                "env_steps": a.env_steps,
                "updates": a.updates,
                "wall_s": a.wall_s,
                "averaging": a.averaging,
            },
            "losses": list(a.losses),
            "settings": json.dumps(a.settings.to_dict()),
        }

    def load_agent_state(self, j: int, state: dict[str, Any]) -> None:
        """Continue agent j from a checkpoint (`agent_state_dict`)."""
        a = self.agents[j]
        self._sync_agents()
        self.nets.load_agent(j, state)
        self.buffer.load_agent(j, state["buffer"])
        a.obs = load_episode_state(state, a.envs, a.stats, a.rng)
        c = state["counters"]
        a.episodes_done, a.env_steps = int(c["episodes_done"]), int(c["env_steps"])
        a.updates, a.wall_s = int(c["updates"]), float(c["wall_s"])
        # checkpoints from before the flag averaged from the first update
        a.averaging = bool(c.get("averaging", a.average_due()))
        a.losses = [float(x) for x in state["losses"]]
        self.wall_s = max(self.wall_s, a.wall_s)
        self._stack_agents()


class DQNTrainer:
    """Trains one Q network on the lane-change environment, resumable: the loop's agent of one.

    ``trainer.train(on_episode=..., should_stop=...)`` runs until `settings.episodes`
    episodes have finished or `should_stop()` is true. `on_episode(row)` receives one
    metrics dict per finished episode; `on_checkpoint(trainer)` is called every
    `checkpoint_every` episodes (at the end of the vector step that reached them: a checkpoint
    never splits a step); `on_vector_step(trainer)` after every vector step
    (returning True stops training, as an SB3 callback returning False would).
    """

    def __init__(
        self, env_config: EnvConfig, settings: DQNSettings | None = None, approaches: list[Approach] | None = None
    ) -> None:
        self.env_config = env_config
        s = settings or DQNSettings()
        self.loop = DQNLoop([FleetMember(env_config, s, approaches)], OneNet, threads=s.threads, drop_finished=False)
        self.agent = self.loop.agents[0]
        nets = self.loop.nets
        assert isinstance(nets, OneNet)
        self.q, self.target, self.q_avg, self.optimizer = nets.q, nets.target, nets.q_avg, nets.optimizer

    @property
    def settings(self) -> DQNSettings:
        """The agent's settings, episodes resolved (a resume may set more episodes)."""
        return self.agent.settings

    @settings.setter
    def settings(self, value: DQNSettings) -> None:
        self.agent.settings = value

    @property
    def policy_net(self) -> nn.Module:
        """The network whose greedy actions are the trained policy (the averaged one once averaging started)."""
        return self.q_avg if self.agent.averaging else self.q

    @property
    def episodes_done(self) -> int:
        return self.agent.episodes_done

    @property
    def env_steps(self) -> int:
        return self.agent.env_steps

    @property
    def updates(self) -> int:
        return self.agent.updates

    @property
    def averaging(self) -> bool:
        return self.agent.averaging

    @property
    def wall_s(self) -> float:
        return self.loop.wall_s

    def epsilon(self) -> float:
        return self.agent.epsilon()

    def learning_rate(self) -> float:
        return self.agent.learning_rate()

    def train(
        self,
        on_episode: Callable[[dict], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
        on_checkpoint: Callable[["DQNTrainer"], None] | None = None,
        on_vector_step: Callable[["DQNTrainer"], bool] | None = None,
    ) -> "DQNTrainer":
        """Run the training loop (see the class doc). Returns self."""
        self.loop.run(
            on_episode=None if on_episode is None else lambda _, row: on_episode(row),
            on_checkpoint=None if on_checkpoint is None else lambda _: on_checkpoint(self),
            should_stop=should_stop,
            on_vector_step=None if on_vector_step is None else lambda: on_vector_step(self),
        )
        return self

    def state_dict(self) -> dict[str, Any]:
        """The trainer's checkpoint (`DQNLoop.agent_state_dict`)."""
        return self.loop.agent_state_dict(0)

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.loop.load_agent_state(0, state)
        torch.set_rng_state(state["torch_rng"])
