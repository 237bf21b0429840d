"""The headway a driver keeps in steady car following, read over the whole drive."""

import numpy as np
import pandas as pd
import pytest
from sklearn.metrics import adjusted_rand_score

from clustering.features import driver_features
from clustering.pipeline import analyze_tables
from indicators.following import COLUMNS, FOLLOWING, following_episodes
from indicators.stats import following_points
from indicators.settings import AnalysisSettings
from tests.support.synthetic_decisions import make_recording
from laneprint.schemas import validate


def during(traffic: pd.DataFrame, vid: str, t0: float, t1: float) -> pd.DataFrame:
    """`traffic` with vehicle `vid` present only for t0 <= t < t1."""
    t = traffic["t_s"].to_numpy()
    return traffic[(traffic["vehicle_id"] != vid) | ((t >= t0 - 1e-9) & (t < t1 - 1e-9))]


def scene():
    # ego at 25 m/s in lane 0, 4.5 m long. A: 50 m ahead bumper to bumper at 25 m/s (2.0 s) for
    # 20 s; B cuts in 10 m ahead at 25 m/s for 1 s; C, slower (20 m/s), ahead for the rest.
    # D drives beside the ego in lane 1 (never a leader). From t = 30 s the ego drives at its free
    # speed, 30 m/s: at 25 m/s it is held back.
    meta, ego, traffic = make_recording(
        duration_s=40,
        hz=10,
        ego_v=25.0,
        lanes=[(0, 0)],
        vehicles=[
            ("A", 54.5, 25.0, 0, 4.5),
            ("B", 14.5, 25.0, 0, 4.5),
            ("C", 230.0, 20.0, 0, 4.5),
            ("D", 5.0, 25.0, 1, 4.5),
        ],
    )
    traffic = during(during(during(traffic, "A", 0, 20), "B", 20, 21), "C", 21, 41)
    ego.loc[ego["t_s"] >= 30, "ego_v_mps"] = 30.0
    return meta, ego, traffic


def test_one_episode_per_leader_held_steady_long_enough():
    meta, ego, traffic = scene()
    ep = following_episodes(meta, ego, traffic)
    validate(ep, FOLLOWING)
    assert list(ep.columns) == COLUMNS
    # A is followed for 20 s; B's 1 s is a cut-in (shorter than follow_min_s); C is being closed in on
    assert list(ep["f_id"]) == ["A"]
    row = ep.iloc[0]
    assert row["thw_s"] == pytest.approx(2.0)
    assert row["f_gap_m"] == pytest.approx(50.0)
    assert row["duration_s"] == pytest.approx(20.0)
    assert row["episode_id"] == "rec0:f0" and row["driver_id"] == "D01"


def test_the_thresholds_decide_what_counts_as_following():
    meta, ego, traffic = scene()
    # a shorter minimum keeps the cut-in; a wider speed band takes the slower leader too
    short = following_episodes(meta, ego, traffic, AnalysisSettings(follow_min_s=1.0))
    assert list(short["f_id"]) == ["A", "B"]
    wide = following_episodes(meta, ego, traffic, AnalysisSettings(follow_dv_mps=6.0))
    assert list(wide["f_id"]) == ["A", "C"]
    # an ego slower than the minimum speed follows nobody
    assert following_episodes(meta, ego, traffic, AnalysisSettings(follow_min_speed_mps=30.0)).empty


def test_a_car_ahead_at_the_egos_own_free_speed_is_not_followed():
    meta, ego, traffic = scene()
    ego["ego_v_mps"] = 25.0  # never held back: 25 m/s is its free speed, A just drives as fast
    assert following_episodes(meta, ego, traffic).empty


def test_no_traffic_gives_an_empty_table_with_the_columns():
    meta, ego, _ = scene()
    ep = following_episodes(meta, ego, pd.DataFrame(columns=["t_s", "vehicle_id", "x_m", "v_mps", "lane", "length_m"]))
    assert ep.empty and list(ep.columns) == COLUMNS


def test_the_level_is_the_low_quantile_so_far_leaders_do_not_pull_it():
    eps = pd.DataFrame(
        {
            "driver_id": "D1",
            "episode_id": [f"e{i}" for i in range(5)],
            "ego_v_mps": 25.0,
            "thw_s": [1.0, 2.0, 3.0, 4.0, 100.0],
        }
    )
    feats, notes = driver_features(following_points(eps), ["D1"], AnalysisSettings(feature_indicators=("thw_follow",)))
    assert feats.to_numpy().ravel() == pytest.approx(2.0)  # the 25th percentile on the log scale
    assert notes == {"D1": []}


def episodes_by_style(truth: dict[str, str], seed: int = 0) -> pd.DataFrame:
    """Twelve steady-following episodes per driver around its style's headway."""
    keep_s = {"Defensive": 3.0, "Normal": 1.8, "Aggressive": 1.0}
    rng = np.random.default_rng(seed)
    rows = [
        {
            "driver_id": d,
            "episode_id": f"{d}:f{i}",
            "ego_v_mps": rng.uniform(17, 25),
            "thw_s": keep_s[s] * np.exp(rng.normal(0, 0.1)),
        }
        for d, s in truth.items()
        for i in range(12)
    ]
    return pd.DataFrame(rows)


@pytest.mark.slow
def test_auto_reads_a_driver_by_the_headway_it_keeps_when_its_presses_mislead():
    from tests.clustering.test_clustering_selection import FRONT_GAP_M, acceptance_table

    dec, truth = acceptance_table()
    # D01 (Normal) pulls out nearer the Defensive drivers' gaps than the Normal ones', yet follows at
    # a Normal headway (as the perturbed Normal driver of SUMO study 246)
    d01 = dec["driver_id"] == "D01"
    dec.loc[d01, "f_gap_m"] *= (FRONT_GAP_M["Defensive"] / FRONT_GAP_M["Normal"]) ** 0.6
    # and every style accepts the same lag gaps: only the front gap and headway tell them apart
    dec["nb_gap_m"] = 30.0 * np.exp(np.random.default_rng(2).normal(0, 0.2, len(dec)))
    assert truth["D01"] == "Normal"
    headway = analyze_tables(dec, AnalysisSettings(features="headway", n_bootstrap=0))
    assert adjusted_rand_score([truth[d] for d in headway["styles"]["driver_id"]], headway["styles"]["style"]) < 1
    out = analyze_tables(dec, AnalysisSettings(features="auto", n_bootstrap=30), following=episodes_by_style(truth))
    fs = out["feature_sets"].set_index("name")
    assert fs.index[fs["chosen"]][0] == "following"
    st = out["styles"]
    assert adjusted_rand_score([truth[d] for d in st["driver_id"]], st["style"]) == 1.0
    # without the drives' episodes thw_follow is undefined for everyone: the set reads as 'headway'
    bare = analyze_tables(dec, AnalysisSettings(features="following", n_bootstrap=0))
    assert list(bare["styles"]["style"]) == list(headway["styles"]["style"])
