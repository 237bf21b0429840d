"""Rewards: the study's eqs. 10-13 (typo fixed) and ours, with hand-computed values."""

import numpy as np
import pandas as pd
import pytest

from laneprint.errors import UserError
from rl.baselines.greedy import greedy_actions
from rl.problem.rewards import ReferenceLines, RewardSettings, action_rewards, closeness, step_reward
from rl.problem.scene import Indicators

LINES = ReferenceLines((0.2, 0.0), (0.2, 0.0), (1.0, -10.0))  # at v=20: t_f 4, t_nf 4, dv_nb 10


def ind(t_f, t_nf, dv_nb, v=20.0):
    arr = lambda x: np.array([np.nan if x is None else x], float)  # noqa: E731
    return Indicators(
        arr(v),
        arr(t_f),
        arr(t_nf),
        arr(dv_nb),
        arr(t_f) == arr(t_f),
        arr(t_nf) == arr(t_nf),
        arr(dv_nb) == arr(dv_nb),
        arr(0.0),
    )


def test_closeness_eq10():
    e = np.array([0.0, 0.2, 1.1, 2.0, 3.0])
    np.testing.assert_allclose(closeness(e, 0.2, 2.0), [1.0, 1.0, 0.5, 0.0, 0.0])


def test_paper_reward_actions_sum_to_three():
    paper = RewardSettings(name="paper")
    rc, rk = action_rewards(ind(4.0 + 1.1, 4.0, 10.0 + 2.75), LINES, paper, dt=0.5)
    assert rc[0] == pytest.approx(0.5 + 1.0 + 0.5)  # t_f half-way, t_nf exact, dv_nb (5-2.75)/4.5
    assert rc[0] + rk[0] == pytest.approx(3.0)


def test_timing_reward_is_one_off_advantage():
    timing = RewardSettings(name="timing")  # m = 1 s, 2 m/s; baseline 2.6; pass penalty 0.5
    r, terms = step_reward(ind(5.0, 4.0, 10.0), np.array([0]), LINES, timing, dt=0.5)
    assert r[0] == pytest.approx(3.0 - 2.6) and terms["base"][0] == -2.6
    r, terms = step_reward(ind(5.0, 4.0, 10.0), np.array([1]), LINES, timing, dt=0.5)
    assert r[0] == -0.5 and terms["pass"][0] == -0.5  # an acceptable gap passed up
    r, _ = step_reward(ind(7.0, 4.0, 10.0), np.array([1]), LINES, timing, dt=0.5)
    assert r[0] == 0.0  # t_f 3 s off: (2 - 3)/1 -> 0, sum 2 < 2.6: nothing passed up
    late = RewardSettings(name="timing", late_penalty_per_s=1.0, pass_penalty=0.0)
    r, terms = step_reward(ind(3.0, 4.0, 10.0), np.array([1]), LINES, late, dt=0.5)
    assert r[0] == pytest.approx(-0.5) and terms["late"][0] == pytest.approx(-0.5)


def test_undefined_indicators_rule():
    paper = RewardSettings(name="paper")
    rc, _ = action_rewards(ind(4.0, None, None), LINES, paper, dt=0.5)
    assert rc[0] == pytest.approx(3.0)  # no target-lane leader / no follower: no objection
    rc, _ = action_rewards(ind(None, 4.0, 10.0), LINES, paper, dt=0.5)
    assert rc[0] == pytest.approx(2.0)  # no closing leader: no reason to change


def test_greedy_picks_larger_immediate_reward():
    assert greedy_actions(ind(4.0, 4.0, 10.0), LINES)[0] == 0
    assert greedy_actions(ind(9.0, 9.0, 20.0), LINES)[0] == 1


def test_lines_from_table_and_paper():
    t = pd.DataFrame(
        {
            "scope": ["style"] * 3,
            "name": ["Normal"] * 3,
            "kind": ["typical"] * 3,
            "indicator": ["t_f", "t_nf", "dv_nb"],
            "A": [0.1, 0.2, 0.9],
            "b": [1.0, 2.0, -5.0],
            "source": ["typical driver D01"] * 3,
        }
    )
    lines = ReferenceLines.from_table(t, style="normal")
    assert lines.t_nf == (0.2, 2.0)
    assert ReferenceLines.paper("Aggressive").dv_nb == (1.01, -9.25)
    with pytest.raises(UserError):
        ReferenceLines.from_table(t, style="Defensive")
    with pytest.raises(UserError):
        RewardSettings(name="nope")
