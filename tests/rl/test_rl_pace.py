"""The drivers' pace: the advantage an agent's own change needs (`rl.drive.pace`, `choose_side`)."""

import numpy as np

from rl.drive.loop import choose_side
from rl.drive.pace import exceeds, lowest_threshold, onsets, thresholds


def test_an_onset_is_the_start_of_a_run_of_wanting_a_change():
    a = np.array([-1.0, 0.2, 0.6, 0.1, 0.7, 0.8, -np.inf, 0.9])
    assert onsets([a], 0.0) == 2  # from the start of the 0.2 run and after the -inf step
    assert onsets([a], 0.5) == 3  # 0.6, then 0.7-0.8, then 0.9
    assert onsets([a, a], 0.5) == 6 and onsets([a], 1.0) == 0
    assert onsets([np.array([0.4, 0.4])], 0.0) == 1  # wanting from the first step counts once


def test_the_threshold_is_the_lowest_whose_onsets_do_not_exceed_the_presses():
    # recordings that want a change in short bursts at low advantage and once for long at a high one
    a = [np.array([0.1, -1, 0.1, -1, 0.1, -1, 0.1, -1, 0.9, 0.9, 0.9, -1])] * 20
    tau, counts = lowest_threshold(a, presses=20)
    assert counts[0.0] == 100 and counts[tau] <= 20 and tau == 0.15  # the first grid step above the bursts
    assert lowest_threshold(a, presses=100)[0] == 0.0  # already at the drivers' pace: the agent as trained
    never = lowest_threshold([np.full(4, 9.0)] * 10, presses=0)[0]
    assert never == 3.0  # wants a change everywhere and its drivers never pressed: the largest tried


def test_an_excess_within_chance_leaves_the_agent_as_trained():
    """156 onsets against 150 presses (the shipped study's Aggressive agent) is no evidence of a faster
    pace: the threshold stays 0, where the strict count would take the first one under 150."""
    a = [np.array([0.1, -1.0, 0.1, -1.0])] * 75 + [np.array([0.1, -1.0, 0.1])] * 3  # 156 onsets, below 0.15
    assert onsets(a, 0.0) == 156 and onsets(a, 0.15) == 0
    assert not exceeds(156, 150) and exceeds(200, 150) and not exceeds(5, 1)  # a few events prove nothing
    assert lowest_threshold(a, presses=150)[0] == 0.0
    assert lowest_threshold(a, presses=120)[0] == 0.15  # 30 % more: beyond chance


def test_choose_side_needs_the_threshold():
    assert choose_side({0: 0.3}) == 0 and choose_side({0: 0.0}) == 0 and choose_side({0: -0.1}) is None
    assert choose_side({0: 0.3}, threshold=0.5) is None and choose_side({0: 0.6, 2: 0.55}, threshold=0.5) == 0
    assert choose_side({0: 0.2, 2: 0.55}, threshold=0.5) == 2


def test_choose_side_takes_each_lanes_own_threshold():
    need = {0: 0.0, 2: 0.5}  # to the right as trained, to the left the drivers' pace
    assert choose_side({0: 0.3, 2: 0.45}, need) == 0  # the larger advantage does not reach its side's threshold
    assert choose_side({0: 0.3, 2: 0.6}, need) == 2 and choose_side({0: -0.1, 2: 0.45}, need) is None


def test_by_side_the_presses_to_the_right_do_not_pay_for_onsets_to_the_left():
    """The agent wants left twice as often as its drivers pressed left and right never (in the closed
    loop the assistant's returns and the agent's own come after its changes to the left): pooled, the
    presses to the right hide the excess; by side the left needs the pace of the presses to the left."""
    adv = [{"left": np.array([0.1, -1.0] * 10), "right": np.full(20, -1.0)} for _ in range(10)]  # 100 onsets left
    presses = {"left": 50, "right": 50, "unknown": 0}
    pooled = thresholds(adv, presses, km=10.0)  # the default
    assert pooled["min_advantage"] == 0.0 and "min_advantage_by_side" not in pooled  # 100 onsets, 100 presses
    by_side = thresholds(adv, presses, km=10.0, by="side")
    assert by_side["by"] == "side" and by_side["min_advantage"] == 0.0
    assert by_side["min_advantage_by_side"] == {"left": 0.15, "right": 0.0}
    assert "to the left 10.00 as trained, 0.00 with at least 0.15, against 5.00 presses" in by_side["note"]
    # a press without a side: the pace cannot be read by side, and says so
    unknown = thresholds(adv, {**presses, "unknown": 3}, km=10.0, by="side")
    assert "min_advantage_by_side" not in unknown and "3 of the presses have no side" in unknown["note"]
