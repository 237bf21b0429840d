"""At every press the frames show what the ground truth says, computed independently."""

from __future__ import annotations

import numpy as np
import pytest

from laneprint.reference import FAR_FOLLOWER_M, kph_to_mps
from laneprint.schemas import EGO, TRAFFIC, validate


def _by_session(study):
    return {m["session_id"]: (m, e, t) for m, e, t in study.recordings}


def test_small_study_has_every_case(small_study):
    cases = {d["case"] for d in small_study.decisions}
    assert cases == {"clean", "slowed", "no_target_leader", "far_follower", "cancelled"}
    # exact shares per driver: 13 decisions -> 1 slowed, 2 no leader, 1 far, 1 cancelled, 8 clean
    for did in ("D01", "D02", "D03"):
        mine = [d["case"] for d in small_study.decisions if d["driver_id"] == did]
        assert len(mine) == 13
        assert mine.count("clean") == 8 and mine.count("no_target_leader") == 2


def test_presses_in_frames_are_the_ground_truth_presses(small_study, presses):
    recs = _by_session(small_study)
    for sid, (meta, ego, _traffic) in recs.items():
        truth = [d["press_t_s"] for d in small_study.decisions if d["session_id"] == sid]
        assert presses(ego) == pytest.approx(truth, abs=1e-9)
        assert meta["session_id"] == sid and meta["driver_id"] == sid.split("_")[0]
        assert meta["speed_limit_kph"] == float(sid.split("_S")[1])


def test_indicators_at_press_equal_intended_values(small_study, indicators_at):
    recs = _by_session(small_study)
    checked = 0
    for d in small_study.decisions:
        _, ego, traffic = recs[d["session_id"]]
        got = indicators_at(ego, traffic, d["press_t_s"], d["target_lane"])
        assert got["v_e"] == pytest.approx(d["v_e_mps"], abs=1e-9)
        assert got["ego_lane"] == d["from_lane"]
        if d["case"] == "slowed":
            continue
        assert got["t_f"] == pytest.approx(d["t_f_s"], rel=1e-9)
        if d["t_nf_s"] is not None:
            assert got["t_nf"] == pytest.approx(d["t_nf_s"], rel=1e-9)
        assert got["dv_nb"] == pytest.approx(d["dv_nb_mps"], rel=1e-9)
        if d["case"] == "clean":
            # the clean values are the driver's line plus noise: near the line
            for k, tol in (("t_f", 2.0), ("t_nf", 2.0), ("dv_nb", 5.0)):
                key = {"t_f": "t_f_s", "t_nf": "t_nf_s", "dv_nb": "dv_nb_mps"}[k]
                assert abs(d[key] - d["line"][k]) < tol
            checked += 1
    assert checked >= 20


def test_untidy_cases_have_their_property(small_study, indicators_at):
    recs = _by_session(small_study)
    for d in small_study.decisions:
        _, ego, traffic = recs[d["session_id"]]
        got = indicators_at(ego, traffic, d["press_t_s"], d["target_lane"])
        t = ego["t_s"].to_numpy()
        after = (t > d["press_t_s"]) & (t <= d["press_t_s"] + 5.0)
        lanes_after = set(ego.loc[after, "ego_lane"].tolist())
        if d["case"] == "no_target_leader":
            assert got["nf"] is None and got["t_nf"] is None and d["t_nf_status"] == "absent"
        if d["case"] == "far_follower":
            assert got["nb_gap"] > FAR_FOLLOWER_M and d["dv_nb_status"] == "far"
        else:
            assert got["nb_gap"] < FAR_FOLLOWER_M
        if d["case"] == "cancelled":
            assert lanes_after == {d["from_lane"]}
            row = ego.loc[np.isclose(t, d["press_t_s"])].iloc[0]
            assert row["lc_direction"] == d["direction"]
        else:
            assert d["target_lane"] in lanes_after
        if d["case"] == "slowed":
            # the ego slowed to the front car's speed: not closing, or closing very slowly
            assert got["v_e"] < kph_to_mps(d["speed_limit_kph"] - 5)
            assert got["v_e"] - got["f"]["v_mps"] == pytest.approx(0.0, abs=0.31)
            assert got["t_f"] is None or got["t_f"] > 20
            assert (got["t_f"] is None) == (d["t_f_status"] == "not_closing")


def test_direction_matches_the_lane_change(small_study):
    for d in small_study.decisions:
        assert d["direction"] == ("left" if d["target_lane"] > d["from_lane"] else "right")


def test_frames_match_the_schemas_and_physics(small_study):
    for _meta, ego, traffic in small_study.recordings:
        validate(ego, EGO)
        validate(traffic, TRAFFIC)
        assert np.all(np.diff(ego["t_s"]) > 0)
        assert np.diff(ego["t_s"]).max() == pytest.approx(0.02)
        # each vehicle: constant lane and speed, x moving at that speed
        for _vid, g in traffic.groupby("vehicle_id"):
            assert g["lane"].nunique() == 1 and g["v_mps"].nunique() == 1
            slope = np.diff(g["x_m"]) / np.diff(g["t_s"])
            assert slope == pytest.approx(np.full(len(slope), g["v_mps"].iloc[0]), rel=1e-6)
        # nobody overlaps in a lane, the ego included, and nobody is outside the scene
        merged = traffic.merge(ego[["t_s", "ego_x_m", "ego_lane", "ego_length_m"]], on="t_s")
        assert (merged["x_m"] - merged["ego_x_m"]).abs().max() <= 150.0 + 1e-9
        same = merged[merged["lane"] == merged["ego_lane"]]
        gap = (same["x_m"] - same["ego_x_m"]).abs() - (same["length_m"] + same["ego_length_m"]) / 2
        assert gap.min() > 0
        tr = traffic.sort_values(["t_s", "lane", "x_m"], ignore_index=True)
        same_group = (tr["t_s"].diff() == 0) & (tr["lane"].diff() == 0)
        spacing = tr["x_m"].diff() - (tr["length_m"] + tr["length_m"].shift()) / 2
        assert same_group.sum() > 0
        assert spacing[same_group].min() > 0


def test_ego_speed_stays_in_the_band_outside_slowed_episodes(small_study):
    for meta, ego, _ in small_study.recordings:
        limit = meta["speed_limit_kph"]
        t = ego["t_s"].to_numpy()
        keep = np.ones(len(t), dtype=bool)
        for d in small_study.decisions:
            if d["session_id"] == meta["session_id"] and d["case"] == "slowed":
                keep &= ~((t >= d["episode_start_t_s"]) & (t <= d["episode_end_t_s"]))
        v = ego["ego_v_mps"].to_numpy()[keep]
        assert v.min() >= kph_to_mps(limit - 5) - 1e-9
        assert v.max() <= kph_to_mps(limit + 5) + 1e-9


def test_not_yet_seconds_before_a_clean_press(small_study, indicators_at):
    """Before the press the front car's TTC is larger than at the press and shrinking."""
    recs = _by_session(small_study)
    for d in small_study.decisions:
        if d["case"] != "clean":
            continue
        _, ego, traffic = recs[d["session_id"]]
        before = [indicators_at(ego, traffic, d["press_t_s"] - s, d["target_lane"]) for s in (4.0, 2.0)]
        ttcs = [b["t_f"] for b in before if b["t_f"] is not None and b["f"]["vehicle_id"] == d["vehicles"]["f"]]
        assert d["press_t_s"] - d["episode_start_t_s"] >= 6.0 - 1e-9
        assert all(x > d["t_f_s"] for x in ttcs)
        assert ttcs == sorted(ttcs, reverse=True)
