"""The imitation benchmark: one fit per driver, whatever the seeds."""

import numpy as np


def test_a_drivers_classifier_is_fitted_once_for_all_its_seeds():
    from rl.problem.env import approaches_from_decisions, formulation_config
    from rl.baselines.imitation import ImitationClassifier, fitted_classifier, labelled_states
    from rl.problem.rewards import ReferenceLines
    from tests.support.rl_workspaces import rule_driver_decisions

    lines = ReferenceLines.paper("Normal")
    approaches, _ = approaches_from_decisions(rule_driver_decisions(lines, 30, seed=3))
    cfg = formulation_config(lines, "decisions")
    cache: dict = {}
    first = fitted_classifier(approaches, cfg, 0, cache, key=("D01",))
    assert fitted_classifier(approaches, cfg, 1, cache, key=("D01",)) is first
    assert fitted_classifier(approaches, cfg, 1, cache, key=("D02",)) is not first
    X, _ = labelled_states(approaches, cfg)  # the seed changes nothing: the shared fit is seed 1's
    np.testing.assert_array_equal(
        first.press_probability(X), ImitationClassifier(random_state=1).fit(approaches, cfg).press_probability(X)
    )
