"""`--learner auto`: for each target, the learner whose held-out agreement is higher on an inner split.

Neither learner is best everywhere (rl/README.md, "A tree Q function"): the trees resolve a
driver who changes the moment a gap turns acceptable, the DQN reads the smoother presses of
the shipped study better. So `choose_learner` deals the target's own training sessions into
inner folds, fits both learners on all but one fold and predicts that one, scores each
learner's pooled predictions of every session once (the mean of the left and right balanced
accuracies on the presses and not-yet states, so a weak side counts), and fits the better one on
all of them; the trees must win by more than `AutoSettings.margin` (a near-tie keeps the DQN).
One split of a quarter of the sessions was too noisy a judge (rl/README.md). Inside `crossval`
this happens within each fold's training sessions: the held-out fold never takes part in the choice.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from laneprint.progress import ProgressFn
from rl.baselines.imitation import labelled_states
from rl.problem.env import Approach, EnvConfig, learner_env
from rl.problem.rewards import CHANGE
from rl.settings import AutoSettings, DQNSettings, TreeQSettings

__all__ = ["Choice", "choose_learner", "chosen_settings", "fit_learner", "inner_folds"]


@dataclass(frozen=True)
class Choice:
    """Which learner `choose_learner` took, and why."""

    learner: str  # 'dqn' or 'trees'
    scores: dict[str, float]  # each learner's inner held-out score (mean balanced accuracy over the sides)
    n_train: int  # the target's approaches
    n_holdout: int  # approaches the candidates were scored on (each once, by a fit without its session)
    folds: int = 0  # inner folds
    by_side: dict[str, dict[str, float]] = field(default_factory=dict)  # each learner's score per side

    def to_dict(self) -> dict[str, Any]:
        return {"learner": self.learner, "scores": self.scores, "n_train": self.n_train,
                "n_holdout": self.n_holdout, "folds": self.folds, "by_side": self.by_side}


def session_of(decision_id: str) -> str:
    """The recording a decision belongs to (decision ids are '<recording_id>:<press index>')."""
    return decision_id.rsplit(":", 1)[0]


def inner_folds(approaches: list[Approach], folds: int, seed: int) -> list[tuple[list[Approach], list[Approach]]]:
    """`folds` (fit, hold-out) pairs whose hold-outs cover the sessions once each (seeded).

    Each driver's sessions are shuffled and dealt in turn to the folds, so every driver with two or
    more sessions is held out somewhere and kept to fit on everywhere; a driver with one session is
    always fitted on. Where no driver has two sessions, whole sessions are dealt instead.
    """
    rng = np.random.default_rng([seed, 11])
    by_driver: dict[str, list[str]] = {}
    for a in approaches:
        s = session_of(a.decision_id)
        if s not in by_driver.setdefault(a.driver_id, []):
            by_driver[a.driver_id].append(s)
    groups = [sessions for sessions in by_driver.values() if len(sessions) >= 2]
    if not groups:  # one session per driver: deal the sessions themselves
        groups = [sorted({session_of(a.decision_id) for a in approaches})]
    fold_of: dict[str, int] = {}
    offset = 0
    for sessions in groups:
        for i, s in enumerate(rng.permutation(sorted(sessions))):
            fold_of[str(s)] = (offset + i) % folds  # a driver's sessions go to different folds first
        offset += len(sessions)  # the next driver starts where this one stopped: folds stay even
    pairs = []
    for f in range(folds):
        out = [a for a in approaches if fold_of.get(session_of(a.decision_id)) == f]
        fit = [a for a in approaches if fold_of.get(session_of(a.decision_id)) != f]
        if out and fit:
            pairs.append((fit, out))
    return pairs


def side_scores(change: np.ndarray, y: np.ndarray, left: np.ndarray) -> dict[str, float]:
    """The balanced accuracy of the changes `change` against labels `y`, per side present ('left', 'right')."""
    scores = {}
    for name, side in (("left", left), ("right", ~left)):
        yes, no = side & (y == 1), side & (y == 0)
        if yes.any() and no.any():
            scores[name] = round(float(0.5 * (change[yes].mean() + (~change[no]).mean())), 4)
    return scores


def held_out_changes(net: Any, approaches: list[Approach], cfg: EnvConfig) -> tuple[np.ndarray, ...]:
    """(`net`'s greedy change-or-not, the labels, whether the side is left) on `approaches`' states."""
    from rl.learners.dqn import greedy_actions

    x, y = labelled_states(approaches, cfg)
    left = np.concatenate([a.scene.left for a in approaches])
    return greedy_actions(net, x) == CHANGE, y, left


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
    """Which learner to fit on `approaches`: both fitted and scored across inner folds of the sessions.

    Each learner's held-out changes from every inner fold are pooled and scored once, so every
    session the target drove takes part in the choice. `cfg` is the DQN's environment; the trees read
    it with their own press scale (`learner_env`). With too few sessions to hold any out, the DQN is taken.
    """
    settings = with_seed(settings, settings.seed)
    pairs = inner_folds(approaches, settings.folds, settings.seed)
    if not pairs:
        return Choice("dqn", {}, len(approaches), 0)
    scores, by_side = {}, {}
    for name, s in (("dqn", settings.dqn), ("trees", settings.trees)):
        pooled = []
        for i, (fit, held) in enumerate(pairs):
            net = fit_learner(fit, cfg, s, progress, f"{label}: choosing, {name} {i + 1}/{len(pairs)}")
            pooled.append(held_out_changes(net, held, learner_env(cfg, name)))
        by_side[name] = side_scores(*(np.concatenate(parts) for parts in zip(*pooled)))
        scores[name] = round(float(np.mean(list(by_side[name].values()))), 4) if by_side[name] else float("nan")
    gain = np.nan_to_num(scores["trees"], nan=-1.0) - np.nan_to_num(scores["dqn"], nan=-1.0)
    return Choice("trees" if gain > settings.margin else "dqn", scores, len(approaches),
                  sum(len(held) for _, held in pairs), len(pairs), by_side)


def chosen_settings(settings: AutoSettings, choice: Choice) -> DQNSettings | TreeQSettings:
    """The chosen learner's settings, seeded as `choose_learner` seeded it."""
    seeded = with_seed(settings, settings.seed)
    return seeded.trees if choice.learner == "trees" else seeded.dqn


def with_seed(settings: AutoSettings, seed: int) -> AutoSettings:
    """`settings` with every random choice seeded from `seed` (a crossval fold's)."""
    return replace(settings, seed=seed, dqn=replace(settings.dqn, seed=seed), trees=replace(settings.trees, seed=seed))
