"""The held-back rule of `laneprint drive` (rl/drive/heldback.py): fast tests on synthetic scenes."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from laneprint.simulator.sumo.traffic import VehicleState
from rl.drive.heldback import (
    DEFAULT_PATIENCE_S,
    MIN_LAG_PRESSES,
    FollowStats,
    HeldBackRule,
    LeftBehind,
    Line,
    above_floors,
    accepts,
    dwell_from,
    dwell_times,
    following_before_press,
    lag_headways,
    patience_from,
    rule_target,
)
from rl.drive.loop import AgentControl, Watch, live_scene
from rl.problem.env import EnvConfig
from rl.problem.rewards import CHANGE, KEEP

DESIRED = 25.0  # [m/s]


class _Vehicle:
    def __init__(self) -> None:
        self.requests: list[tuple[str, int, float]] = []
        self.modes: list[int] = []

    def setLaneChangeMode(self, vid: str, mode: int) -> None:
        self.modes.append(mode)

    def changeLane(self, vid: str, lane: int, duration: float) -> None:
        self.requests.append((vid, lane, duration))


class _Api:
    def __init__(self) -> None:
        self.vehicle = _Vehicle()


def _never_changes(scene) -> np.ndarray:
    """A stub agent that always keeps (the shipped-study agent behind a followed leader)."""
    q = np.zeros((len(scene), 2))
    q[:, CHANGE], q[:, KEEP] = -1.5, 0.0
    return q


def _rule(patience: float = 5.0) -> HeldBackRule:
    return HeldBackRule(patience, gap_nf=Line(0.0, 30.0), gap_nb=Line(0.0, 30.0), thw_nb=Line(0.0, 3.0))


def _follow(
    others: dict[str, VehicleState],
    seconds: float,
    rule: HeldBackRule | None = None,
    use_rule: bool = True,
    v_e: float = 20.0,
) -> tuple[AgentControl, _Api, list[float]]:
    """The ego in lane 0 of two, following `others['f']` at its speed, for `seconds` of 0.1 s steps;
    the times at which a change was requested."""
    control = AgentControl(
        _never_changes, EnvConfig(observation="indicators"), 0.1, 2, rule or _rule(), DESIRED, use_rule
    )
    api = _Api()
    control.start(api)
    times: list[float] = []
    for i in range(int(round(seconds / 0.1))):
        t = round(0.1 * i, 6)
        ego = VehicleState(x=100.0 + v_e * t, v=v_e, lane=0, length=4.5)
        moved = {k: VehicleState(s.x + s.v * t, s.v, s.lane, s.length) for k, s in others.items()}
        n = len(api.vehicle.requests)
        control.step(api, t, ego, 0.0, moved)
        if len(api.vehicle.requests) > n:
            times.append(t)
    return control, api, times


LEADER = {"f": VehicleState(130.0, 20.0, 0, 4.5)}  # 30 m ahead at the ego's speed: 5 m/s below its desired


def test_a_followed_slower_leader_triggers_the_rule_after_the_patience_not_before():
    control, api, times = _follow(LEADER, 12.0)
    assert times and times[0] == pytest.approx(5.0, abs=0.51)  # the first decision step once held 5 s
    assert all(t >= 5.0 - 1e-9 for t in times)
    assert api.vehicle.requests[0] == ("ego", 1, 0.5)
    assert {d.source for d in control.decisions} == {"rule"}
    _, api, times = _follow(LEADER, 4.9)
    assert times == [] and api.vehicle.requests == []


def test_an_unacceptable_gap_does_not_trigger():
    close_follower = {**LEADER, "b": VehicleState(80.0, 20.0, 1, 4.5)}  # lag gap 15.5 m < 30 m
    control, api, times = _follow(close_follower, 20.0)
    assert times == [] and control.stats.n_held > 0
    short_lead = {**LEADER, "l": VehicleState(115.0, 21.0, 1, 4.5)}  # lead gap 10.5 m, 22.5 m at 12 s: < 30 m
    _, _, times = _follow(short_lead, 12.0)
    assert times == []
    tailgater = {**LEADER, "b": VehicleState(25.5, 25.0, 1, 4.5)}  # lag gap 70 m, 40 m at 6 s, headway < 3 s
    _, _, times = _follow(tailgater, 6.0)
    assert times == []


def test_a_far_follower_and_a_wide_gap_are_accepted():
    wide = {**LEADER, "b": VehicleState(40.0, 20.0, 1, 4.5), "l": VehicleState(170.0, 24.0, 1, 4.5)}
    _, _, times = _follow(wide, 8.0)  # lag gap 55.5 m, but its headway 2.78 s < 3 s
    assert times == []
    wider = {**LEADER, "b": VehicleState(30.0, 20.0, 1, 4.5), "l": VehicleState(170.0, 24.0, 1, 4.5)}
    _, _, times = _follow(wider, 8.0)  # lag 65.5 m, headway 3.3 s; lead 65.5 m, 4 m/s faster than the leader
    assert times and times[0] == pytest.approx(5.0, abs=0.51)
    ego = VehicleState(100.0, 20.0, 0, 4.5)
    strict = HeldBackRule(5.0, Line(0.0, 30.0), Line(0.0, 30.0), Line(0.0, 6.0))
    far = live_scene(ego, {"b": VehicleState(-10.0, 20.0, 1, 4.5)}, 1)[0]  # 105.5 m > far_follower_m, 5.3 s
    near = live_scene(ego, {"b": VehicleState(5.0, 20.0, 1, 4.5)}, 1)[0]  # 90.5 m, headway 4.5 s < 6 s
    assert accepts(strict, far, 150.0)[0] and not accepts(strict, near, 150.0)[0]


def test_no_rule_when_the_target_lane_is_not_faster_or_the_leader_is_not_slow():
    slower_lane = {**LEADER, "l": VehicleState(190.0, 20.5, 1, 4.5)}  # wide gap, but no faster
    _, _, times = _follow(slower_lane, 12.0)
    assert times == []
    quick = {"f": VehicleState(130.0, 24.5, 0, 4.5)}  # 0.5 m/s below the desired speed: not held back
    control, _, times = _follow(quick, 12.0, v_e=24.5)
    assert times == [] and control.stats.n_held == 0


def test_the_pure_agent_is_measured_but_not_helped():
    control, api, times = _follow(LEADER, 20.0, use_rule=False)
    assert times == [] and api.vehicle.requests == []
    s = control.stats.summary()
    assert s["held_share"] == 1.0 and s["longest_passed_up_s"] == pytest.approx(20.0, abs=0.01)
    assert s["advantage_held_nonneg"] == 0 and s["held_tf_above_line_steps"] == s["held_steps"] == 40


def test_the_comparator_only_looks():
    control, api = Watch(EnvConfig(), 0.1, 2, _rule(), DESIRED), _Api()
    control.start(api)
    for i in range(100):
        t = 0.1 * i
        control.step(
            api, t, VehicleState(100.0 + 20 * t, 20.0, 0, 4.5), 0.0, {"f": VehicleState(130.0 + 20 * t, 20.0, 0, 4.5)}
        )
    assert api.vehicle.modes == [] and api.vehicle.requests == []  # SUMO's own lane changing stays on
    assert control.n_asked == 20 and control.stats.n_held == 20


def test_rule_target_takes_the_faster_accepted_lane():
    ego = VehicleState(100.0, 20.0, 1, 4.5)
    others = {
        "f": VehicleState(130.0, 20.0, 1, 4.5),
        "l": VehicleState(170.0, 23.0, 2, 4.5),
        "r": VehicleState(180.0, 26.0, 0, 4.5),
    }
    scenes = {k: live_scene(ego, others, k)[0] for k in (2, 0)}
    assert rule_target(_rule(), scenes, 4.0, 150.0) is None  # not patient long enough yet
    assert rule_target(_rule(), scenes, 5.0, 150.0) == 0
    scenes = {k: live_scene(ego, {"f": others["f"]}, k)[0] for k in (2, 0)}
    assert rule_target(_rule(), scenes, 5.0, 150.0) == 2  # both free: overtake on the left


def test_lines_are_read_within_their_speeds_and_above_their_floor():
    line = Line(5.0, -60.0, v_lo=10.0, v_hi=25.0, floor=8.0)
    assert line.at([5.0, 14.0, 20.0, 30.0]) == pytest.approx([8.0, 10.0, 40.0, 65.0])
    ego = VehicleState(100.0, 20.0, 0, 4.5)
    rule = HeldBackRule(5.0, line, Line(0.0, 30.0), Line(0.0, 3.0))
    near = live_scene(ego, {"l": VehicleState(140.0, 22.0, 1, 4.5)}, 1)[0]  # lead gap 35.5 m < 40 m
    far = live_scene(ego, {"l": VehicleState(150.0, 22.0, 1, 4.5)}, 1)[0]
    assert not accepts(rule, near, 150.0)[0] and accepts(rule, far, 150.0)[0]


def test_rule_round_trips_through_json():
    rule = HeldBackRule(6.0, Line(1.0, 2.0, 3.0, 4.0, 5.0), Line(0.0, 30.0), Line(0.0, 3.0), source={"x": "y"})
    assert HeldBackRule.from_dict(json.loads(json.dumps(rule.to_dict()))) == rule


def test_follow_stats_passed_up_is_per_stretch():
    s = FollowStats(0.5)
    for gap in (True, True, False, True):
        s.record(True, 0.0, gap, gap, False)
    s.record(False, 0.0, True, True, True)
    for _ in range(2):
        s.record(True, 0.0, True, False, False)
    assert s.longest_passed_up_s == pytest.approx(1.5) and s.longest_passed_up_faster_s == pytest.approx(1.5)
    assert s.n_held == 6 and s.n_steps == 7


def _approach(rec: str, press: int, closing: list[float]) -> pd.DataFrame:
    n = len(closing)
    return pd.DataFrame(
        {
            "recording_id": rec,
            "press_index": press,
            "t_s": np.arange(n) * 0.5,
            "ego_v_mps": 20.0,
            "f_v_mps": 20.0 - np.asarray(closing),
            "f_present": True,
            "label": ["keep"] * (n - 1) + ["change"],
        }
    )


def test_patience_is_the_median_following_time_before_presses():
    followed = [_approach("r", k, [5, 3] + [0.2] * (k + 6)) for k in range(5)]  # 3.5-5.5 s after following
    closing = [_approach("r", 10 + k, [5, 4, 3, 2]) for k in range(5)]
    d = pd.concat(followed + closing, ignore_index=True)
    assert sorted(following_before_press(d)) == [0.0] * 5 + [3.0, 3.5, 4.0, 4.5, 5.0]
    patience, why = patience_from(d)
    assert patience == pytest.approx(4.0) and "5 of 10 presses" in why
    patience, why = patience_from(pd.concat(followed[:2] + closing, ignore_index=True))
    assert patience == DEFAULT_PATIENCE_S and "fewer than" in why


def test_the_agent_does_not_return_behind_the_leader_the_rule_left():
    """After the rule's change to the left, an agent that wants back right is not asked to while the
    leader it left is still ahead; once passed, it is."""

    def back_right(scene) -> np.ndarray:
        q = np.zeros((len(scene), 2))
        q[:, CHANGE] = np.where(scene.left, -1.5, 0.5)  # keeps about the left, changes back right
        return q

    control = AgentControl(back_right, EnvConfig(observation="indicators"), 0.1, 2, _rule(), DESIRED, True)
    api = _Api()
    control.start(api)
    truck = VehicleState(130.0, 20.0, 0, 12.0)
    for i in range(55):  # held behind the truck in lane 0: the rule asks for lane 1 after 5 s (t = 5.4)
        control.step(
            api,
            0.1 * i,
            VehicleState(100.0 + 2.0 * i, 20.0, 0, 4.5),
            0.0,
            {"f": VehicleState(truck.x + 2.0 * i, 20.0, 0, 12.0)},
        )
    assert api.vehicle.requests == [("ego", 1, 0.5)] and control.overtakings[-1].leader_id == "f"
    # now in lane 1, the truck 20 m ahead in lane 0: the agent's wish to go right is vetoed
    control.step(api, 6.0, VehicleState(230.0, 24.0, 1, 4.5), 0.0, {"f": VehicleState(250.0, 20.0, 0, 12.0)})
    for i in range(1, 5):
        control.step(
            api, 6.0 + 0.1 * i, VehicleState(230.0, 24.0, 1, 4.5), 0.0, {"f": VehicleState(250.0, 20.0, 0, 12.0)}
        )
    assert len(api.vehicle.requests) == 1 and control.n_vetoed == 1
    for i in range(5, 10):  # the truck passed (its centre 30 m behind the ego's): the agent returns
        control.step(
            api, 6.0 + 0.1 * i, VehicleState(300.0, 24.0, 1, 4.5), 0.0, {"f": VehicleState(270.0, 20.0, 0, 12.0)}
        )
    assert api.vehicle.requests[-1] == ("ego", 0, 0.5) and control.decisions[-1].source == "agent"


def test_no_veto_behind_a_leader_that_no_longer_holds_the_ego_back():
    """The car the ego changed out behind speeds up and pulls away: the overtaking is over, the agent's
    return behind it is requested (before, it waited until that car was out of sight)."""

    def back_right(scene) -> np.ndarray:
        q = np.zeros((len(scene), 2))
        q[:, CHANGE] = np.where(scene.left, -1.5, 0.5)
        return q

    control = AgentControl(back_right, EnvConfig(observation="indicators"), 0.1, 2, _rule(), DESIRED, True)
    api = _Api()
    control.overtakings.append(LeftBehind(0, "f"))  # an overtaking of "f" from lane 0, under way
    ego = VehicleState(230.0, 24.0, 1, 4.5)
    for v_f, requests in ((20.0, 0), (DESIRED - 1.0, 1)):  # slower than the ego's desired speed, then not
        for i in range(5):
            control.step(api, 6.0 + 0.1 * i, ego, 0.0, {"f": VehicleState(290.0, v_f, 0, 4.5)})
        assert len(api.vehicle.requests) == requests
    assert api.vehicle.requests[-1] == ("ego", 0, 0.5) and control.n_vetoed == 1


def test_no_change_of_the_agent_into_a_gap_below_the_targets_floor():
    def always(scene) -> np.ndarray:
        q = np.zeros((len(scene), 2))
        q[:, CHANGE] = 0.5
        return q

    rule = HeldBackRule(
        5.0, Line(0.0, 30.0, floor=8.0), Line(0.0, 30.0, floor=6.0), Line(0.0, 3.0, floor=0.75), undo_check=False
    )  # an agent that changes everywhere would undo every change to the left
    ego = VehicleState(100.0, 17.0, 0, 4.5)
    for cut_in, n in ((VehicleState(106.0, 7.0, 1, 4.5), 0), (VehicleState(115.0, 15.0, 1, 4.5), 1)):
        for use_rule in (True, False):  # lead gap 1.5 m (below the floor), then 10.5 m
            control, api = AgentControl(always, EnvConfig(), 0.1, 2, rule, DESIRED, use_rule), _Api()
            for i in range(5):
                control.step(api, 0.1 * i, ego, 0.0, {"nf": cut_in})
            assert len(api.vehicle.requests) == (n if use_rule else 1)  # the pure agent has no floor
            assert control.n_gated == (1 - n if use_rule else 0)


def test_no_change_closing_on_the_target_leader_faster_than_the_floor():
    rule = HeldBackRule(
        5.0, Line(0.0, 30.0, floor=8.0), Line(0.0, 30.0, floor=6.0), Line(0.0, 3.0, floor=0.75), t_nf_floor_s=1.5
    )
    ego = VehicleState(100.0, 23.0, 1, 4.5)
    fast_close = live_scene(ego, {"r": VehicleState(115.0, 10.0, 0, 4.5)}, 0)[0]  # 10.5 m, t_nf 0.8 s
    slow_close = live_scene(ego, {"r": VehicleState(115.0, 20.0, 0, 4.5)}, 0)[0]  # 10.5 m, t_nf 3.5 s
    assert not above_floors(rule, fast_close, 150.0)[0] and above_floors(rule, slow_close, 150.0)[0]


def test_the_rule_completes_an_overtaking_once_the_leader_is_passed():
    control = AgentControl(_never_changes, EnvConfig(observation="indicators"), 0.1, 2, _rule(), DESIRED, True)
    api = _Api()
    for i in range(55):  # held 5 s behind the truck: the rule changes left
        control.step(
            api,
            0.1 * i,
            VehicleState(100.0 + 2.0 * i, 20.0, 0, 4.5),
            0.0,
            {"f": VehicleState(130.0 + 2.0 * i, 20.0, 0, 12.0)},
        )
    assert api.vehicle.requests == [("ego", 1, 0.5)]
    for k, (ego_x, truck_x) in enumerate(((230.0, 250.0), (300.0, 280.0), (400.0, 300.0))):
        for i in range(5):  # alongside, just passed (lag gap 11.75 m < 30 m), then far ahead (91.75 m)
            control.step(
                api,
                6.0 + k + 0.1 * i,
                VehicleState(ego_x, 25.0, 1, 4.5),
                0.0,
                {"f": VehicleState(truck_x, 20.0, 0, 12.0)},
            )
        assert len(api.vehicle.requests) == (1 if k < 2 else 2)
    assert api.vehicle.requests[-1] == ("ego", 0, 0.5) and control.decisions[-1].source == "return"
    for i in range(5):  # back in lane 0: the overtaking is complete
        control.step(
            api, 10.0 + 0.1 * i, VehicleState(400.0, 25.0, 0, 4.5), 0.0, {"f": VehicleState(300.0, 20.0, 0, 12.0)}
        )
    assert control.overtakings == [] and control.left_behind is None


def test_overtakings_stack_on_three_lanes():
    """0 -> 1 behind a truck, 1 -> 2 behind a car: returned to 1 once the car is passed, then to 0."""
    control = AgentControl(_never_changes, EnvConfig(observation="indicators"), 0.1, 3, _rule(), DESIRED, True)
    api = _Api()
    t = [0.0]

    def until_request(ego: VehicleState, others: dict, n: int = 200) -> None:
        """Steps of 0.1 s until the control requests a change (at most `n`), then the lane change starts."""
        before = len(api.vehicle.requests)
        for _ in range(n):
            control.step(api, t[0], ego, 0.0, others)
            t[0] += 0.1
            if len(api.vehicle.requests) > before:
                break
        for _ in range(5):  # under way: off the lane centre
            control.step(api, t[0], ego, 1.0, others)
            t[0] += 0.1

    truck, car = VehicleState(130.0, 20.0, 0, 12.0), VehicleState(160.0, 20.0, 1, 4.5)
    until_request(VehicleState(100.0, 20.0, 0, 4.5), {"t": truck})  # held behind the truck 5 s
    assert api.vehicle.requests == [("ego", 1, 0.5)]
    until_request(VehicleState(120.0, 20.0, 1, 4.5), {"t": truck, "c": car})  # held behind the car 5 s
    assert api.vehicle.requests[-1] == ("ego", 2, 0.5) and [o.lane for o in control.overtakings] == [0, 1]
    far = {"t": VehicleState(100.0, 20.0, 0, 12.0), "c": VehicleState(150.0, 20.0, 1, 4.5)}
    until_request(VehicleState(260.0, 25.0, 2, 4.5), far)  # both passed, gaps 105 m and 157 m
    assert api.vehicle.requests[-1] == ("ego", 1, 0.5) and control.decisions[-1].source == "return"
    until_request(VehicleState(260.0, 25.0, 1, 4.5), far)
    assert api.vehicle.requests[-1] == ("ego", 0, 0.5) and control.decisions[-1].source == "return"
    until_request(VehicleState(260.0, 25.0, 0, 4.5), far, n=20)
    assert control.overtakings == [] and len(api.vehicle.requests) == 4


def _presses(rows: list[tuple[str, float, str]]) -> pd.DataFrame:
    """Press rows (recording, press time, side); each lane change 1.5 s after its press."""
    return pd.DataFrame(
        {
            "recording_id": [r for r, _, _ in rows],
            "press_t_s": [t for _, t, _ in rows],
            "lane_change_t_s": [t + 1.5 for _, t, _ in rows],
            "lc_direction": [s for _, _, s in rows],
            "label": "change",
        }
    )


def _back_and_forth() -> pd.DataFrame:
    """One recording: left, right 10-15 s after the change, left again 2 s after that, ... (6 left>right,
    5 right>left)."""
    rows, t = [], 0.0
    for k in range(6):
        rows.append(("r", t, "left"))
        t += 1.5 + 10.0 + k  # left>right: 10-15 s after the change
        rows.append(("r", t, "right"))
        t += 1.5 + 2.0  # right>left: 2 s after the change
    return _presses(rows)


def test_dwell_is_a_percentile_of_the_time_from_a_change_to_the_next_press():
    rows = _back_and_forth()
    dwell, why = dwell_from(rows)
    assert dwell["left>right"] == pytest.approx(10.25)  # the 5th percentile of 10-15 s (DWELL_PERCENTILE)
    assert dwell["right>left"] == pytest.approx(2.0) and "left>right 6, right>left 5" in why
    assert "percentile 5 " in why
    quartile, why = dwell_from(rows, percentile=25.0)  # drive --dwell-percentile 25
    assert quartile["left>right"] == pytest.approx(11.25) and "percentile 25 " in why
    # pairs never span recordings, and kinds with fewer than MIN_DWELL_PAIRS are not read
    few = _presses([(f"r{k}", 0.0, "left") for k in range(10)] + [("r0", 20.0, "right")])
    assert dwell_from(few)[0] == {}


def test_the_agent_is_not_asked_about_a_side_sooner_after_a_change_than_its_drivers_pressed():
    def always(scene) -> np.ndarray:
        q = np.zeros((len(scene), 2))
        q[:, CHANGE] = 0.5
        return q

    rule = HeldBackRule(5.0, Line(0.0, 0.0), Line(0.0, 0.0), Line(0.0, 0.0), dwell_s={"left>right": 4.0})
    for use_rule, first_back in ((True, 4.0), (False, 0.0)):
        control, api = (
            AgentControl(always, EnvConfig(observation="indicators"), 0.1, 2, rule, DESIRED, use_rule),
            _Api(),
        )
        control.start(api)
        control.step(api, 0.0, VehicleState(100.0, 20.0, 0, 4.5), 0.0, {})  # in lane 0 ...
        times = []
        for i in range(1, 61):  # ... then in lane 1 from t = 0.1 s: a change to the left just made
            t = round(0.1 * i, 6)
            n = len(api.vehicle.requests)
            control.step(api, t, VehicleState(100.0 + 2.0 * i, 20.0, 1, 4.5), 0.0, {})
            if len(api.vehicle.requests) > n:
                times.append(t)
        assert times and times[0] >= 0.1 + first_back - 1e-9 and times[0] < 0.1 + first_back + 0.5
        assert (control.n_dwelled > 0) == use_rule
        if use_rule:
            assert control.decisions[0].too_soon == [] and api.vehicle.requests[0][1] == 0


def test_drawn_dwells_come_from_the_drivers_own_times():
    times = dwell_times(_back_and_forth())
    assert times["left>right"] == pytest.approx([10.0, 11.0, 12.0, 13.0, 14.0, 15.0])
    assert times["right>left"] == pytest.approx([2.0] * 5)
    rule = HeldBackRule(
        5.0, Line(0.0, 0.0), Line(0.0, 0.0), Line(0.0, 0.0), dwell_s={"left>right": 10.25}, dwell_draws=times
    )
    drawn = [rule.draw_dwell("left", np.random.default_rng([3, k])) for k in range(50)]
    assert all(set(d) == {"left>right"} and d["left>right"] in times["left>right"] for d in drawn)
    assert len({d["left>right"] for d in drawn}) > 3  # spread over the drivers' times, not one percentile
    assert drawn[7] == rule.draw_dwell("left", np.random.default_rng([3, 7]))  # seeded
    assert rule.draw_dwell("right", np.random.default_rng(0)) == {"right>left": 2.0}
    # the drawn dwell replaces the percentile for its kind; a kind not drawn keeps `dwell_s`
    assert rule.dwell_ok("left", 12.5, "right", {"left>right": 12.0})
    assert not rule.dwell_ok("left", 11.5, "right", {"left>right": 12.0})
    assert not rule.dwell_ok("left", 10.0, "right", {}) and rule.dwell_ok("left", 10.5, "right", {})


def test_the_agent_waits_the_dwell_drawn_at_its_change():
    def always(scene) -> np.ndarray:
        q = np.zeros((len(scene), 2))
        q[:, CHANGE] = 0.5
        return q

    draws = {"left>right": [2.0, 3.0, 4.0, 5.0, 6.0]}
    rule = HeldBackRule(
        5.0, Line(0.0, 0.0), Line(0.0, 0.0), Line(0.0, 0.0), dwell_s={"left>right": 2.0}, dwell_draws=draws
    )
    firsts = []
    for seed in range(6):
        control, api = (
            AgentControl(
                always, EnvConfig(observation="indicators"), 0.1, 2, rule, DESIRED, True, np.random.default_rng(seed)
            ),
            _Api(),
        )
        control.start(api)
        control.step(api, 0.0, VehicleState(100.0, 20.0, 0, 4.5), 0.0, {})  # in lane 0 ...
        for i in range(1, 81):  # ... then in lane 1 from t = 0.1 s: a change to the left just made
            n = len(api.vehicle.requests)
            control.step(api, round(0.1 * i, 6), VehicleState(100.0 + 2.0 * i, 20.0, 1, 4.5), 0.0, {})
            if len(api.vehicle.requests) > n:
                break
        wait = control.drawn["left>right"]
        assert wait == rule.draw_dwell("left", np.random.default_rng(seed))["left>right"]
        assert wait - 1e-9 <= round(0.1 * i, 6) - 0.1 < wait + 0.5  # back once its drawn dwell has passed
        firsts.append(wait)
    assert len(set(firsts)) > 1  # each drive its own draws


def test_no_change_in_front_of_a_follower_closing_faster_than_the_floor():
    ego = VehicleState(100.0, 20.0, 0, 4.5)
    fast = live_scene(ego, {"nb": VehicleState(70.0, 25.0, 1, 4.5)}, 1)[0]  # 25.5 m behind, 5 m/s faster
    slow = live_scene(ego, {"nb": VehicleState(70.0, 18.0, 1, 4.5)}, 1)[0]
    far = live_scene(ego, {"nb": VehicleState(-100.0, 30.0, 1, 4.5)}, 1)[0]  # beyond far_follower_m
    rule = HeldBackRule(5.0, Line(0.0, 0.0), Line(0.0, 0.0), Line(0.0, 0.0), dv_nb_floor_mps=-2.0)
    assert [bool(above_floors(rule, s, 150.0)[0]) for s in (fast, slow, far)] == [False, True, True]
    assert bool(above_floors(HeldBackRule(5.0, Line(0.0, 0.0), Line(0.0, 0.0), Line(0.0, 0.0)), fast, 150.0)[0])
    for r in (rule, HeldBackRule(5.0, Line(0.0, 0.0), Line(0.0, 0.0), Line(0.0, 0.0), dwell_s={"left>right": 3.0})):
        assert HeldBackRule.from_dict(json.loads(json.dumps(r.to_dict()))) == r  # -inf travels as null


def _side_blind(scene) -> np.ndarray:
    """An agent that does not know the side: it changes behind a closer, slower leader (an overtaking) and
    into a free lane when its own is free too (how returns to the right look)."""
    closing = scene.f_present & (scene.x_f - scene.x_e < 60.0) & (scene.v_f < scene.v_e - 1.0)
    free = ~scene.f_present & ~scene.nf_present
    q = np.zeros((len(scene), 2))
    q[:, CHANGE] = np.where(closing | free, 0.5, -0.5)
    return q


def _requests(
    rule: HeldBackRule, lane: int, others: dict[str, VehicleState], n_lanes: int = 2
) -> tuple[list, AgentControl]:
    control, api = (
        AgentControl(_side_blind, EnvConfig(observation="indicators"), 0.1, n_lanes, rule, DESIRED, True),
        _Api(),
    )
    control.start(api)
    for i in range(5):
        control.step(
            api,
            0.1 * i,
            VehicleState(100.0 + 2.5 * i, 25.0, lane, 4.5),
            0.0,
            {k: VehicleState(s.x + s.v * 0.1 * i, s.v, s.lane, s.length) for k, s in others.items()},
        )
    return [lane for _, lane, _ in api.vehicle.requests], control


def test_the_agents_own_change_needs_its_sides_pace():
    """Behind a slower leader the side-blind agent wants left with an advantage of 0.5: requested when the
    drivers' pace to the left asks less, not when it asks more (the pace to the right does not matter)."""
    rule = HeldBackRule(5.0, Line(0.0, 0.0), Line(0.0, 0.0), Line(0.0, 0.0))
    slow = {"f": VehicleState(140.0, 18.0, 0, 4.5)}
    assert _requests(replace(rule, min_advantage_by_side={"left": 0.4, "right": 9.0}), 0, slow)[0] == [1]
    assert _requests(replace(rule, min_advantage_by_side={"left": 0.6, "right": 0.0}), 0, slow)[0] == []
    assert _requests(replace(rule, min_advantage=0.6), 0, slow)[0] == []  # pooled: one threshold for both
    paced = rule.with_pace({"min_advantage": 0.2, "min_advantage_by_side": {"left": 0.6, "right": 0.0}, "note": "n"})
    assert (paced.needs("left"), paced.needs("right"), paced.source["min_advantage"]) == (0.6, 0.0, "n")
    assert rule.with_pace({"min_advantage": 0.2, "note": "pooled"}).needs("left") == 0.2
    assert HeldBackRule.from_dict(json.loads(json.dumps(paced.to_dict()))) == paced  # policy.json carries it


def test_no_change_to_the_left_that_the_agent_would_at_once_undo():
    """In an empty world a side-blind agent wants both ways: its change to the left is not requested (it
    would want back at once), its return to the right is; behind a slower leader it overtakes (the check
    is made only with no leader within range). `undo_check=False` requests all."""
    rule = HeldBackRule(5.0, Line(0.0, 0.0), Line(0.0, 0.0), Line(0.0, 0.0))
    requests, control = _requests(rule, 0, {})
    assert requests == [] and control.n_undone > 0
    assert _requests(replace(rule, undo_check=False), 0, {})[0] == [1]
    assert _requests(rule, 1, {})[0] == [0]  # the return to the right: not checked
    slow = {"f": VehicleState(140.0, 18.0, 0, 4.5)}  # 40 m ahead, 7 m/s slower
    requests, control = _requests(rule, 0, slow)
    assert requests == [1] and control.n_undone == 0
    middle, _ = _requests(rule, 1, {}, n_lanes=3)  # the middle lane of an empty road: right, never left
    assert middle == [0]

    # an agent that wants every change would undo every one; behind a leader it is not asked, so it goes
    def always(scene) -> np.ndarray:
        q = np.zeros((len(scene), 2))
        q[:, CHANGE] = 0.5
        return q

    for others, requested in (({}, []), ({"f": VehicleState(200.0, 25.0, 0, 4.5)}, [1])):
        control, api = AgentControl(always, EnvConfig(observation="indicators"), 0.1, 2, rule, DESIRED, True), _Api()
        for i in range(5):
            control.step(
                api,
                0.1 * i,
                VehicleState(100.0 + 2.5 * i, 25.0, 0, 4.5),
                0.0,
                {k: VehicleState(s.x + 2.5 * i, s.v, s.lane, s.length) for k, s in others.items()},
            )
        assert [lane for _, lane, _ in api.vehicle.requests] == requested
        assert (control.n_undone > 0) == (not others)


def test_follower_headways_are_read_per_side_from_presses_with_a_near_follower():
    def presses(side: str, n: int, thw: float, gap: float = 30.0) -> list[dict]:
        return [{"label": "change", "lc_direction": side, "nb_gap_m": gap, "thw_nb_s": thw + 0.1 * i} for i in range(n)]

    rows = presses("right", 12, 1.0) + presses("left", 3, 4.0) + presses("left", 5, 9.0, gap=150.0)
    rows += [{"label": "keep", "lc_direction": "left", "nb_gap_m": 10.0, "thw_nb_s": 0.2}]
    lag = lag_headways(pd.DataFrame(rows))
    assert lag["right"] == pytest.approx([1.0 + 0.1 * i for i in range(12)])
    # three near presses to the left are too few: that side draws from both sides'; far followers never count
    assert lag["left"] == pytest.approx(sorted(lag["right"] + [4.0, 4.1, 4.2]))
    assert lag_headways(pd.DataFrame(presses("right", MIN_LAG_PRESSES - 1, 1.0))) == {}


def test_the_agent_does_not_cut_in_front_of_a_follower_closer_than_the_headway_drawn():
    def always(scene) -> np.ndarray:
        q = np.zeros((len(scene), 2))
        q[:, CHANGE] = 0.5
        return q

    rule = HeldBackRule(
        5.0, Line(0.0, 0.0), Line(0.0, 0.0), Line(0.0, 0.0), undo_check=False, lag_draws={"left": [2.0]}
    )
    ego = VehicleState(100.0, 20.0, 0, 4.5)
    # a follower in the left lane at the ego's speed: 15.5 m (0.78 s) behind, then 55.5 m (2.78 s)
    for follower, requested in ((VehicleState(80.0, 20.0, 1, 4.5), 0), (VehicleState(40.0, 20.0, 1, 4.5), 1)):
        for use_lag in (True, False):
            control = AgentControl(
                always, EnvConfig(), 0.1, 2, rule if use_lag else replace(rule, lag_draws={}), DESIRED, True
            )
            api = _Api()
            for i in range(5):
                control.step(api, 0.1 * i, ego, 0.0, {"nb": follower})
            assert control.lag_drawn == ({"left": 2.0} if use_lag else {})
            assert len(api.vehicle.requests) == (requested if use_lag else 1)  # only the floors without draws
            assert control.n_lagged == (1 - requested if use_lag else 0)
