"""Trainer settings without torch: `laneprint`'s startup and the dashboard read
them without importing the trainer (`rl.learners.dqn` re-exports `DQNSettings`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

#: Fewest episodes `DQNSettings.resolved_episodes` gives a recorded-scenes agent.
MIN_RECORDED_EPISODES = 2000

#: Where episodes' scenes come from, and what the agent sees.
SCENES: tuple[str, ...] = ("synthetic", "recorded")
OBSERVATIONS: tuple[str, ...] = ("paper", "indicators", "direction", "acceptance")

#: The command line's default reward, chosen by held-out agreement (rl/README.md).
DEFAULT_REWARD = "decisions"
#: Each reward's own scenes and observation, used where the user names none:
#: `decisions` is paid by recorded presses; `timing` and `paper` are the study's
#: formulation (synthetic scenes, the 8-value state) as the first sessions measured it.
FORMULATIONS: dict[str, tuple[str, str]] = {
    "decisions": ("recorded", "acceptance"),
    "timing": ("synthetic", "paper"),
    "paper": ("synthetic", "paper"),
}


def resolve_formulation(
    reward: str | None, scenes: str | None, observation: str | None, lines: str = "analysis"
) -> tuple[str, str, str]:
    """(reward, scenes, observation) with the defaults filled in.

    Table 1's lines (`lines='paper'`) need no data, so the default reward there is
    `timing` on synthetic scenes; otherwise `DEFAULT_REWARD`.
    """
    reward = reward or (DEFAULT_REWARD if lines == "analysis" else "timing")
    own = FORMULATIONS.get(reward, ("synthetic", "paper"))
    return reward, scenes or own[0], observation or own[1]


@dataclass(frozen=True)
class DQNSettings:
    """Training settings (defaults: the study's Table 2, plus our vectorisation).

    The default 16 environments x two updates of 256 per vector step keep the
    study's replay ratio (32 sampled transitions per collected one) with 8 times
    fewer, 8 times larger updates; ``num_envs=1, gradient_steps=1, batch_size=32``
    is the study's loop.
    """

    episodes: int = 10000  # episodes to train (the study's N_e); on recorded scenes, unless set, 30 per recorded
    # approach of the target (`episodes_per_approach`), at most this
    episodes_per_approach: float = 30.0  # recorded scenes: episodes = this x recorded approaches, within
    # [MIN_RECORDED_EPISODES, episodes] (0 = exactly `episodes`); see `resolved_episodes`
    learning_rate: float = 0.005  # eta, Adam step size at the start
    learning_rate_end: float | None = 0.0005  # the step size falls linearly to this over `episodes` (None: constant)
    eps_start: float = 0.8  # epsilon_s, initial exploration
    eps_end: float = 0.1  # epsilon_e, final exploration
    exploration_fraction: float = 1.0  # share of `episodes` over which epsilon falls linearly
    gamma: float = 0.98  # discount factor per step
    buffer_size: int = 10000  # M_r, replay memory [transitions]
    learning_starts: int = 2000  # M_i, transitions stored before the first update
    batch_size: int = 256  # transitions per update (the study's M_m = 32 with num_envs = 1)
    target_update_episodes: int = 20  # N_u, copy the target network every this many episodes
    hidden: tuple[int, ...] = (128, 128, 128)  # hidden layer widths (ReLU)
    num_envs: int = 16  # environments stepped together (1 = the study's loop)
    gradient_steps: int = 2  # updates per vector step
    loss: str = "mse"  # 'mse' (eq. 5) or 'huber'
    double_q: bool = False  # Double DQN target: the online net picks the next action, the target net values it
    max_grad_norm: float = 10.0  # gradient clipping (0 = none)
    average_tau: float = 0.02  # if > 0, the policy is a Polyak average of the online weights (step tau per update) ...
    average_from: float = 0.5  # ... from this share of `episodes` on (before it, the online net is the policy)
    threads: int = 1  # torch intra-op threads (small nets oversubscribe with more)
    seed: int = 0  # seed of everything random: environments, exploration, sampling (numpy) and the network (torch)
    checkpoint_every: int = 500  # save a checkpoint every this many episodes (0 = never)

    def __post_init__(self) -> None:
        shares = ("eps_start", "eps_end", "exploration_fraction", "gamma", "average_tau", "average_from")
        bad = [f"{k} must be in [0, 1]" for k in shares if not 0.0 <= getattr(self, k) <= 1.0]
        bad += [
            f"{k} must be at least 1"
            for k in ("buffer_size", "batch_size", "num_envs", "gradient_steps", "target_update_episodes", "threads")
            if getattr(self, k) < 1
        ]
        bad += [
            f"{k} must be at least 0"
            for k in ("episodes", "episodes_per_approach", "learning_starts", "max_grad_norm", "checkpoint_every")
            if getattr(self, k) < 0
        ]
        if self.learning_rate <= 0 or (self.learning_rate_end is not None and self.learning_rate_end < 0):
            bad.append("learning_rate must be above 0 and learning_rate_end at least 0")
        if self.loss not in ("mse", "huber"):
            bad.append(f"loss must be 'mse' or 'huber', not {self.loss!r}")
        if bad:
            raise ValueError("; ".join(bad))

    def resolved_episodes(self, n_approaches: int | None) -> "DQNSettings":
        """These settings with `episodes` fixed for `n_approaches` recorded approaches (None: synthetic scenes).

        Held out, a recorded-scenes agent overfits the approaches it replays: the
        same number of replays per approach generalised best (rl/README.md).
        """
        if n_approaches is None or self.episodes_per_approach <= 0:
            return self
        n = int(min(self.episodes, max(MIN_RECORDED_EPISODES, round(self.episodes_per_approach * n_approaches))))
        return replace(self, episodes=n, episodes_per_approach=0.0)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "DQNSettings":
        d = dict(d)
        if "hidden" in d:
            d["hidden"] = tuple(d["hidden"])
        return DQNSettings(**d)


#: Who learns the Q function: per target the one of the DQN and the trees that agrees better across inner
#: folds of its sessions (`rl.learners.choice`), the study's DQN, or fitted Q iteration with boosted trees
#: (`rl.learners.trees`). The first is the default where it applies (`default_learner`).
LEARNERS: tuple[str, ...] = ("auto", "dqn", "trees")


def trees_fit(reward: str, scenes: str) -> bool:
    """Whether the tree learner (alone or in 'auto') can fit this formulation: the `decisions` reward on
    recorded scenes only (the trees fit the drivers' recorded presses)."""
    return reward == "decisions" and scenes == "recorded"


def default_learner(reward: str, scenes: str, fleet: bool = False) -> str:
    """The learner a command takes when none is named: 'auto' for one style or driver where the trees fit
    (`trees_fit`); the study's DQN for fleets (trained batched) and every other formulation, the paper's
    among them."""
    return "auto" if not fleet and trees_fit(reward, scenes) else "dqn"


#: The `decisions` reward's press scale the tree learner fits [s]: a change's reward falls by 1 per
#: half a second off the press, a sharp reward the trees resolve and the network does not (rl/README.md).
TREES_PRESS_SCALE_S = 0.5


@dataclass(frozen=True)
class TreeQSettings:
    """Fitted Q iteration with boosted regression trees (`--learner trees`), for the `decisions` reward.

    Each Q function is scikit-learn's `HistGradientBoostingRegressor` with these settings (the
    imitation classifier's tree size and step, no early stopping); `iterations` bootstraps Q(keep) this many
    steps back from the press.
    """

    iterations: int = 10  # fitted Q iterations of Q(keep)
    trees: int = 200  # boosting stages per Q function
    learning_rate: float = 0.05  # boosting step
    max_leaf_nodes: int = 15  # leaves per tree
    min_samples_leaf: int = 20  # states per leaf, at least
    press_weight: float = 2.0  # weight of a press state in the regressions, against 1 for the others
    gamma: float = 0.98  # discount per step (the DQN's)
    seed: int = 0  # seeds the trees' random tie-breaks

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.trees < 1:
            raise ValueError("the tree learner needs at least one iteration and one tree")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "TreeQSettings":
        return TreeQSettings(**d)


@dataclass(frozen=True)
class AutoSettings:
    """`--learner auto`: both learners' settings, and how much of the target's sessions decide between them."""

    dqn: DQNSettings = DQNSettings()  # the DQN's settings (in a config file: the [dqn] table)
    trees: TreeQSettings = TreeQSettings()  # the trees' settings (in a config file: the [trees] table)
    folds: int = 3  # inner folds of each driver's sessions that decide (every session scored once)
    margin: float = 0.01  # the trees are taken only when they agree better by more than this (a near-tie keeps
    # the study's DQN: on the shipped study a fold that took the trees by 0.006 lost 4 points held out)
    seed: int = 0  # seeds the inner folds and both learners
    stop_early: bool = True  # stop the inner DQNs once the choice cannot change (`reach`), and the agent's DQN
    # once the trees have won
    reach: float = 0.3  # how far the DQNs' pooled inner score is taken to rise over a whole run: with a share f of
    # their episodes left, a running score s may still end as high as s + reach * f ... (the running score of the
    # policy average rises as it trains: on the shipped study, 3 styles x 2 seeds, from half the episodes to the
    # end it rose by 0.08-0.28 x the share left; 0.1 took the trees where the DQN ended 3 points above them)
    reach_down: float = 0.03  # ... and as low as s - reach_down * f (there it fell by about 0.015 x the share left
    # at most)
    check_from: float = 0.5  # the running inner score is first checked at this share of the inner DQNs' episodes
    # (the policy average starts at `dqn.average_from`; before it the online net's score swings) ...
    check_every: float = 0.05  # ... and then every this share of them
    inner_trees: float = 0.5  # the inner folds' trees are quicker ones: this share of `trees.trees` boosting stages,
    # each step 1/share larger (the same shrinkage); the trees a run keeps are fitted as `trees` says. 1: the same
    # trees inside. On the shipped study (3 styles x 2 seeds) 0.5 moved the trees' inner score by at most 0.005 (0.25:
    # up to 0.018) for half their fitting time
    trees_beside: str = "process"  # 'process' (forked; Linux, else 'no') or 'thread': fit the trees' inner folds
    # beside the DQNs, on the other core; the DQNs' running scores wait for the trees' and are settled against them
    # in order, so the choice, its stops and the weights are those of 'no': the trees' inner folds first, then the
    # DQNs (which leaves a core idle all along: torch and the trees each run one thread)
    fleet_threads: int = 2  # torch threads of the choice's fleet while two or more DQNs train and no tree fit
    # runs (capped at the machine's cores; the lone DQN left at the end runs on `dqn.threads`, quicker for one net)

    def __post_init__(self) -> None:
        if self.reach < 0 or self.reach_down < 0 or not 0 <= self.check_from <= 1 or not 0 < self.check_every <= 1:
            raise ValueError("auto needs reach >= 0, reach_down >= 0, check_from in [0, 1] and check_every in (0, 1]")
        if not 0 < self.inner_trees <= 1:
            raise ValueError("auto needs inner_trees in (0, 1]")
        if self.fleet_threads < 1:
            raise ValueError("auto needs fleet_threads >= 1")
        if self.trees_beside not in ("process", "thread", "no"):
            raise ValueError(f"trees_beside must be 'process', 'thread' or 'no', not {self.trees_beside!r}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "dqn": self.dqn.to_dict(),
            "trees": self.trees.to_dict(),
            "folds": self.folds,
            "margin": self.margin,
            "seed": self.seed,
            "stop_early": self.stop_early,
            "reach": self.reach,
            "reach_down": self.reach_down,
            "check_from": self.check_from,
            "check_every": self.check_every,
            "inner_trees": self.inner_trees,
            "trees_beside": self.trees_beside,
            "fleet_threads": self.fleet_threads,
        }

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "AutoSettings":
        extra = {
            k: d[k]
            for k in (
                "stop_early",
                "reach",
                "reach_down",
                "check_from",
                "check_every",
                "inner_trees",
                "trees_beside",
                "fleet_threads",
            )
            if k in d
        }
        return AutoSettings(
            DQNSettings.from_dict(d["dqn"]),
            TreeQSettings.from_dict(d["trees"]),
            d.get("folds", 3),
            d.get("margin", 0.0),
            d.get("seed", 0),
            **extra,
        )


#: A learner's settings: the DQN's, the tree learner's, or both with the choice between them.
LearnerSettings = DQNSettings | TreeQSettings | AutoSettings


def learner_name(settings: LearnerSettings) -> str:
    """'dqn', 'trees' or 'auto'."""
    return {TreeQSettings: "trees", AutoSettings: "auto"}.get(type(settings), "dqn")


def learner_config(settings: LearnerSettings) -> dict[str, Any]:
    """How a run or a cross-validation stores its learner: ``{"learner": name, name: settings}``
    (a DQN run's settings stay under "dqn", as before the tree learner)."""
    return {"learner": learner_name(settings), learner_name(settings): settings.to_dict()}


def stored_learner(config: dict[str, Any]) -> LearnerSettings:
    """The learner settings stored by `learner_config` (a config without "learner" is a DQN's)."""
    kind = config.get("learner", "dqn")
    if kind == "trees":
        return TreeQSettings.from_dict(config["trees"])
    if kind == "auto":
        return AutoSettings.from_dict(config["auto"])
    return DQNSettings.from_dict(config["dqn"])


# --- can a run learn? (checked before it starts: `laneprint train`, `crossval`, the dashboard) -------------

#: A run whose expected transitions reach `learning_starts` only within this factor is 'late'.
LATE_FACTOR = 1.25


def expected_transitions(settings: DQNSettings, approach_steps: float) -> float:
    """Transitions a run of `settings.episodes` episodes is expected to collect, at most about.

    Each episode runs until the agent changes lane or its approach ends (`approach_steps`
    steps); exploring, the agent changes lane at a step with probability epsilon / 2 (a
    random action), epsilon falling linearly as in the trainer, and its network is taken to
    say 'keep' (an untrained network that says 'change' ends its episodes sooner). 300 episodes
    of `tests.support.rl_workspaces.analysed_workspace`'s approaches (27 steps): 1,678 expected, 1,344-1,440
    collected by seeds 0-2 (issue 23's 300-episode run collected 1,616).
    """
    import numpy as np

    n = int(settings.episodes)
    if n <= 0:
        return 0.0
    frac = np.minimum(1.0, np.arange(n) / max(1.0, settings.exploration_fraction * n))
    eps = settings.eps_start + frac * (settings.eps_end - settings.eps_start)
    p = np.clip(eps / 2.0, 1e-9, 1.0)
    steps = max(1.0, float(approach_steps))
    return float(np.sum((1.0 - (1.0 - p) ** steps) / p))


def decision_counts(decisions: Any) -> Any:
    """Per driver (index, as text) of an analysis's decisions table: `states` (its rows) and `presses`."""
    press = (decisions["label"] == "change").rename("presses")
    return press.groupby(decisions["driver_id"].astype(str)).agg(states="size", presses="sum")


def target_counts(counts: Any, styles: Any, kind: str, name: str) -> tuple[int, int]:
    """(states, presses) a target replays, from `decision_counts` (None: none): the driver's, or those of
    its style's members in the `styles` table."""
    if counts is None:
        return 0, 0
    drivers = [str(name)]
    if kind == "style" and styles is not None:
        drivers = (
            styles.loc[styles["style"].astype(str).str.lower() == str(name).lower(), "driver_id"].astype(str).tolist()
        )
    mine = counts.reindex(drivers).fillna(0).sum()
    return int(mine["states"]), int(mine["presses"])


def approach_steps(env: Any, n_states: int = 0, n_presses: int = 0) -> tuple[float | None, str]:
    """(steps an episode runs at most on average, where the figure comes from) for an environment
    config `env` (`rl.problem.env.EnvConfig`) replaying `n_states` recorded states (not-yet states and
    presses) of `n_presses` approaches.

    Recorded scenes: the states per approach plus the run-on after the press (`replay_late_s`);
    synthetic scenes: the mean initial time to collision with the leader over `dt_s` (the episode
    ends at the leader). (None, '') for recorded scenes without a press.
    """
    if env.scenes != "recorded":
        return (sum(env.t_f0_s) / 2.0) / env.dt_s, "synthetic scenes"
    if not n_presses:
        return None, ""
    return n_states / n_presses + env.replay_late_s / env.dt_s, "the target's recorded approaches"


@dataclass(frozen=True)
class LearningCheck:
    """Whether a run's episodes are enough for its network to start learning, said before it starts."""

    verdict: str
    """'' (learning begins in time), 'late' (only in the last part of the run) or 'never'."""
    expected: float
    """Transitions the run is expected to collect, at most about (`expected_transitions`)."""
    needed_episodes: int
    """About the fewest episodes for `expected` to reach `learning_starts` at these settings."""
    message: str
    """One sentence for the user ('' when the verdict is '')."""


def learning_check(
    settings: DQNSettings,
    steps: float | None,
    source: str = "",
    episodes_name: str = "--episodes",
    starts_name: str = "--learning-starts",
) -> LearningCheck:
    """Check `settings` against episodes of about `steps` steps (`approach_steps`; None: no check).

    `episodes_name`, `starts_name`: how the message names the two settings (the command line's
    options, or the dashboard's fields).
    """
    if not steps:
        return LearningCheck("", 0.0, 0, "")
    starts, episodes = int(settings.learning_starts), int(settings.episodes)
    expected = expected_transitions(settings, steps)
    if expected >= LATE_FACTOR * starts:
        return LearningCheck("", expected, 0, "")
    needed = _fewest_episodes(settings, steps, starts)
    where = f"episodes of up to {steps:.0f} steps in {source}, most ended early by exploration"
    if expected < starts:
        return LearningCheck(
            "never",
            expected,
            needed,
            (
                f"{episodes:,} episodes make at most about {expected:,.0f} transitions ({where}), but learning "
                f"starts after {starts:,}: the agent would learn nothing. Use at least about {needed:,} episodes "
                f"({episodes_name}), or lower {starts_name}."
            ),
        )
    return LearningCheck(
        "late",
        expected,
        needed,
        (
            f"learning would begin only near the end: at most about {expected:,.0f} transitions in {episodes:,} "
            f"episodes ({where}) against {starts:,} before the first update; more episodes ({episodes_name}) "
            f"or a lower {starts_name} give it time to learn."
        ),
    )


def _fewest_episodes(settings: DQNSettings, steps: float, transitions: float) -> int:
    """The fewest episodes whose expected transitions reach `transitions` (bisection; the schedule
    stretches with the run, so more episodes never collect fewer)."""
    lo, hi = 1, 2
    while expected_transitions(replace(settings, episodes=hi), steps) < transitions and hi < 10**7:
        lo, hi = hi, hi * 2
    while lo < hi:
        mid = (lo + hi) // 2
        if expected_transitions(replace(settings, episodes=mid), steps) >= transitions:
            hi = mid
        else:
            lo = mid + 1
    return hi
