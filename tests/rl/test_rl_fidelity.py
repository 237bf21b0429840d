"""The drive beside its drivers (`rl.drive.fidelity`): rates, sides and indicator distributions."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rl.drive.fidelity import (
    compare_values,
    lane_change_pairs,
    lane_changes,
    lane_use,
    poisson_interval,
    press_values,
    rate_comparison,
)


def _ego(lanes: list[int], km: float = 2.0) -> pd.DataFrame:
    n = len(lanes)
    return pd.DataFrame({"t_s": np.arange(n) * 1.0, "ego_lane": lanes, "ego_x_m": np.linspace(0.0, km * 1000.0, n)})


def test_lane_changes_count_flips_by_side_over_the_distance():
    ego = _ego([0, 0, 1, 1, 2, 1, 0, 0, 1], km=3.0)
    assert lane_change_pairs(ego) == {"0>1": 2, "1>2": 1, "2>1": 1, "1>0": 1}
    assert lane_changes(ego) == {"changes": 5, "left": 3, "right": 2, "km": pytest.approx(3.0)}


def test_lane_use_gives_the_time_in_each_lane_and_the_pairs_per_km():
    # 1 s per sample: lane 0 for 2 s, lane 1 for 5 s, lane 2 for 1 s (the last sample holds no time)
    one = _ego([0, 0, 1, 1, 2, 1, 1, 1, 1], km=2.0)
    two = _ego([1, 1, 1, 1, 1], km=2.0)  # 4 s in lane 1, no change
    use = lane_use([one, two])
    assert use["time_share"] == {"0": pytest.approx(2 / 12), "1": pytest.approx(9 / 12), "2": pytest.approx(1 / 12)}
    assert use["pairs_per_km"] == {"0>1": pytest.approx(0.25), "1>2": pytest.approx(0.25), "2>1": pytest.approx(0.25)}
    assert lane_use([]) == {"time_share": {}, "pairs_per_km": {}}


def test_the_rate_is_within_tolerance_only_near_the_drivers():
    drivers = pd.DataFrame(
        {"driver_id": ["a", "b"], "changes": [30, 50], "left": [15, 25], "right": [15, 25], "km": [10.0, 10.0]}
    )  # 4 per km pooled
    near = rate_comparison({"changes": 45, "left": 30, "right": 15, "km": 10.0}, drivers)
    assert near["ratio"] == pytest.approx(1.125) and near["within_tolerance"]
    assert near["agent"]["left_share"] == pytest.approx(2 / 3) and near["drivers"]["left_share"] == 0.5
    assert near["drivers"]["per_km_range"] == [3.0, 5.0]
    lo, hi = near["agent"]["per_km_ci"]
    assert lo < 4.5 < hi
    far = rate_comparison({"changes": 60, "left": 30, "right": 30, "km": 10.0}, drivers)
    assert far["ratio"] == pytest.approx(1.5) and not far["within_tolerance"]


def test_poisson_interval_covers_the_rate_and_narrows_with_exposure():
    lo, hi = poisson_interval(10, 5.0)
    assert lo < 2.0 < hi
    lo2, hi2 = poisson_interval(100, 50.0)
    assert hi2 - lo2 < hi - lo
    assert poisson_interval(0, 5.0)[0] == 0.0 and poisson_interval(3, 0.0) == (None, None)


def test_a_median_outside_the_drivers_iqr_is_said():
    rng = np.random.default_rng(0)
    drivers = rng.normal(10.0, 2.0, 200)
    same = compare_values(rng.normal(10.0, 2.0, 50), drivers, rng)
    shifted = compare_values(rng.normal(16.0, 2.0, 50), drivers, rng)
    assert same["median_in_iqr"] and not shifted["median_in_iqr"]
    assert shifted["wasserstein"] > same["wasserstein"] and shifted["ks"] > same["ks"]
    lo, hi = same["agent"]["median_ci"]
    assert lo <= same["agent"]["median"] <= hi
    assert compare_values(np.zeros(0), drivers, rng)["median_in_iqr"] is None


def test_press_values_keep_defined_values_at_presses_only():
    d = pd.DataFrame(
        {
            "label": ["keep", "change", "change"],
            "t_f_s": [1.0, 2.0, np.nan],
            "t_f_status": ["ok", "ok", "not_closing"],
            "f_gap_m": [5.0, 6.0, 7.0],
            "ego_v_mps": [20.0, 20.0, 20.0],
            "f_v_mps": [19.0, 19.0, 21.0],
        }
    )
    got = press_values(d)
    assert list(got["t_f"]) == [2.0] and list(got["gap_f"]) == [6.0, 7.0] and list(got["thw_f"]) == [0.3, 0.35]
    assert len(got["gap_nb"]) == 0


def test_the_drive_figure_draws_the_rate_and_every_indicator_and_marks_a_miss():
    from rl.plots import drive_fidelity

    rng = np.random.default_rng(1)
    drivers = pd.DataFrame({"driver_id": ["a"], "changes": [30], "left": [15], "right": [15], "km": [10.0]})
    fid = {
        "tolerance": 0.2,
        "medians_in_iqr": "1 of 2",
        "rate": rate_comparison({"changes": 33, "left": 16, "right": 17, "km": 10.0}, drivers),
        "indicators": {
            "t_f": compare_values(rng.normal(8, 1, 40), rng.normal(8, 1, 90), rng),
            "gap_f": compare_values(rng.normal(90, 5, 40), rng.normal(50, 5, 90), rng),
        },
    }
    fig = drive_fidelity(fid)
    titles = [a.text for a in fig.layout.annotations]
    assert titles[:3] == ["lane changes per km [1/km]", "t_f [s]", "gap_f [m] (outside the drivers' IQR)"]
    assert len(fig.data) == 6  # agent and drivers in each of the three panels
    rate = [t for t in fig.data if t.xaxis in (None, "x")]
    assert [t.y[0] for t in rate] == [pytest.approx(3.3), pytest.approx(3.0)]


def test_the_drive_figure_shows_where_each_side_drove_by_lane():
    from rl.plots import drive_fidelity

    drivers = pd.DataFrame({"driver_id": ["a"], "changes": [30], "left": [15], "right": [15], "km": [10.0]})
    fid = {
        "tolerance": 0.2,
        "medians_in_iqr": "0 of 0",
        "indicators": {},
        "rate": rate_comparison({"changes": 33, "left": 16, "right": 17, "km": 10.0}, drivers),
        "lanes": {"agent": lane_use([_ego([0, 1, 2, 2, 2, 1])]), "drivers": lane_use([_ego([0, 0, 0, 1, 1, 0])])},
    }
    fig = drive_fidelity(fid)
    assert [a.text for a in fig.layout.annotations][1:] == [
        "time in each lane [share]",
        "lane changes per km by lane pair",
    ]
    shares = {t.name: dict(zip(t.x, t.y)) for t in fig.data if t.type == "bar" and "0>1" not in t.x}
    assert shares["agent"] == {"0": pytest.approx(0.2), "1": pytest.approx(0.2), "2": pytest.approx(0.6)}
    assert shares["drivers"] == {"0": pytest.approx(0.6), "1": pytest.approx(0.4), "2": 0.0}
    del fid["lanes"]  # a drive reported before the comparison by lane: the figure without those panels
    assert len(drive_fidelity(fid).layout.annotations) == 1
