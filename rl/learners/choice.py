"""`--learner auto`: for each target, the learner whose held-out agreement is higher on an inner split.

Neither learner is best everywhere (rl/README.md, "A tree Q function"): the trees resolve a
driver who changes the moment a gap turns acceptable, the DQN reads the smoother presses of
the shipped study better. So `choose_learner` holds out a share of the target's own training
sessions, fits both on the rest, scores each on the held-out presses and not-yet states (the
mean of the left and right balanced accuracies, so a weak side counts), and fits the better
one on all of them; the trees must win by more than `AutoSettings.margin` (a near-tie keeps
the DQN). Inside `crossval` this happens within each fold's training sessions: the
held-out fold never takes part in the choice.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from laneprint.progress import ProgressFn
from rl.baselines.imitation import labelled_states
from rl.problem.env import Approach, EnvConfig, learner_env
from rl.problem.rewards import CHANGE
from rl.settings import AutoSettings, DQNSettings, TreeQSettings

__all__ = ["Choice", "choose_learner", "chosen_settings", "fit_learner", "inner_split"]


@dataclass(frozen=True)
class Choice:
    """Which learner `choose_learner` took, and why."""

    learner: str  # 'dqn' or 'trees'
    scores: dict[str, float]  # each learner's inner held-out score (mean balanced accuracy over the sides)
    n_train: int  # approaches the candidates were fitted on
    n_holdout: int  # approaches they were scored on

    def to_dict(self) -> dict[str, Any]:
        return {"learner": self.learner, "scores": self.scores, "n_train": self.n_train,
                "n_holdout": self.n_holdout}


def session_of(decision_id: str) -> str:
    """The recording a decision belongs to (decision ids are '<recording_id>:<press index>')."""
    return decision_id.rsplit(":", 1)[0]


def inner_split(approaches: list[Approach], share: float, seed: int) -> tuple[list[Approach], list[Approach]]:
    """(fit, hold-out): about `share` of the sessions held out, drawn per driver so each driver keeps
    sessions on both sides where it has two or more (seeded)."""
    rng = np.random.default_rng([seed, 11])
    by_driver: dict[str, list[str]] = {}
    for a in approaches:
        s = session_of(a.decision_id)
        if s not in by_driver.setdefault(a.driver_id, []):
            by_driver[a.driver_id].append(s)
    held: set[str] = set()
    for sessions in by_driver.values():
        if len(sessions) < 2:
            continue
        k = max(1, int(round(share * len(sessions))))
        held.update(rng.choice(sorted(sessions), size=min(k, len(sessions) - 1), replace=False).tolist())
    if not held:  # one session per driver: hold out whole drivers' sessions instead
        sessions = sorted({session_of(a.decision_id) for a in approaches})
        k = max(1, int(round(share * len(sessions))))
        held = set(rng.choice(sessions, size=min(k, len(sessions) - 1), replace=False).tolist())
    fit = [a for a in approaches if session_of(a.decision_id) not in held]
    out = [a for a in approaches if session_of(a.decision_id) in held]
    return fit, out


def side_score(net: Any, approaches: list[Approach], cfg: EnvConfig) -> float:
    """Mean over the sides present of the balanced accuracy of `net`'s greedy actions."""
    from rl.learners.dqn import greedy_actions

    x, y = labelled_states(approaches, cfg)
    left = np.concatenate([a.scene.left for a in approaches])
    change = greedy_actions(net, x) == CHANGE
    scores = []
    for side in (left, ~left):
        yes, no = side & (y == 1), side & (y == 0)
        if yes.any() and no.any():
            scores.append(0.5 * (change[yes].mean() + (~change[no]).mean()))
    return float(np.mean(scores)) if scores else float("nan")


def fit_learner(approaches: list[Approach], cfg: EnvConfig, settings: DQNSettings | TreeQSettings,
                progress: ProgressFn | None = None, label: str = "agent") -> Any:
    """The Q network of `settings`' learner fitted on `approaches` (`cfg` as that learner reads it)."""
    if isinstance(settings, TreeQSettings):
        from rl.learners.trees import fit_tree_q

        return fit_tree_q(approaches, learner_env(cfg, "trees"), settings, progress, label)
    from rl.learners.dqn import DQNTrainer
    from laneprint.progress import report

    trainer = DQNTrainer(cfg, settings, approaches=approaches)

    def tick(t: Any) -> bool:
        report(progress, t.episodes_done, t.settings.episodes, label)
        return False

    trainer.train(on_vector_step=tick)
    return trainer.policy_net


def choose_learner(approaches: list[Approach], cfg: EnvConfig, settings: AutoSettings,
                   progress: ProgressFn | None = None, label: str = "agent") -> Choice:
    """Which learner to fit on `approaches`: both fitted on part of the sessions, scored on the rest.

    `cfg` is the DQN's environment; the trees read it with their own press scale (`learner_env`).
    With too few sessions to hold any out, the DQN is taken.
    """
    settings = with_seed(settings, settings.seed)
    fit, held = inner_split(approaches, settings.holdout, settings.seed)
    if not fit or not held:
        return Choice("dqn", {}, len(approaches), 0)
    scores = {}
    for name, s in (("dqn", settings.dqn), ("trees", settings.trees)):
        net = fit_learner(fit, cfg, s, progress, f"{label}: choosing, {name}")
        scores[name] = round(side_score(net, held, learner_env(cfg, name)), 4)
    gain = np.nan_to_num(scores["trees"], nan=-1.0) - np.nan_to_num(scores["dqn"], nan=-1.0)
    return Choice("trees" if gain > settings.margin else "dqn", scores, len(fit), len(held))


def chosen_settings(settings: AutoSettings, choice: Choice) -> DQNSettings | TreeQSettings:
    """The chosen learner's settings, seeded as `choose_learner` seeded it."""
    seeded = with_seed(settings, settings.seed)
    return seeded.trees if choice.learner == "trees" else seeded.dqn


def with_seed(settings: AutoSettings, seed: int) -> AutoSettings:
    """`settings` with every random choice seeded from `seed` (a crossval fold's)."""
    return replace(settings, seed=seed, dqn=replace(settings.dqn, seed=seed), trees=replace(settings.trees, seed=seed))
