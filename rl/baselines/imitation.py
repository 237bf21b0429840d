"""The imitation benchmark: a plain scikit-learn classifier of press vs not-yet states.

Beside the study's greedy benchmark, every report says how far the agent is from
a classifier trained directly on the drivers' decisions, on the same states and
the same observation the agent sees (`rl.problem.env.observation`), so the
comparison is about the method, not the information. Presses are rare (one per
approach against 10-30 not-yet states), so the classes are weighted to balance,
as the balanced accuracy that scores it.

    clf = ImitationClassifier(random_state=0).fit(approaches, cfg)
    policy = clf.policy(cfg)          # Scene -> actions, for `rl.evaluation.evaluate`
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from rl.problem.env import Approach, EnvConfig, observation
from rl.problem.rewards import CHANGE, KEEP
from rl.problem.scene import Scene


def labelled_states(approaches: list[Approach], cfg: EnvConfig) -> tuple[np.ndarray, np.ndarray]:
    """Observations of every recorded state and whether it is a press (1) or not yet (0)."""
    scene = Scene.concat([a.scene for a in approaches])
    y = np.concatenate([np.r_[np.zeros(len(a) - 1), 1.0] for a in approaches]).astype(int)
    return observation(scene, cfg), y


#: Rows from which `HistGradientBoostingClassifier` bins a subsample (drawn with its random_state).
_BINNING_SUBSAMPLE = 200_000


def fitted_classifier(
    approaches: list[Approach], cfg: EnvConfig, seed: int, cache: dict | None = None, key: tuple = ()
) -> "ImitationClassifier":
    """`ImitationClassifier(random_state=seed).fit(approaches, cfg)`, taken from `cache` when
    the same data (`key` names it, e.g. the drivers) and observation were fitted before.

    Without early stopping, feature subsampling or (below `_BINNING_SUBSAMPLE` rows)
    binning subsamples, the trees never draw from `random_state`: a fleet's agents of
    one driver with different seeds share one fit instead of fitting the same one again.
    The cache belongs to the caller (one fleet shard's evaluations), so it never outlives the data.
    """
    if cache is None:
        return ImitationClassifier(random_state=seed).fit(approaches, cfg)
    n_states = sum(len(a) for a in approaches)
    full_key = (
        key,
        cfg.observation,
        cfg.range_m,
        cfg.v_max_mps,
        cfg.far_follower_m,
        seed if n_states > _BINNING_SUBSAMPLE else None,
    )
    if full_key not in cache:
        cache[full_key] = ImitationClassifier(random_state=seed).fit(approaches, cfg)
    return cache[full_key]


@dataclass
class ImitationClassifier:
    """Gradient-boosted trees (`HistGradientBoostingClassifier`) on the observation, classes balanced."""

    max_iter: int = 200  # boosting rounds
    learning_rate: float = 0.05
    max_leaf_nodes: int = 15
    min_samples_leaf: int = 20
    threshold: float = 0.5  # change where the balanced press probability exceeds this
    random_state: int = 0

    def fit(self, approaches: list[Approach], cfg: EnvConfig) -> "ImitationClassifier":
        X, y = labelled_states(approaches, cfg)
        self.constant_ = None
        if len(np.unique(y)) < 2:  # one class only: predict it
            self.constant_ = CHANGE if y.all() else KEEP
            return self
        # one OpenMP thread: on a busy machine the trees' thread team spins waiting for
        # cores and a 4 s fit took 50 s (and a fleet evaluates one agent per core anyway)
        with threadpool_limits(limits=1, user_api="openmp"):
            self.model_ = self._fit_model(X, y)
        return self

    def _fit_model(self, X: np.ndarray, y: np.ndarray):
        from sklearn.ensemble import HistGradientBoostingClassifier

        return HistGradientBoostingClassifier(
            max_iter=self.max_iter,
            learning_rate=self.learning_rate,
            max_leaf_nodes=self.max_leaf_nodes,
            min_samples_leaf=self.min_samples_leaf,
            class_weight="balanced",
            early_stopping=False,
            random_state=self.random_state,
        ).fit(X, y)

    def press_probability(self, obs: np.ndarray) -> np.ndarray:
        """Balanced probability that each observation is a press."""
        if self.constant_ is not None:
            return np.full(len(obs), 1.0 if self.constant_ == CHANGE else 0.0)
        with threadpool_limits(limits=1, user_api="openmp"):  # see `fit`
            return self.model_.predict_proba(obs)[:, 1]

    def policy(self, cfg: EnvConfig):
        """The classifier as an evaluation policy: Scene -> 0 (change) / 1 (keep)."""

        def act(scene: Scene) -> np.ndarray:
            p = self.press_probability(observation(scene, cfg))
            return np.where(p > self.threshold, CHANGE, KEEP)

        return act
