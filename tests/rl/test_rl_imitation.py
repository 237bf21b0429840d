"""The imitation benchmark's batched binning changes nothing but its speed."""

import numpy as np
import pytest

from rl.imitation import batched_binning


def _data(seed: int = 0, n: int = 800):
    rng = np.random.default_rng(seed)
    X = np.c_[rng.normal(size=n), rng.integers(0, 40, n), np.round(rng.random(n), 3), rng.exponential(size=n)]
    X[rng.random(n) < 0.05, 3] = np.nan
    y = (X[:, 0] + rng.normal(size=n) > 1.8).astype(int)  # rare presses, as the decisions
    return X, y


@pytest.mark.slow
def test_batched_binning_gives_sklearns_thresholds_and_trees():
    binning = pytest.importorskip("sklearn.ensemble._hist_gradient_boosting.binning")
    from sklearn.ensemble import HistGradientBoostingClassifier

    if not batched_binning():
        pytest.skip("this scikit-learn bins without weighted percentiles")
    X, y = _data()
    w = np.where(y == 1, len(y) / (2 * y.sum()), len(y) / (2 * (len(y) - y.sum())))
    patched = binning._weighted_percentile

    def fit():
        clf = HistGradientBoostingClassifier(max_iter=5, class_weight="balanced", early_stopping=False,
                                             random_state=0).fit(X, y)
        return clf.predict_proba(X), [binning._find_binning_thresholds(X[:, f], 255, w) for f in range(X.shape[1])]

    fast_proba, fast_thresholds = fit()
    binning._weighted_percentile = patched.original
    try:
        proba, thresholds = fit()
    finally:
        binning._weighted_percentile = patched
    np.testing.assert_array_equal(fast_proba, proba)
    for a, b in zip(fast_thresholds, thresholds):
        np.testing.assert_array_equal(a, b)


def test_a_drivers_classifier_is_fitted_once_for_all_its_seeds():
    from rl.env import approaches_from_decisions, formulation_config
    from rl.imitation import ImitationClassifier, fitted_classifier, labelled_states
    from rl.rewards import ReferenceLines
    from rl.testing import rule_driver_decisions

    lines = ReferenceLines.paper("Normal")
    approaches, _ = approaches_from_decisions(rule_driver_decisions(lines, 30, seed=3))
    cfg = formulation_config(lines, "decisions")
    cache: dict = {}
    first = fitted_classifier(approaches, cfg, 0, cache, key=("D01",))
    assert fitted_classifier(approaches, cfg, 1, cache, key=("D01",)) is first
    assert fitted_classifier(approaches, cfg, 1, cache, key=("D02",)) is not first
    X, _ = labelled_states(approaches, cfg)  # the seed changes nothing: the shared fit is seed 1's
    np.testing.assert_array_equal(first.press_probability(X),
                                  ImitationClassifier(random_state=1).fit(approaches, cfg).press_probability(X))
