"""Robust per-driver lines behind the clustering features."""

import numpy as np
import pandas as pd
import pytest
import statsmodels.api as sm
from scipy import stats

from clustering.features import driver_features, lines_by_row, robust_line
from indicators.settings import AnalysisSettings


def test_huber_and_theilsen_match_statsmodels_and_scipy():
    rng = np.random.default_rng(5)
    v = rng.uniform(16, 26, 45)
    y = 0.3 * v + rng.standard_t(2, 45)
    rlm = sm.RLM(y, sm.add_constant(v), M=sm.robust.norms.HuberT()).fit()
    assert robust_line(v, y, "huber") == pytest.approx((rlm.params[1], rlm.params[0]), rel=1e-6)
    assert robust_line(v, y, "median") == pytest.approx((0.0, np.median(y)))
    ts = stats.theilslopes(y, v)
    assert robust_line(v, y, "theilsen") == pytest.approx((ts.slope, ts.intercept))
    assert robust_line(v, y, "ols") == pytest.approx(tuple(np.polyfit(v, y, 1)))
    # vectorised over rows = one call per row
    A, b = lines_by_row(np.vstack([v, v[::-1]]), np.vstack([y, y[::-1]]), "huber")
    assert A[0] == pytest.approx(A[1]) and b[0] == pytest.approx(b[1])


def test_features_are_line_values_in_seconds():
    v = np.array([16.0, 18.0, 20.0, 22.0, 24.0, 26.0])
    pts = pd.DataFrame(
        {
            "driver_id": "D1",
            "decision_id": [f"d{i}" for i in range(6)],
            "indicator": "t_f",
            "v": v,
            "y": np.exp(0.1 * v),
            "status": "ok",
            "used": True,
        }
    )
    feats, notes = driver_features(pts, ["D1"], AnalysisSettings())
    assert feats.loc["D1", "t_f_at_70kph_s"] == pytest.approx(np.exp(0.1 * 70 / 3.6))
    assert np.isnan(feats.loc["D1", "t_nf_at_80kph_s"])
    assert notes["D1"] == ["t_nf: no defined values, imputed"]


def test_lines_are_not_extrapolated_beyond_the_drivers_speeds():
    """7 presses at 68-86 km/h: the 60 km/h feature is the line at 68 km/h, not a guess below it."""
    v = np.linspace(19.0, 24.0, 7)
    pts = pd.DataFrame(
        {
            "driver_id": "D1",
            "decision_id": [f"d{i}" for i in range(7)],
            "indicator": "t_f",
            "v": v,
            "y": np.exp(0.3 * v),
            "status": "ok",
            "used": True,
        }
    )
    feats, _ = driver_features(pts, ["D1"], AnalysisSettings())
    assert feats.loc["D1", "t_f_at_60kph_s"] == pytest.approx(np.exp(0.3 * 19.0))
    assert feats.loc["D1", "t_f_at_90kph_s"] == pytest.approx(np.exp(0.3 * 24.0))
    assert feats.loc["D1", "t_f_at_80kph_s"] == pytest.approx(np.exp(0.3 * 80 / 3.6))
    wide, _ = driver_features(pts, ["D1"], AnalysisSettings(feature_extrapolate=True))
    assert wide.loc["D1", "t_f_at_60kph_s"] == pytest.approx(np.exp(0.3 * 60 / 3.6))


@pytest.mark.parametrize("method", ["huber", "theilsen", "ols"])
def test_rows_padded_with_nan_fit_like_unpadded(method):
    rng = np.random.default_rng(8)
    v = rng.uniform(16, 26, 30)
    y = 0.2 * v + rng.standard_t(3, 30)
    V = np.vstack([np.r_[v, np.full(10, np.nan)], np.r_[v, rng.uniform(16, 26, 10)]])
    Y = np.vstack([np.r_[y, np.full(10, np.nan)], np.r_[y, rng.normal(size=10)]])
    A, b = lines_by_row(V, Y, method)
    assert (A[0], b[0]) == pytest.approx(robust_line(v, y, method))


def test_trimmed_level_matches_scipy_and_shrugs_off_a_stray_press():
    rng = np.random.default_rng(3)
    rows = [rng.lognormal(3.5, 0.3, n) for n in (1, 2, 4, 5, 9, 23)]
    Y = np.full((len(rows), 23), np.nan)
    for r, y in enumerate(rows):
        Y[r, : len(y)] = y
    A, b = lines_by_row(np.full_like(Y, 20.0), Y, "trimmed")
    assert (A == 0).all()
    assert b == pytest.approx([stats.trim_mean(y, 0.2) for y in rows])
    # a driver's level of gaps it accepts: one gap left open by traffic (300 m) barely moves it
    gaps = np.array([30.0, 32.0, 31.0, 29.0, 33.0, 30.5, 31.5, 300.0])
    _, level = lines_by_row(np.full((1, 8), 20.0), gaps[None, :], "trimmed")
    assert 30.0 < level[0] < 32.0
