"""The lane-change decision environment (`laneprint/LaneChangeDecision-v0`).

A two-lane highway. The ego drives at a constant speed behind a slower leader
``C_f``; the target lane holds a leader ``C_nf`` and a follower ``C_nb``. Every
vehicle keeps its speed, so the times to collision fall by exactly ``dt`` per
step and ``dv_nb`` is constant: the question is only *when* to change lane.

Action Space
    ``Discrete(2)``: 0 = TO CHANGE lane (ends the episode), 1 = NOT TO CHANGE.

Observation Space
    ``Box(0, 1, (8,), float32)``: ``[v_e, x_e, v_f, x_f, v_nf, x_nf, v_nb, x_nb]``
    normalised to (0, 1] (see `rl.problem.scene.observe`): speeds over ``v_max_mps``;
    positions ego-centred over ``+-range_m`` (the ego is always 0.5). An absent
    ``C_nf`` / ``C_nb`` shows as nothing within range: at the front / rear edge,
    at the ego's speed.

Rewards
    From the target's reference lines, `paper` or `timing` (see `rl.problem.rewards`);
    ``info["terms"]`` holds the named terms of each step.

Episode End
    Terminated on TO CHANGE, or when the ego reaches ``C_f`` (gap <= 0) without
    changing (``end_at_leader``). Truncated after ``max_steps`` steps.

Starting State
    Matched to the synthetic study (`laneprint.simulator.config`): ego speed
    uniform over the sections' limits +-5 km/h, leaders' speeds Uniform(5, 14) m/s,
    followers' Uniform(6, 11) m/s (the study's presses: 8.5 +- 1.4),
    cars 4-5 m and 10 % trucks 10-16 m. ``C_f`` is placed so that its initial time
    to collision is uniform in ``t_f0_s`` (every episode then crosses the moment a
    driver would change); ``C_nf`` so that ``t_nf - t_f`` is uniform in
    ``nf_ttc_offset_s`` (covering the study's presses, where both sit near the
    driver's lines, and target-lane cars being passed early in an approach),
    present with ``nf_present_prob``; ``C_nb`` behind at a uniform gap
    (beyond 100 m it is "far" and has no influence). All randomness comes
    from ``self.np_random`` (seeded by ``reset(seed=...)``).

Replay mode (``approaches=[...]``): each episode is one recorded approach from
the workspace's decisions table: the not-yet states and the press, in time
order, then (if the agent has not changed by the press) the press scene moved on
at constant speeds every ``dt_s``. See `approaches_from_decisions`. In a middle
lane the driver also passed up the other side at every one of those states: with
``other_side`` the trainer's `VecReplayEnv` replays that side's scenes too, as an
approach without a press (a change there is paid as one far too early, -1; a keep
0; it ends at its last state).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from laneprint.errors import UserError
from laneprint.reference import FAR_FOLLOWER_M
from rl.problem.rewards import CHANGE, TERMS, ReferenceLines, RewardSettings, decisions_step_reward, step_reward
from rl.settings import OBSERVATIONS, SCENES, TREES_PRESS_SCALE_S, resolve_formulation
from rl.problem.scene import (
    ACCEPTANCE_FEATURES,
    DIRECTION_FEATURE,
    INDICATOR_FEATURES,
    OBS_NAMES,
    Scene,
    acceptance_features,
    direction_feature,
    indicator_features,
    indicators,
    observe,
)

ENV_ID = "laneprint/LaneChangeDecision-v0"


@dataclass(frozen=True)
class EnvConfig:
    """Everything that defines the environment, in one place (units in comments)."""

    dt_s: float = 0.5  # time between two decisions [s] (the analysis's not-yet step)
    max_steps: int = 200  # episode truncation (Table 2, N_s) [steps]
    ego_speed_mps: tuple[float, float] = (55 / 3.6, 95 / 3.6)  # ego speed, uniform: limits 60-90 km/h +-5 [m/s]
    traffic_speed_mps: tuple[float, float] = (5.0, 14.0)  # C_f, C_nf speeds, uniform [m/s]
    nb_speed_mps: tuple[float, float] = (6.0, 11.0)  # C_nb speed, uniform [m/s] (the study's followers: ~9)
    t_f0_s: tuple[float, float] = (1.0, 25.0)  # initial time to collision with C_f, uniform [s]
    nf_present_prob: float = 0.88  # probability of a leader in the target lane
    nf_ttc_offset_s: tuple[float, float] = (-10.0, 4.0)  # initial t_nf - t_f, uniform [s] (gap >= 1 m)
    nb_present_prob: float = 1.0  # probability of a follower in the target lane
    nb_gap0_m: tuple[float, float] = (5.0, 140.0)  # initial gap to C_nb, uniform [m]
    ego_length_m: float = 4.5  # [m]
    car_length_m: tuple[float, float] = (4.0, 5.0)  # traffic car length, uniform [m]
    truck_share: float = 0.1  # share of traffic vehicles that are trucks
    truck_length_m: tuple[float, float] = (10.0, 16.0)  # truck length, uniform [m]
    range_m: float = 150.0  # sensing range ahead and behind; farther vehicles are not seen [m]
    v_max_mps: float = 40.0  # speed that normalises to 1 [m/s]
    far_follower_m: float = FAR_FOLLOWER_M  # C_nb farther than this has no influence [m]
    end_at_leader: bool = True  # terminate when the ego reaches C_f without changing
    scenes: str = "synthetic"  # 'synthetic' (drawn from the ranges above) or 'recorded' (replayed approaches)
    replay_late_s: float = 10.0  # recorded scenes: after the press, an approach runs on at most this long [s]
    observation: str = "paper"  # 'paper' (8 values), 'indicators' (the 8 + t_f, t_nf, dv_nb and their flags),
    # 'direction' (indicators + the target lane's side), 'acceptance' (indicators + gaps and time headways)
    other_side: bool = True  # recorded scenes: also replay the side a middle-lane driver did not take, as
    # approaches without a press (`Approach.other`; no effect on two lanes); False = only the driver's side
    reward: RewardSettings = field(default_factory=RewardSettings)  # which reward, its parameters
    lines: ReferenceLines = field(default_factory=lambda: ReferenceLines.paper("Normal"))  # target lines

    def __post_init__(self) -> None:
        if self.scenes not in SCENES:
            raise UserError(f"unknown scenes {self.scenes!r}: choose one of {', '.join(SCENES)}")
        if self.observation not in OBSERVATIONS:
            raise UserError(f"unknown observation {self.observation!r}: choose one of {', '.join(OBSERVATIONS)}")
        if self.reward.name == "decisions" and self.scenes != "recorded":
            raise UserError(
                "the 'decisions' reward is paid by the driver's recorded presses: it needs "
                "recorded scenes (--scenes recorded)"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "EnvConfig":
        d = dict(d)
        d.setdefault("scenes", "synthetic")  # runs from before these settings
        d.setdefault("observation", "paper")
        d.setdefault("other_side", False)  # runs from before the setting replayed only the driver's side
        d["reward"] = RewardSettings(**d.get("reward", {}))
        if "lines" in d:
            d["lines"] = ReferenceLines.from_dict(d["lines"])
        for k, v in list(d.items()):
            if isinstance(v, list):
                d[k] = tuple(v)
        return EnvConfig(**d)


#: Observations that append the indicator features to the study's 8 values.
_WITH_INDICATORS = ("indicators", "direction", "acceptance")


def observation_names(cfg: EnvConfig) -> tuple[str, ...]:
    """Names of the observation's values, in order."""
    extra = INDICATOR_FEATURES if cfg.observation in _WITH_INDICATORS else ()
    if cfg.observation == "acceptance":
        extra += ACCEPTANCE_FEATURES
    return OBS_NAMES + extra + ((DIRECTION_FEATURE,) if cfg.observation == "direction" else ())


def observation(scene: Scene, cfg: EnvConfig) -> np.ndarray:
    """What the agent sees of each scene, shape (n, len(observation_names(cfg))) float32."""
    obs = observe(scene, cfg.range_m, cfg.v_max_mps)
    if cfg.observation in _WITH_INDICATORS:
        obs = np.concatenate([obs, indicator_features(scene, cfg.far_follower_m, cfg.range_m)], axis=1)
    if cfg.observation == "acceptance":
        obs = np.concatenate([obs, acceptance_features(scene, cfg.range_m)], axis=1)
    if cfg.observation == "direction":
        obs = np.concatenate([obs, direction_feature(scene)], axis=1)
    return obs


def formulation_config(
    lines: ReferenceLines,
    reward: str | None = None,
    scenes: str | None = None,
    observation: str | None = None,
    lines_source: str = "analysis",
    other_side: bool | None = None,
) -> EnvConfig:
    """An `EnvConfig` for `lines`, the unnamed settings filled by `rl.settings.resolve_formulation`
    (`other_side` None: `EnvConfig`'s default), as the DQN fits it (`learner_env` for the trees')."""
    name, scn, obs = resolve_formulation(reward, scenes, observation, lines_source)
    cfg = EnvConfig(lines=lines, reward=RewardSettings(name=name), scenes=scn, observation=obs)
    return cfg if other_side is None else replace(cfg, other_side=other_side)


def learner_env(cfg: EnvConfig, learner: str) -> EnvConfig:
    """`cfg` as `learner` fits it: the trees fit the `decisions` reward with their own press scale
    (`rl.settings.TREES_PRESS_SCALE_S`); the DQN (and 'auto', which hands each learner its own) as it is."""
    if learner == "trees" and cfg.reward.name == "decisions":
        return replace(cfg, reward=replace(cfg.reward, press_scale_s=TREES_PRESS_SCALE_S))
    return cfg


def default_config() -> EnvConfig:
    """The default configuration (matched to the synthetic study's traffic)."""
    return EnvConfig()


def _half_lengths(rng: np.random.Generator, cfg: EnvConfig, n: int) -> np.ndarray:
    """Half of (ego length + a traffic vehicle's length) for `n` vehicles [m]."""
    truck = rng.random(n) < cfg.truck_share
    length = np.where(truck, rng.uniform(*cfg.truck_length_m, n), rng.uniform(*cfg.car_length_m, n))
    return (cfg.ego_length_m + length) / 2.0


def sample_scenes(rng: np.random.Generator, cfg: EnvConfig, n: int) -> Scene:
    """`n` random starting scenes (see the module doc, Starting State)."""
    u = rng.uniform
    v_e = u(*cfg.ego_speed_mps, n)
    v_f, v_nf = u(*cfg.traffic_speed_mps, n), u(*cfg.traffic_speed_mps, n)
    v_nb = u(*cfg.nb_speed_mps, n)
    hl_f, hl_nf, hl_nb = (_half_lengths(rng, cfg, n) for _ in range(3))
    t_f0 = u(*cfg.t_f0_s, n)
    t_nf0 = t_f0 + u(*cfg.nf_ttc_offset_s, n)
    x_e = np.zeros(n)
    x_f = x_e + hl_f + t_f0 * np.maximum(v_e - v_f, 0.1)
    x_nf = x_e + hl_nf + np.maximum(t_nf0 * (v_e - v_nf), 1.0)
    x_nb = x_e - hl_nb - u(*cfg.nb_gap0_m, n)
    return Scene(
        v_e=v_e,
        x_e=x_e,
        f_present=np.ones(n, bool),
        v_f=v_f,
        x_f=x_f,
        hl_f=hl_f,
        nf_present=rng.random(n) < cfg.nf_present_prob,
        v_nf=v_nf,
        x_nf=x_nf,
        hl_nf=hl_nf,
        nb_present=rng.random(n) < cfg.nb_present_prob,
        v_nb=v_nb,
        x_nb=x_nb,
        hl_nb=hl_nb,
    )


def transition(
    scene: Scene, actions: np.ndarray, cfg: EnvConfig, t_from_press_s: np.ndarray | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """Apply `actions` to a batch of scenes (in place).

    Returns (reward, named terms, terminated, reached_leader). The reward is that of
    the action in the scene where it was taken; kept scenes then move on by dt.
    `t_from_press_s` (recorded scenes: time from the driver's press) pays the
    `decisions` reward.
    """
    if cfg.reward.name == "decisions":
        if t_from_press_s is None:
            raise ValueError("the 'decisions' reward needs the time from the press of every scene")
        reward, terms = decisions_step_reward(t_from_press_s, actions, cfg.reward)
    else:
        ind = indicators(scene, cfg.far_follower_m, cfg.range_m)
        reward, terms = step_reward(ind, actions, cfg.lines, cfg.reward, cfg.dt_s)
    changed = np.asarray(actions) == CHANGE
    scene.advance(cfg.dt_s)
    gap_f = np.where(scene.f_present, scene.x_f - scene.x_e - scene.hl_f, np.inf)
    reached = ~changed & (gap_f <= 0.0) if cfg.end_at_leader else np.zeros_like(changed)
    return reward, terms, changed | reached, reached


# --- replay of recorded approaches -------------------------------------------------


@dataclass
class Approach:
    """One recorded approach: the not-yet states and the press, in time order."""

    decision_id: str
    driver_id: str
    t_s: np.ndarray  # time of each recorded state [s]; the last is the press
    scene: Scene  # the recorded scenes, same length
    other: Scene | None = None  # in a middle lane, the side not taken at the same states (else None)

    @property
    def press_t_s(self) -> float:
        return float(self.t_s[-1])

    def __len__(self) -> int:
        return len(self.t_s)


#: Why a recorded decision is not replayed (see `approaches_from_decisions`).
SKIP_REASONS = {
    "no_closing_leader": "no closing ego-lane leader at the press (t_f undefined); scored unless "
    "include_following=False (the study's rule)",
    "following": "the ego was following its leader at the press (closing speed below the analysis's "
    "min_closing_mps, t_f_reason 'following'); scored unless include_following=False",
    "no_press": "no 'change' row for the decision (its press was dropped by the analysis)",
}


def scenes_from_decisions(rows: pd.DataFrame, vehicle_length_m: float = 4.5, other: bool = False) -> Scene:
    """Scenes of DECISIONS rows (one per row); absent vehicles flagged, gaps kept exact.

    ``other=True``: the scenes asking about the other side of the ego lane (`other_lane`,
    `other_nf_*` / `other_nb_*`, `indicators.decisions.OTHER_SIDE`) instead of the target lane.
    """

    def col(name: str) -> np.ndarray:
        return rows[name].to_numpy(dtype=float, na_value=np.nan)

    x_e, v_e = col("ego_x_m"), col("ego_v_mps")

    def part(role: str, ahead: bool, prefix: str = "") -> dict[str, np.ndarray]:
        """The Scene fields of `role` (f, nf, nb) from the columns ``<prefix><role>_*``."""
        present = rows[f"{prefix}{role}_present"].to_numpy(dtype=bool)
        x, v, gap = col(f"{prefix}{role}_x_m"), col(f"{prefix}{role}_v_mps"), col(f"{prefix}{role}_gap_m")
        dist = (x - x_e) if ahead else (x_e - x)
        hl = np.where(present & np.isfinite(gap) & np.isfinite(dist), dist - gap, vehicle_length_m)
        return {
            f"{role}_present": present,
            f"v_{role}": np.where(present, v, v_e),
            f"x_{role}": np.where(present, x, x_e),
            f"hl_{role}": hl,
        }

    prefix, lane = ("other_", "other_lane") if other else ("", "target_lane")
    left = (rows[lane].to_numpy() > rows["ego_lane"].to_numpy()) if lane in rows else None
    return Scene(
        v_e=v_e, x_e=x_e, **part("f", True), **part("nf", True, prefix), **part("nb", False, prefix), left=left
    )


def approaches_from_decisions(
    decisions: pd.DataFrame, vehicle_length_m: float = 4.5, include_following: bool = True
) -> tuple[list[Approach], dict[str, int]]:
    """Recorded approaches from a DECISIONS table, and how many were skipped, by reason.

    Every decision with a press row is replayed, including presses made while
    following a slow leader or with no closing leader at all (t_f undefined): the
    driver decided there too, and a held-out score that leaves them out flatters
    every policy. ``include_following=False`` restores the study's rule, which
    skips them (counted as 'no_closing_leader' / 'following'). Undefined ``t_nf``
    or ``dv_nb`` are always kept: the scene models absent and far vehicles.

    An approach made in a lane with a neighbour on each side carries the other
    side's scene at each of its states in ``other`` (from the analysis's
    `other_lane` / `other_nf_*` / `other_nb_*` columns; None without them, as in
    tables analysed before those columns): what `VecReplayEnv` replays as an
    approach without a press when ``EnvConfig.other_side`` is set.
    """
    skipped = {k: 0 for k in SKIP_REASONS}
    df = decisions.sort_values(["decision_id", "t_s"], kind="stable").reset_index(drop=True)
    if df.empty:
        return [], skipped
    # one pass over all rows (a groupby of small frames cost ~10 ms a decision)
    did = df["decision_id"].astype(str).to_numpy()
    group = np.r_[0, np.cumsum(did[1:] != did[:-1])]
    n_groups = int(group[-1]) + 1
    is_change = (df["label"] == "change").to_numpy()
    press = np.full(n_groups, -1)
    np.maximum.at(press, group[is_change], np.flatnonzero(is_change))  # the last press row of each decision
    t = df["t_s"].to_numpy(float)
    ok = press >= 0
    skipped["no_press"] = int((~ok).sum())
    if not include_following:
        t_f_ok = (df["t_f_status"] == "ok").to_numpy()
        following = (df["t_f_reason"] == "following").to_numpy() if "t_f_reason" in df else np.zeros(len(df), bool)
        no_leader = ok & ~t_f_ok[np.maximum(press, 0)]
        follows = ok & ~no_leader & following[np.maximum(press, 0)]
        skipped["no_closing_leader"], skipped["following"] = int(no_leader.sum()), int(follows.sum())
        ok &= ~no_leader & ~follows
    press_t = np.where(ok, t[np.maximum(press, 0)], -np.inf)
    before = (df["label"] == "keep").to_numpy() & (t < press_t[group])
    scenes = scenes_from_decisions(df, vehicle_length_m)
    has_other = df["other_lane"].to_numpy() >= 0 if "other_lane" in df else np.zeros(len(df), bool)
    others = scenes_from_decisions(df, vehicle_length_m, other=True) if has_other.any() else None
    drivers = df["driver_id"].astype(str).to_numpy()
    bounds = np.r_[0, np.flatnonzero(group[1:] != group[:-1]) + 1, len(df)]
    out: list[Approach] = []
    for g in np.flatnonzero(ok):
        lo, hi = bounds[g], bounds[g + 1]
        rows = np.r_[lo + np.flatnonzero(before[lo:hi]), press[g]]
        other = others.take(rows) if others is not None and has_other[rows].all() else None
        out.append(Approach(did[lo], drivers[lo], t[rows], scenes.take(rows), other))
    return out, skipped


def replayed_approaches(approaches: list[Approach], config: EnvConfig) -> int:
    """How many approaches `VecReplayEnv` replays: the recorded ones, and with ``config.other_side``
    those of the sides not taken (what `DQNSettings.resolved_episodes` scales with)."""
    return len(approaches) + (sum(a.other is not None for a in approaches) if config.other_side else 0)


# --- the gymnasium environment ------------------------------------------------------


class LaneChangeDecisionEnv(gym.Env):
    """The study's lane-change decision as a gymnasium environment (see the module doc)."""

    metadata = {"render_modes": []}

    def __init__(
        self, config: EnvConfig | None = None, approaches: list[Approach] | None = None, **overrides: Any
    ) -> None:
        cfg = config or default_config()
        self.config = replace(cfg, **overrides) if overrides else cfg
        self.approaches = approaches
        if approaches is not None and len(approaches) == 0:
            raise ValueError("replay mode needs at least one approach")
        if approaches is None and self.config.scenes == "recorded":
            raise ValueError("recorded scenes need approaches (see approaches_from_decisions)")
        self.action_space = gym.spaces.Discrete(2)
        self.observation_space = gym.spaces.Box(
            0.0, 1.0, shape=(len(observation_names(self.config)),), dtype=np.float32
        )
        self._scene: Scene | None = None
        self._steps = 0
        self._approach: Approach | None = None
        self._replay_i = 0

    def _obs(self) -> np.ndarray:
        assert self._scene is not None, "reset() first"
        return observation(self._scene, self.config)[0]

    def _info(self) -> dict[str, Any]:
        assert self._scene is not None, "reset() first"
        ind = indicators(self._scene, self.config.far_follower_m, self.config.range_m)
        # undefined indicators are None (NaN would make equal infos compare unequal)
        info: dict[str, Any] = {
            k: (None if np.isnan(x := float(getattr(ind, k)[0])) else x) for k in ("v_e", "t_f", "t_nf", "dv_nb")
        }
        if self._approach is not None:
            info["decision_id"] = self._approach.decision_id
            info["recorded"] = self._replay_i < len(self._approach)
        return info

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self._steps = 0
        if self.approaches is None:
            self._approach = None
            self._scene = sample_scenes(self.np_random, self.config, 1)
        else:
            idx = (options or {}).get("approach")
            if idx is None:
                idx = int(self.np_random.integers(len(self.approaches)))
            self._approach = self.approaches[idx]
            self._replay_i = 0
            self._scene = self._approach.scene.take(slice(0, 1))
        return self._obs(), self._info()

    def _t_from_press(self) -> np.ndarray | None:
        a = self._approach
        if a is None:
            return None
        if self._replay_i < len(a):
            return np.array([a.t_s[self._replay_i] - a.press_t_s])
        return np.array([(self._replay_i - len(a) + 1) * self.config.dt_s])

    def step(self, action):
        if self._scene is None:
            raise RuntimeError("call reset() before step()")
        act = np.array([int(action)])
        recorded_next = self._approach is not None and self._replay_i + 1 < len(self._approach)
        reward, terms, terminated, reached = transition(self._scene, act, self.config, self._t_from_press())
        if recorded_next:  # the data, not the constant-speed model, says whether the leader was reached
            reached[:] = False
            terminated = act == CHANGE
        self._steps += 1
        late = False
        if self._approach is not None and not terminated[0]:
            self._replay_i += 1
            if self._replay_i < len(self._approach):  # next recorded state replaces the extrapolation
                self._scene = self._approach.scene.take(slice(self._replay_i, self._replay_i + 1))
            late = float(self._t_from_press()[0]) > self.config.replay_late_s
        truncated = bool((self._steps >= self.config.max_steps or late) and not terminated[0])
        info = self._info()
        info.update(
            terms={k: float(terms[k][0]) for k in TERMS},
            changed=bool(act[0] == CHANGE),
            reached_leader=bool(reached[0]),
        )
        return self._obs(), float(reward[0]), bool(terminated[0]), truncated, info


class VecLaneChangeEnv:
    """`num_envs` random-start environments stepped together with numpy (for the trainer).

    Same model as `LaneChangeDecisionEnv` (shared `sample_scenes` / `transition`),
    auto-resetting: `step` returns the next observations, in which finished
    environments already show their new episode's first state; their last
    observation is in ``final_obs``.
    """

    def __init__(self, config: EnvConfig, num_envs: int, rng: np.random.Generator) -> None:
        self.config = config
        self.num_envs = num_envs
        self.rng = rng
        self.scene = sample_scenes(rng, config, num_envs)
        self.steps = np.zeros(num_envs, dtype=np.int64)

    def observe(self) -> np.ndarray:
        return observation(self.scene, self.config)

    def step(self, actions: np.ndarray) -> dict[str, Any]:
        """Step all environments; returns a dict of arrays (see the class doc)."""
        reward, terms, terminated, reached = transition(self.scene, actions, self.config)
        self.steps += 1
        truncated = ~terminated & (self.steps >= self.config.max_steps)
        done = terminated | truncated
        final_obs = obs = self.observe()
        if done.any():
            idx = np.flatnonzero(done)
            self.scene.put(idx, sample_scenes(self.rng, self.config, len(idx)))
            self.steps[idx] = 0
            obs = self.observe()
        return {
            "obs": obs,
            "final_obs": final_obs,
            "reward": reward,
            "terms": terms,
            "terminated": terminated,
            "truncated": truncated,
            "reached_leader": reached,
        }

    def state_dict(self) -> dict[str, Any]:
        return {"scene": {k: v.copy() for k, v in self.scene.as_arrays().items()}, "steps": self.steps.copy()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.scene = Scene(**{k: np.asarray(v).copy() for k, v in state["scene"].items()})
        self.steps = np.asarray(state["steps"]).copy()


#: "Time from the press" of a state of a side not taken [s]: every change there is far too early.
NO_PRESS_S = 1e6


class VecReplayEnv:
    """`num_envs` environments replaying recorded approaches (``EnvConfig.scenes = 'recorded'``).

    The trainer's counterpart of `LaneChangeDecisionEnv`'s replay mode, with the
    interface of `VecLaneChangeEnv`. An episode starts at a recorded state drawn
    uniformly over all states of all approaches (an epsilon-greedy agent that
    starts at the first state would seldom live to see the press) and steps through
    the approach's later states; after the press the press scene runs on at
    constant speeds for at most ``replay_late_s``. While a next recorded state
    exists the data, not the constant-speed model, says what happened: reaching
    the leader is only tested on extrapolated steps.

    With ``config.other_side`` the sides not taken (`Approach.other`) are replayed
    too, after the recorded approaches, as approaches without a press: their
    states are ``NO_PRESS_S`` before a press that never comes (a change is paid
    the `decisions` floor, a keep 0), and a keep at their last state ends the
    episode (truncated) instead of running on.
    """

    def __init__(self, config: EnvConfig, approaches: list[Approach], num_envs: int, rng: np.random.Generator) -> None:
        if not approaches:
            raise UserError("no recorded approaches to replay for this target")
        self.config = config
        self.num_envs = num_envs
        self.rng = rng
        others = [a.other for a in approaches if a.other is not None] if config.other_side else []
        self.states = Scene.concat([a.scene for a in approaches] + others)
        lengths = np.array([len(a) for a in approaches] + [len(o) for o in others])
        starts = np.r_[0, np.cumsum(lengths)[:-1]]
        self.last = np.repeat(starts + lengths - 1, lengths)  # index of the press of each state's approach
        self.t_rel = np.concatenate(
            [a.t_s - a.press_t_s for a in approaches] + [np.full(len(o), -NO_PRESS_S) for o in others]
        )
        self.no_press = np.repeat(np.arange(len(lengths)) >= len(approaches), lengths)  # states of sides not taken
        self.index = self.rng.integers(len(self.t_rel), size=num_envs)  # current recorded state, or its press
        self.late = np.zeros(num_envs)  # time run on past the press [s] (0 while recorded)
        self.scene = self.states.take(self.index)
        self.steps = np.zeros(num_envs, dtype=np.int64)

    def observe(self) -> np.ndarray:
        return observation(self.scene, self.config)

    def _draw_starts(self, idx: np.ndarray) -> np.ndarray:
        """New starting states (indices into `states`) for the environments `idx`, which start afresh."""
        return self.rng.integers(len(self.t_rel), size=len(idx))

    def t_from_press(self) -> np.ndarray:
        return np.where(self.late > 0, self.late, self.t_rel[self.index])

    def step(self, actions: np.ndarray) -> dict[str, Any]:
        """Step all environments; returns a dict of arrays (see `VecLaneChangeEnv.step`)."""
        recorded_next = (self.late == 0) & (self.index < self.last[self.index])
        no_press = self.no_press[self.index]
        reward, terms, terminated, reached = transition(self.scene, actions, self.config, self.t_from_press())
        reached = reached & ~recorded_next
        terminated = (np.asarray(actions) == CHANGE) | reached
        self.steps += 1
        go_on = ~terminated
        nxt = np.flatnonzero(go_on & recorded_next)
        self.index[nxt] += 1
        self.scene.put(nxt, self.states.take(self.index[nxt]))
        ends = go_on & ~recorded_next & no_press  # the last state of a side not taken: no press to run on to
        runs_on = go_on & ~recorded_next & ~no_press
        self.late[runs_on] += self.config.dt_s
        truncated = go_on & (ends | (self.steps >= self.config.max_steps) | (self.late > self.config.replay_late_s))
        done = terminated | truncated
        final_obs = obs = self.observe()
        if done.any():
            idx = np.flatnonzero(done)
            self.index[idx] = self._draw_starts(idx)
            self.late[idx] = 0.0
            self.steps[idx] = 0
            self.scene.put(idx, self.states.take(self.index[idx]))
            obs = self.observe()
        return {
            "obs": obs,
            "final_obs": final_obs,
            "reward": reward,
            "terms": terms,
            "terminated": terminated,
            "truncated": truncated,
            "reached_leader": reached,
        }

    def state_dict(self) -> dict[str, Any]:
        return {
            "scene": {k: v.copy() for k, v in self.scene.as_arrays().items()},
            "steps": self.steps.copy(),
            "index": self.index.copy(),
            "late": self.late.copy(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.scene = Scene(**{k: np.asarray(v).copy() for k, v in state["scene"].items()})
        self.steps = np.asarray(state["steps"]).copy()
        if "index" in state:
            self.index = np.asarray(state["index"]).copy()
            self.late = np.asarray(state["late"]).copy()


def make_vec_env(
    config: EnvConfig, num_envs: int, rng: np.random.Generator, approaches: list[Approach] | None = None
) -> "VecLaneChangeEnv | VecReplayEnv":
    """The trainer's vectorised environment for `config.scenes`."""
    if config.scenes == "recorded":
        if approaches is None:
            raise UserError("recorded scenes need the target's approaches")
        return VecReplayEnv(config, approaches, num_envs, rng)
    return VecLaneChangeEnv(config, num_envs, rng)


def register() -> None:
    """Register the environment with gymnasium (idempotent)."""
    if ENV_ID not in gym.registry:
        gym.register(
            id=ENV_ID,
            entry_point="rl.problem.env:LaneChangeDecisionEnv",
            max_episode_steps=None,
            disable_env_checker=False,
        )
