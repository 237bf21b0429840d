"""Decision points and indicators on tiny constant-speed scenes with hand-computed values."""

import numpy as np
import pandas as pd
import pytest

from indicators.decisions import COLUMNS, extract_decisions
from indicators.settings import AnalysisSettings
from tests.support.synthetic_decisions import make_recording
from laneprint.schemas import DECISIONS, validate

# ego at 20 m/s from x = 0, length 4.5; lane 0 until the flip at t = 7.0, then lane 1.
# A: lane 0 leader, 15 m/s. B: lane 1 leader, 18 m/s, 5 m long. C: lane 1 follower, 25 m/s.
# D: lane 1, far behind. E: lane 1, far ahead and faster (never the nearest leader).
VEHICLES = [
    ("A", 60, 15, 0, 4.5),
    ("B", 150, 18, 1, 5.0),
    ("C", -40, 25, 1, 4.5),
    ("D", -200, 20, 1, 4.5),
    ("E", 300, 30, 1, 4.5),
]


def scene(**kw):
    args = dict(
        duration_s=10,
        hz=10,
        ego_v=20.0,
        lanes=[(0, 0), (7.0, 1)],
        presses=[(5.0, 0.5, None), (9.0, 0.3, "right")],
        vehicles=VEHICLES,
    )
    args.update(kw)
    return make_recording(**args)


def test_press_indicators_match_hand_computation():
    meta, ego, traffic = scene()
    dec, skipped = extract_decisions(meta, ego, traffic)
    assert skipped == []
    validate(dec, DECISIONS)
    assert list(dec.columns) == COLUMNS
    press = dec[(dec["label"] == "change") & (dec["press_index"] == 0)].iloc[0]
    assert press["t_s"] == pytest.approx(5.0)
    assert press["target_lane"] == 1 and not press["cancelled"]
    assert press["lane_change_t_s"] == pytest.approx(7.0)
    # ego x = 100; A x = 135: gap = 35 - (4.5 + 4.5) / 2 = 30.5, closing 5 m/s
    assert press["f_id"] == "A"
    assert press["f_gap_m"] == pytest.approx(30.5)
    assert press["t_f_s"] == pytest.approx(6.1)
    # B x = 240: gap = 140 - (4.5 + 5) / 2 = 135.25, closing 2 m/s
    assert press["nf_id"] == "B"
    assert press["t_nf_s"] == pytest.approx(67.625)
    # C x = 85: gap = 15 - 4.5 = 10.5; dv_nb = 20 - 25
    assert press["nb_id"] == "C"
    assert press["nb_gap_m"] == pytest.approx(10.5)
    assert press["dv_nb_mps"] == pytest.approx(-5.0)
    assert (press["t_f_status"], press["t_nf_status"], press["dv_nb_status"]) == ("ok", "ok", "ok")


def test_keep_states_every_step_back_to_the_start():
    meta, ego, traffic = scene()
    dec, _ = extract_decisions(meta, ego, traffic)
    first = dec[dec["press_index"] == 0]
    assert list(first["t_s"]) == pytest.approx([0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0])
    assert list(first["label"]) == ["keep"] * 10 + ["change"]
    assert (first["decision_id"] == "rec0:0").all()
    # at t = 0: ego x 0, A x 60 -> gap 55.5, TTC 11.1; C x -40 -> gap 35.5
    t0 = first.iloc[0]
    assert t0["t_f_s"] == pytest.approx(11.1)
    assert t0["nb_gap_m"] == pytest.approx(35.5)


def test_cancelled_press_uses_direction_and_approach_starts_after_lane_change():
    meta, ego, traffic = scene()
    # C passes the ego at 8.0 s and leads from then on: the time window alone is tested here
    dec, _ = extract_decisions(meta, ego, traffic, AnalysisSettings(same_leader_approach=False))
    second = dec[dec["press_index"] == 1]
    # previous lane change crossed at 7.0, settle 1.0 s -> keep states at 8.0 and 8.5
    assert list(second["t_s"]) == pytest.approx([8.0, 8.5, 9.0])
    press = second.iloc[-1]
    assert press["cancelled"] and press["target_lane"] == 0 and press["ego_lane"] == 1
    # ahead in lane 1 at t = 9: C at 185 (ego 180): gap 0.5, faster -> not closing
    assert press["f_id"] == "C" and press["t_f_status"] == "not_closing" and np.isnan(press["t_f_s"])
    assert press["t_f_reason"] == "not_closing"
    # lane 0 ahead: A at 195: gap 10.5, closing 5 -> 2.1; nobody behind in lane 0
    assert press["t_nf_s"] == pytest.approx(2.1)
    assert press["dv_nb_status"] == "absent" and not press["nb_present"] and np.isnan(press["dv_nb_mps"])
    assert press["dv_nb_reason"] == "absent"


def test_no_target_leader_and_far_follower():
    vehicles = [("A", 60, 15, 0, 4.5), ("D", -200, 20, 1, 4.5)]
    meta, ego, traffic = scene(vehicles=vehicles, presses=[(5.0, 0.5, None)])
    dec, _ = extract_decisions(meta, ego, traffic, AnalysisSettings(far_follower_m=100.0))
    press = dec[dec["label"] == "change"].iloc[0]
    assert not press["nf_present"] and press["t_nf_status"] == "absent" and np.isnan(press["t_nf_s"])
    # D at -100 when the ego is at 100: gap 195.5 > 100 -> far, value kept
    assert press["dv_nb_status"] == "far"
    assert press["nb_gap_m"] == pytest.approx(195.5)
    assert press["dv_nb_mps"] == pytest.approx(0.0)
    assert press["dv_nb_reason"] == "far"
    near, _ = extract_decisions(meta, ego, traffic, AnalysisSettings(far_follower_m=200.0))
    assert near[near["label"] == "change"].iloc[0]["dv_nb_status"] == "ok"


def test_recording_without_presses_is_skipped_with_reason():
    meta, ego, traffic = scene(presses=[])
    dec, skipped = extract_decisions(meta, ego, traffic)
    assert len(dec) == 0 and list(dec.columns) == COLUMNS
    assert skipped == [{"what": "recording", "id": "rec0", "reason": "no lane-change button presses"}]


def test_press_without_lane_change_or_direction_is_skipped():
    meta, ego, traffic = scene(lanes=[(0, 0)], presses=[(5.0, 0.5, None)])
    dec, skipped = extract_decisions(meta, ego, traffic)
    assert len(dec) == 0
    assert len(skipped) == 1 and skipped[0]["id"] == "rec0:0"
    assert "target lane unknown" in skipped[0]["reason"]


def test_traffic_on_its_own_slower_clock_is_carried_forward():
    meta, ego, traffic = scene(hz=100)
    # keep only every 10th traffic sample, shifted by 0.05 s (10 Hz, another clock)
    slow = traffic[np.isclose((traffic["t_s"] * 100).round() % 10, 5)].reset_index(drop=True)
    dec, _ = extract_decisions(meta, ego, slow)
    press = dec[(dec["label"] == "change") & (dec["press_index"] == 0)].iloc[0]
    assert press["t_f_s"] == pytest.approx(6.1)
    assert press["t_nf_s"] == pytest.approx(67.625)


def test_following_a_slow_leader_is_kept_but_flagged():
    # leader 0.2 m/s slower, 20 m ahead: TTC = 15.5 / 0.2 = 77.5 s, reason 'following'
    vehicles = [("A", 20 + 4.5, 19.8, 0, 4.5)]
    meta, ego, traffic = scene(vehicles=vehicles, presses=[(5.0, 0.5, None)])
    dec, _ = extract_decisions(meta, ego, traffic)
    press = dec[dec["label"] == "change"].iloc[0]
    assert press["t_f_status"] == "ok"
    assert press["t_f_s"] == pytest.approx((20 + 4.5 - 0.2 * 5 - 4.5) / 0.2)
    assert press["t_f_reason"] == "following"


def test_decisions_table_has_no_sentinels():
    meta, ego, traffic = scene()
    dec, _ = extract_decisions(meta, ego, traffic)
    for col in ("t_f_s", "t_nf_s", "dv_nb_mps"):
        assert not (dec[col] == -1).any()
    assert isinstance(dec, pd.DataFrame)


def test_approach_starts_when_the_lateral_move_has_settled():
    meta, ego, traffic = scene()
    t = ego["t_s"].to_numpy()
    ego["ego_y_m"] = np.clip((t - 6.0) / 2.0, 0.0, 1.0) * 3.5  # lateral move 6.0 -> 8.0 s, flip at 7.0
    dec, _ = extract_decisions(meta, ego, traffic)
    # lateral speed first below 0.1 m/s at t = 8.1 (central differences): keep states from there
    assert list(dec[dec["press_index"] == 1]["t_s"]) == pytest.approx([8.5, 9.0])


def test_keep_states_cover_only_the_approach_to_the_press_leader():
    # OLD leads in lane 0 until it leaves the scene (last sample 2.9 s, counted 0.5 s more);
    # from then on A is the leader the driver faces at the press at 5 s.
    meta, ego, traffic = scene(vehicles=VEHICLES + [("OLD", 30, 15, 0, 4.5)], presses=[(5.0, 0.5, None)])
    traffic = traffic[~((traffic["vehicle_id"] == "OLD") & (traffic["t_s"] >= 3.0 - 1e-9))]
    dec, _ = extract_decisions(meta, ego, traffic)
    keep = dec[dec["label"] == "keep"]
    assert keep["t_s"].tolist() == pytest.approx([3.5, 4.0, 4.5])
    assert set(keep["f_id"]) == {"A"}
    dec_all, _ = extract_decisions(meta, ego, traffic, AnalysisSettings(same_leader_approach=False))
    assert (dec_all["label"] == "keep").sum() == 10  # 0.0 .. 4.5 s, OLD leading the first ones


def test_other_side_of_a_middle_lane():
    # three lanes: the ego in lane 1 presses left (to lane 2) at t = 5; lane 0 is the side not taken.
    # G: lane 0 leader, 18 m/s, 5 m long; H: lane 0 follower, 22 m/s; I: lane 2 leader (the target's).
    vehicles = [("A", 60, 15, 1, 4.5), ("G", 100, 18, 0, 5.0), ("H", -30, 22, 0, 4.5), ("I", 200, 25, 2, 4.5)]
    meta, ego, traffic = make_recording(
        duration_s=10, hz=10, ego_v=20.0, lanes=[(0, 1), (7.0, 2)], presses=[(5.0, 0.5, "left")], vehicles=vehicles
    )
    dec, _ = extract_decisions(meta, ego, traffic)
    assert list(dec.columns) == COLUMNS
    assert (dec["other_lane"] == 0).all()
    press = dec[dec["label"] == "change"].iloc[0]
    assert press["target_lane"] == 2 and press["nf_id"] == "I"
    # ego x = 100; G x = 190: gap = 90 - (4.5 + 5) / 2 = 85.25; H x = 80: gap = 20 - 4.5 = 15.5
    assert press["other_nf_id"] == "G" and press["other_nf_present"]
    assert press["other_nf_x_m"] == pytest.approx(190.0) and press["other_nf_v_mps"] == pytest.approx(18.0)
    assert press["other_nf_gap_m"] == pytest.approx(85.25)
    assert press["other_nb_id"] == "H" and press["other_nb_gap_m"] == pytest.approx(15.5)
    assert press["other_nb_v_mps"] == pytest.approx(22.0)


def test_no_other_side_outside_a_middle_lane():
    meta, ego, traffic = scene()  # two lanes: lane 0 -> 1, then a cancelled press right from lane 1
    dec, _ = extract_decisions(meta, ego, traffic)
    assert (dec["other_lane"] == -1).all()
    assert not dec["other_nf_present"].any() and not dec["other_nb_present"].any()
    assert dec["other_nf_x_m"].isna().all() and dec["other_nb_id"].isna().all()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_latest_samples_are_merge_asofs(seed):
    """Each vehicle's latest sample at or before each state (within the tolerance), as pandas'
    merge_asof finds it: own clocks, gaps, duplicate times and states out of time order."""
    from indicators.decisions import latest_samples

    rng = np.random.default_rng(seed)
    n_veh, n_rows = 5, 200
    t = np.round(np.sort(rng.uniform(0, 20, n_rows)), 1)  # rounded: equal times within and across vehicles
    tr = pd.DataFrame(
        {
            "t_s": t,
            "vehicle_id": rng.integers(0, n_veh, n_rows).astype(np.int64),
            "x_m": rng.normal(0, 50, n_rows),
            "v_mps": rng.uniform(10, 30, n_rows),
            "lane": rng.integers(0, 3, n_rows).astype(np.int64),
            "length_m": rng.uniform(4, 15, n_rows),
        }
    )
    t_states = rng.permutation(np.round(np.arange(0, 21, 0.5) + rng.normal(0, 1e-9, 42), 9))
    states = np.arange(len(t_states))
    got = latest_samples(states, t_states, tr, n_veh, 0.5)
    left = pd.DataFrame(
        {
            "state": np.repeat(states, n_veh),
            "t_s": np.repeat(t_states, n_veh),
            "vehicle_id": np.tile(np.arange(n_veh, dtype=np.int64), len(states)),
        }
    ).sort_values("t_s", kind="mergesort")
    want = pd.merge_asof(
        left,
        tr.rename(columns={"t_s": "veh_t_s"}),
        left_on="t_s",
        right_on="veh_t_s",
        by="vehicle_id",
        direction="backward",
        tolerance=0.5,
    ).dropna(subset=["veh_t_s"])
    assert len(got) > 0
    pd.testing.assert_frame_equal(
        got.reset_index(drop=True), want[got.columns].reset_index(drop=True), check_dtype=False
    )
