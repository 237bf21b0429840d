"""The dwell and the follower's headway calibrated in closed loop (`rl.drive.calibrate`)."""

import numpy as np
import pandas as pd
import pytest

from rl.drive.calibrate import MIN_HEADWAYS, agent_headways, calibrated_headways, deconvolved_dwell, stays_by_kind


def test_stays_are_the_times_between_consecutive_changes_by_kind():
    ego = pd.DataFrame({"t_s": np.arange(9.0), "ego_lane": [0, 0, 1, 1, 1, 0, 0, 1, 1]})
    assert stays_by_kind([ego]) == {"left>right": [3.0], "right>left": [2.0]}
    assert stays_by_kind([ego, ego])["left>right"] == [3.0, 3.0]  # never across recordings
    assert stays_by_kind([pd.DataFrame({"t_s": [0.0, 1.0], "ego_lane": [0, 1]})]) == {}


def test_an_agent_that_comes_back_at_once_gets_the_drivers_stays():
    drivers = list(np.linspace(20.0, 40.0, 41))
    x = deconvolved_dwell(drivers, [10.0] * 30)  # the agent always wants back after 10 s
    assert np.percentile(x, 50) == pytest.approx(30.0, abs=1.0) and min(x) >= 20.0 and max(x) <= 40.0


def test_an_agent_that_stays_longer_than_its_drivers_needs_no_dwell():
    assert set(deconvolved_dwell([10.0, 12.0, 14.0, 16.0, 18.0], [30.0, 40.0, 50.0])) == {0.0}


def test_the_longer_of_the_dwell_and_the_agents_own_wait_is_distributed_like_the_drivers_stays():
    rng = np.random.default_rng(0)
    drivers = list(rng.uniform(10.0, 60.0, 400))
    agent = list(rng.uniform(5.0, 30.0, 400))
    x = deconvolved_dwell(drivers, agent)
    stays = np.maximum(rng.choice(x, 20000), rng.choice(agent, 20000))  # independent, as in closed loop
    for q in (25, 50, 75):
        assert np.percentile(stays, q) == pytest.approx(np.percentile(drivers, q), abs=2.5)


def test_the_calibrated_dwell_is_closer_to_the_drivers_than_their_own_times_drawn():
    """Drawn from the drivers' stays (`--dwell-draw`), the longer of the draw and the agent's wait comes out
    longer than their stays: their times already hold their own waits."""
    rng = np.random.default_rng(1)
    drivers, agent = rng.uniform(10.0, 60.0, 400), rng.uniform(15.0, 45.0, 400)
    calibrated = np.maximum(rng.choice(deconvolved_dwell(list(drivers), list(agent)), 20000), rng.choice(agent, 20000))
    drawn = np.maximum(rng.choice(drivers, 20000), rng.choice(agent, 20000))
    for q in (25, 50):
        want = np.percentile(drivers, q)
        assert abs(np.percentile(calibrated, q) - want) < abs(np.percentile(drawn, q) - want) - 1.0


def test_the_headway_is_calibrated_only_where_the_agent_takes_shorter_ones_than_its_drivers():
    def change(side: str, thw: float | None, source: str = "agent", started: bool = True) -> dict:
        return {
            "started": started,
            "source": source,
            "thw_nb_s": thw,
            "from_lane": 1,
            "target_lane": 2 if side == "left" else 0,
        }

    rng = np.random.default_rng(5)
    early = list(rng.uniform(0.4, 1.2, 60))  # returns right as soon as the overtaken car is behind
    rows = [change("right", x) for x in early] + [change("left", 3.0 + 0.01 * i) for i in range(40)]
    rows += [change("right", 0.1, source="rule"), change("right", 0.1, started=False), change("left", None)]
    mine = agent_headways(rows)
    assert mine["right"] == pytest.approx(early) and len(mine["left"]) == 40  # its own, started, near ones
    drivers = {"right": list(rng.uniform(1.0, 4.0, 80)), "left": [3.0 + 0.01 * i for i in range(40)]}
    lag = calibrated_headways(drivers, mine)
    assert "left" not in lag  # already its drivers' headways: nothing to wait for
    assert "right" not in calibrated_headways({"right": list(rng.uniform(0.2, 2.0, 80))}, mine)  # within their spread
    with_draw = np.maximum(rng.choice(lag["right"], 20000), rng.choice(early, 20000))
    assert np.median(with_draw) == pytest.approx(np.median(drivers["right"]), abs=0.15)
    assert calibrated_headways(drivers, {"right": early[: MIN_HEADWAYS - 1]}) == {}  # too few of its own
