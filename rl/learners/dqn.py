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
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import torch
from torch import nn

from rl.problem.env import Approach, EnvConfig, make_vec_env, observation_names, replayed_approaches
from rl.problem.rewards import CHANGE, KEEP, TERMS
from rl.settings import DQNSettings

__all__ = ["DQNSettings", "DQNTrainer", "ReplayBuffer", "greedy_actions", "q_network", "q_values"]


def q_network(hidden: tuple[int, ...] = (128, 128, 128), n_obs: int = 8, n_actions: int = 2) -> nn.Sequential:
    """The study's fully connected Q network: 8 -> 128 -> 128 -> 128 -> 2, ReLU."""
    layers: list[nn.Module] = []
    width = n_obs
    for h in hidden:
        layers += [nn.Linear(width, h), nn.ReLU()]
        width = h
    layers.append(nn.Linear(width, n_actions))
    return nn.Sequential(*layers)


def mlp_forward(params: list[torch.Tensor], x: torch.Tensor) -> torch.Tensor:
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


class ReplayBuffer:
    """A ring buffer of transitions in numpy arrays."""

    def __init__(self, size: int, n_obs: int = 8) -> None:
        self.size = size
        self.obs = np.zeros((size, n_obs), np.float32)
        self.next_obs = np.zeros((size, n_obs), np.float32)
        self.actions = np.zeros(size, np.int64)
        self.rewards = np.zeros(size, np.float32)
        self.terminated = np.zeros(size, np.float32)
        self.pos = 0
        self.full = False

    def __len__(self) -> int:
        return self.size if self.full else self.pos

    def add(self, obs, next_obs, actions, rewards, terminated) -> None:
        n = len(actions)
        idx = (self.pos + np.arange(n)) % self.size
        self.obs[idx], self.next_obs[idx] = obs, next_obs
        self.actions[idx], self.rewards[idx], self.terminated[idx] = actions, rewards, terminated
        self.full = self.full or self.pos + n >= self.size
        self.pos = int((self.pos + n) % self.size)

    def sample(self, rng: np.random.Generator, batch: int) -> tuple[torch.Tensor, ...]:
        idx = rng.integers(0, len(self), batch)
        return (torch.from_numpy(self.obs[idx]), torch.from_numpy(self.actions[idx]),
                torch.from_numpy(self.rewards[idx]), torch.from_numpy(self.next_obs[idx]),
                torch.from_numpy(self.terminated[idx]))

    def state_dict(self) -> dict[str, Any]:
        n = len(self)
        return {"obs": torch.from_numpy(self.obs[:n].copy()), "next_obs": torch.from_numpy(self.next_obs[:n].copy()),
                "actions": torch.from_numpy(self.actions[:n].copy()), "rewards": torch.from_numpy(self.rewards[:n].copy()),
                "terminated": torch.from_numpy(self.terminated[:n].copy()), "pos": self.pos, "full": self.full}

    def load_state_dict(self, s: dict[str, Any]) -> None:
        n = len(s["actions"])
        self.obs[:n], self.next_obs[:n] = s["obs"].numpy(), s["next_obs"].numpy()
        self.actions[:n], self.rewards[:n], self.terminated[:n] = s["actions"].numpy(), s["rewards"].numpy(), s["terminated"].numpy()
        self.pos, self.full = int(s["pos"]), bool(s["full"])


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


def checkpoint_due(s: DQNSettings, before: int, episodes_done: int) -> bool:
    """Whether a vector step that took the finished episodes from `before` to `episodes_done` passed a
    multiple of `checkpoint_every` (the checkpoint is taken at the end of that step)."""
    return bool(s.checkpoint_every) and episodes_done // s.checkpoint_every > before // s.checkpoint_every


def episode_row(episode: int, losses: list[float], stats: EpisodeStats, i: int, eps: float,
                actions: np.ndarray, out: dict[str, Any], env_steps: int, wall_s: float) -> dict[str, Any]:
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


def episode_state(envs: Any, obs: np.ndarray, stats: EpisodeStats, rng: np.random.Generator) -> dict[str, Any]:
    """The environments' half of a checkpoint: scenes, observations, running sums, generators."""
    env_state = envs.state_dict()
    return {
        "env_scene": {k: torch.from_numpy(np.asarray(v).copy()) for k, v in env_state["scene"].items()},
        "env_steps_in_episode": torch.from_numpy(env_state["steps"]),
        "env_replay": {k: torch.from_numpy(env_state[k]) for k in ("index", "late") if k in env_state},
        "obs": torch.from_numpy(obs.copy()),
        "stats": {"ret": torch.from_numpy(stats.ret.copy()), "length": torch.from_numpy(stats.length.copy()),
                  **{f"term_{k}": torch.from_numpy(v.copy()) for k, v in stats.terms.items()}},
        "rng": json.dumps(rng.bit_generator.state),
        "env_rng": json.dumps(envs.rng.bit_generator.state),
    }


def load_episode_state(state: dict[str, Any], envs: Any, stats: EpisodeStats, rng: np.random.Generator) -> np.ndarray:
    """Restore `episode_state` into `envs`, `stats` and `rng`; returns the observations."""
    envs.load_state_dict({"scene": {k: v.numpy() for k, v in state["env_scene"].items()},
                          "steps": state["env_steps_in_episode"].numpy(),
                          **{k: v.numpy() for k, v in state.get("env_replay", {}).items()}})
    st = state["stats"]
    stats.ret, stats.length = st["ret"].numpy().copy(), st["length"].numpy().copy()
    stats.terms = {k: st[f"term_{k}"].numpy().copy() if f"term_{k}" in st else np.zeros(stats.n) for k in TERMS}
    rng.bit_generator.state = json.loads(state["rng"])
    envs.rng.bit_generator.state = json.loads(state["env_rng"])
    return state["obs"].numpy().copy()


class DQNTrainer:
    """Trains a Q network on the lane-change environment; resumable.

    ``trainer.train(on_episode=..., should_stop=...)`` runs until `settings.episodes`
    episodes have finished or `should_stop()` is true. `on_episode(row)` receives one
    metrics dict per finished episode; `on_checkpoint(trainer)` is called every
    `checkpoint_every` episodes (at the end of the vector step that reached them: a checkpoint
    never splits a step); `on_vector_step(trainer)` after every vector step
    (returning True stops training, as an SB3 callback returning False would).
    """

    def __init__(self, env_config: EnvConfig, settings: DQNSettings | None = None,
                 approaches: list[Approach] | None = None) -> None:
        self.env_config = env_config
        s = settings or DQNSettings()
        if env_config.scenes == "recorded":
            s = s.resolved_episodes(replayed_approaches(approaches, env_config) if approaches else 0)
        self.settings = s
        torch.set_num_threads(s.threads)
        # --- seeding, in one block ---
        torch.manual_seed(s.seed)
        self.rng = np.random.default_rng(s.seed)
        self.envs = make_vec_env(env_config, s.num_envs, np.random.default_rng([s.seed, 1]), approaches)
        n_obs = len(observation_names(env_config))
        self.q = q_network(s.hidden, n_obs)
        self.target = q_network(s.hidden, n_obs)
        self.target.load_state_dict(self.q.state_dict())
        self.q_avg = q_network(s.hidden, n_obs)
        self.q_avg.load_state_dict(self.q.state_dict())
        # parameter lists cached, multi-tensor kernels and Adam's fused kernel: for a net this
        # small the per-tensor Python loops of Adam, clipping and averaging cost as much as the maths
        self._params = list(self.q.parameters())
        self._avg_params = list(self.q_avg.parameters())
        self._target_params = list(self.target.parameters())
        self.optimizer = torch.optim.Adam(self._params, lr=s.learning_rate, fused=True)
        self.buffer = ReplayBuffer(s.buffer_size, n_obs)
        self.stats = EpisodeStats(s.num_envs)
        self.obs = self.envs.observe()
        self.episodes_done = 0
        self.env_steps = 0
        self.updates = 0
        self.wall_s = 0.0
        self.averaging = False  # True once the policy is the averaged net (see `_start_average`)
        self._losses: list[float] = []

    @property
    def policy_net(self) -> nn.Module:
        """The network whose greedy actions are the trained policy (the averaged one once averaging started)."""
        return self.q_avg if self.averaging else self.q

    def _average_due(self) -> bool:
        return average_due(self.settings, self.episodes_done)

    def _start_average(self) -> None:
        """Start the average afresh from the online weights; from now on it is the policy.

        A flag, not a test of the episode count: a resume may change `episodes`, and
        the average must still start from the online net, not from stale weights.
        """
        self.q_avg.load_state_dict(self.q.state_dict())
        self.averaging = True

    def epsilon(self) -> float:
        return epsilon_at(self.settings, self.episodes_done)

    def learning_rate(self) -> float:
        return learning_rate_at(self.settings, self.episodes_done)

    def _update(self) -> float:
        s = self.settings
        for group in self.optimizer.param_groups:
            group["lr"] = self.learning_rate()
        obs, actions, rewards, next_obs, terminated = self.buffer.sample(self.rng, s.batch_size)
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
            norm = nn.utils.get_total_norm([p.grad for p in self._params], foreach=True)
            if norm + 1e-6 > s.max_grad_norm:
                nn.utils.clip_grads_with_norm_(self._params, s.max_grad_norm, norm, foreach=True)
        self.optimizer.step()
        if self.averaging:
            with torch.no_grad():
                torch._foreach_lerp_(self._avg_params, self._params, s.average_tau)
        self.updates += 1
        return float(loss.detach())

    def train(self, on_episode: Callable[[dict], None] | None = None,
              should_stop: Callable[[], bool] | None = None,
              on_checkpoint: Callable[["DQNTrainer"], None] | None = None,
              on_vector_step: Callable[["DQNTrainer"], bool] | None = None) -> "DQNTrainer":
        """Run the training loop (see the class doc). Returns self."""
        # Adam's second moments of rarely active weights decay into denormal floats, which
        # the CPU handles many times slower: flushing them to zero makes an update ~6 % cheaper
        torch.set_flush_denormal(True)
        try:
            return self._train(on_episode, should_stop, on_checkpoint, on_vector_step)
        finally:
            torch.set_flush_denormal(False)

    def _train(self, on_episode, should_stop, on_checkpoint, on_vector_step) -> "DQNTrainer":
        s = self.settings
        n = s.num_envs
        start = time.perf_counter() - self.wall_s
        while self.episodes_done < s.episodes:
            if should_stop is not None and should_stop():
                break
            # 1. act: epsilon-greedy over the N environments
            eps = self.epsilon()
            if len(self.buffer) < s.learning_starts:
                # an untrained network's argmax is arbitrary (with some observations it says 'change'
                # almost everywhere and ends every episode at once): keep, as the learning check assumes
                actions = np.full(n, KEEP)
            else:
                with torch.no_grad():
                    actions = mlp_forward(self._params, torch.from_numpy(self.obs)).argmax(dim=1).numpy()
            explore = self.rng.random(n) < eps
            actions = np.where(explore, self.rng.integers(0, 2, n), actions)
            # 2. step, store (bootstrapping through truncation: store the true last observation)
            out = self.envs.step(actions)
            self.buffer.add(self.obs, out["final_obs"], actions, out["reward"], out["terminated"].astype(np.float32))
            self.obs = out["obs"]
            self.env_steps += n
            st = self.stats
            st.ret += out["reward"]
            st.length += 1
            for k in TERMS:
                st.terms[k] += out["terms"][k]
            # 3. learn
            if len(self.buffer) >= s.learning_starts:
                for _ in range(s.gradient_steps):
                    self._losses.append(self._update())
            # 4. book-keeping of finished episodes
            done = out["terminated"] | out["truncated"]
            before = self.episodes_done
            for i in np.flatnonzero(done):
                if self.episodes_done >= s.episodes:
                    break
                self.episodes_done += 1
                self.wall_s = time.perf_counter() - start
                if on_episode is not None:
                    on_episode(episode_row(self.episodes_done, self._losses, st, i, eps, actions, out,
                                           self.env_steps, self.wall_s))
                    self._losses = []
                st.ret[i] = 0.0
                st.length[i] = 0
                for k in TERMS:
                    st.terms[k][i] = 0.0
                if not self.averaging and self._average_due():
                    self._start_average()
                if self.episodes_done % s.target_update_episodes == 0:
                    self.target.load_state_dict(self.q.state_dict())
            # a checkpoint once the step's finished episodes are all booked (one taken among them would resume
            # with the later ones' sums not reset and their count lost: another run than the uninterrupted one)
            if on_checkpoint is not None and checkpoint_due(s, before, self.episodes_done):
                on_checkpoint(self)
            self.wall_s = time.perf_counter() - start
            if on_vector_step is not None and on_vector_step(self):
                break
        return self

    # --- checkpoints (everything as tensors / plain values: loadable with weights_only=True) ---

    def state_dict(self) -> dict[str, Any]:
        return {
            "q": self.q.state_dict(),
            "target": self.target.state_dict(),
            "q_avg": self.q_avg.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "buffer": self.buffer.state_dict(),
            **episode_state(self.envs, self.obs, self.stats, self.rng),
            "torch_rng": torch.get_rng_state(),
            "counters": {"episodes_done": self.episodes_done, "env_steps": self.env_steps,
                         "updates": self.updates, "wall_s": self.wall_s, "averaging": self.averaging},
            "losses": list(self._losses),
            "settings": json.dumps(self.settings.to_dict()),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.q.load_state_dict(state["q"])
        self.target.load_state_dict(state["target"])
        self.q_avg.load_state_dict(state["q_avg"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.buffer.load_state_dict(state["buffer"])
        self.obs = load_episode_state(state, self.envs, self.stats, self.rng)
        torch.set_rng_state(state["torch_rng"])
        c = state["counters"]
        self.episodes_done, self.env_steps = int(c["episodes_done"]), int(c["env_steps"])
        self.updates, self.wall_s = int(c["updates"]), float(c["wall_s"])
        # checkpoints from before the flag averaged from the first update
        self.averaging = bool(c.get("averaging", self._average_due()))
        self._losses = [float(x) for x in state["losses"]]
