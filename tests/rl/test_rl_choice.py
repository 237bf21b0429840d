"""`auto`'s learner choice in one fleet (`rl.learners.choice.choose_and_fit`): the choice of `choose_learner`,
the chosen DQN of `fit_learner`, and what cannot win stopped early."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest
import torch

import rl.learners.choice as choice_module
from rl.baselines.imitation import labelled_states
from rl.learners.choice import ChoiceTask, choose_and_fit, choose_learner, chosen_settings, fit_learner, inner_trees
from rl.problem.env import approaches_from_decisions, formulation_config
from rl.problem.rewards import ReferenceLines
from rl.settings import AutoSettings, DQNSettings, TreeQSettings
from tests.support.rl_workspaces import session_decisions

LINES = ReferenceLines.paper("Normal")
DQN = DQNSettings(episodes=300, learning_starts=300, episodes_per_approach=0)
WEAK_TREES = TreeQSettings(trees=1, iterations=1, learning_rate=0.01)  # a Q function that cannot resolve a press


@pytest.fixture(scope="module")
def study():
    approaches, _ = approaches_from_decisions(session_decisions(LINES, 4, 8))
    return approaches, formulation_config(LINES)


@pytest.mark.slow
def test_the_fleet_chooses_as_the_learners_one_after_another_and_keeps_the_same_dqn(study):
    approaches, cfg = study
    auto = AutoSettings(dqn=DQN, trees=WEAK_TREES, margin=0.2, stop_early=False)
    choice = choose_learner(approaches, cfg, auto)
    alone = fit_learner(approaches, cfg, chosen_settings(auto, choice))
    fitted = choose_and_fit([ChoiceTask(approaches, cfg, auto)])[0]
    assert fitted.choice.learner == choice.learner == "dqn" and not fitted.choice.stopped
    for name in ("dqn", "trees"):
        assert fitted.choice.scores[name] == pytest.approx(choice.scores[name], abs=0.05)
    x, _ = labelled_states(approaches, cfg)
    with torch.no_grad():
        q_alone, q_fleet = alone(torch.as_tensor(x)), fitted.net(torch.as_tensor(x))
    assert torch.allclose(q_alone, q_fleet, atol=1e-4)  # the same agent, up to summation order
    assert len(fitted.rows) == fitted.settings.episodes == DQN.episodes  # its metrics, one line per episode
    assert fitted.dqn_state is not None and fitted.dqn_state["counters"]["episodes_done"] == DQN.episodes


@pytest.mark.slow
def test_what_cannot_win_stops_early_and_the_choice_says_so(study):
    approaches, cfg = study
    # reach 0: the first check settles it; the weak trees cannot reach the DQN, which goes on alone
    auto = AutoSettings(dqn=DQN, trees=WEAK_TREES, margin=0.2, reach=0.0, check_from=0.5, trees_beside="no")
    fitted = choose_and_fit([ChoiceTask(approaches, cfg, auto)])[0]
    assert fitted.choice.learner == "dqn" and "stopped at" in fitted.choice.stopped
    assert fitted.choice.checks and fitted.choice.checks[0]["share"] < 1.0
    assert fitted.settings.episodes == len(fitted.rows) == DQN.episodes  # the target's DQN ran to its end
    # the trees out of reach (margin -2: they win whatever the DQN scores): every DQN stops, the trees are fitted
    trees = choose_and_fit([ChoiceTask(approaches, cfg, replace(auto, margin=-2.0))])[0]
    assert trees.choice.learner == "trees" and "stopped at" in trees.choice.stopped
    assert isinstance(trees.settings, TreeQSettings) and trees.net is not None and trees.dqn_state is None
    # reaches larger than any score can move (up and down): nothing stops, as `stop_early=False`
    # (and a cross-validation's DQNs come without their complete state: nothing keeps it)
    full = choose_and_fit([ChoiceTask(approaches, cfg, replace(auto, reach=10.0, reach_down=10.0))], keep_state=False)[
        0
    ]
    assert not full.choice.stopped and np.isfinite(full.choice.scores["dqn"])
    assert full.net is not None and full.dqn_state is None


_TREES_FIT = choice_module._trees_fit


def _slow_trees_fit(*args):
    """The trees still fitting when the DQNs reach their first check (a module function: a process pickles it)."""
    time.sleep(3.0)
    return _TREES_FIT(*args)


@pytest.mark.slow
@pytest.mark.parametrize("beside", ["thread", "process"])
def test_trees_beside_the_fleet_choose_stop_and_train_as_trees_first(study, monkeypatch, beside):
    approaches, cfg = study
    auto = AutoSettings(dqn=DQN, trees=TreeQSettings(trees=20, iterations=2), margin=0.2, reach=0.0, trees_beside="no")
    first = choose_and_fit([ChoiceTask(approaches, cfg, auto)])[0]
    monkeypatch.setattr(choice_module, "_trees_fit", _slow_trees_fit)
    fitted = choose_and_fit([ChoiceTask(approaches, cfg, replace(auto, trees_beside=beside))])[0]
    assert fitted.choice == first.choice and "stopped at" in first.choice.stopped
    assert len(fitted.choice.checks) == 1  # the checks up to the one that settled it, not those made while waiting
    for key, value in first.net.state_dict().items():
        assert torch.equal(fitted.net.state_dict()[key], value)


def test_the_inner_trees_are_quicker_ones_with_the_same_shrinkage():
    auto = AutoSettings(trees=TreeQSettings(trees=200, learning_rate=0.05))
    assert (inner_trees(auto).trees, inner_trees(auto).learning_rate) == (100, pytest.approx(0.1))
    assert inner_trees(replace(auto, inner_trees=1.0)) == auto.trees
    assert inner_trees(replace(auto, trees=WEAK_TREES)).trees == 1


def test_old_choice_settings_read_with_the_new_defaults():
    old = {"dqn": DQNSettings().to_dict(), "trees": TreeQSettings().to_dict(), "folds": 3, "margin": 0.01, "seed": 0}
    assert AutoSettings.from_dict(old) == AutoSettings()
    assert AutoSettings.from_dict(AutoSettings(reach=0.2, reach_down=0.05).to_dict()).reach_down == 0.05
    assert AutoSettings.from_dict(AutoSettings(inner_trees=1.0).to_dict()).inner_trees == 1.0
    with pytest.raises(ValueError):
        AutoSettings(check_every=0.0)
    with pytest.raises(ValueError):
        AutoSettings(inner_trees=0.0)


def test_a_crossvals_inner_folds_are_its_other_outer_folds_each_fitted_once(study):
    from rl.evaluation.crossval import FoldJob, outer_inner_folds
    from rl.learners.choice import session_of

    approaches, cfg = study  # one driver, four sessions: four outer folds of one session each
    sessions = sorted({session_of(a.decision_id) for a in approaches})
    jobs = [
        FoldJob(
            k,
            4,
            [a for a in approaches if session_of(a.decision_id) != s],
            [a for a in approaches if session_of(a.decision_id) == s],
            {},
            cfg,
            AutoSettings(seed=10 + k),
            k,
        )
        for k, s in enumerate(sessions)
    ]
    outer_inner_folds(jobs)
    keys = {}
    for job in jobs:
        assert job.inner is not None and len(job.inner) == 3
        held = sorted(a.decision_id for f in job.inner for a in f.held)
        assert held == sorted(a.decision_id for a in job.train)  # every training session scored once
        for f in job.inner:
            assert not {session_of(a.decision_id) for a in f.fit} & {session_of(a.decision_id) for a in f.held}
            keys.setdefault(f.key, []).append((sorted(a.decision_id for a in f.fit), f.seed))
    assert len(keys) == 6 and all(len(v) == 2 and v[0] == v[1] for v in keys.values())  # one fit, two folds
    assert {seed for v in keys.values() for _, seed in v} == {10, 11, 12}  # the lower fold's seed
