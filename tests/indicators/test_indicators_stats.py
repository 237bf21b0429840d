"""Correlations and OLS fits per driver, including the cases that get no fit."""

import numpy as np
import pandas as pd
import pytest
from scipy import stats as sstats

from indicators.settings import AnalysisSettings
from indicators.stats import PAPER_INDICATORS, LineFit, correlate, fit_line, fit_lines, fit_reasons, pearson


def table(driver: str, v, t_f, t_nf=None, dv_nb=None, f_v=None) -> pd.DataFrame:
    n = len(v)
    t_nf = np.full(n, np.nan) if t_nf is None else np.asarray(t_nf, float)
    dv_nb = np.full(n, np.nan) if dv_nb is None else np.asarray(dv_nb, float)
    t_f = np.asarray(t_f, float)
    return pd.DataFrame(
        {
            "driver_id": driver,
            "decision_id": [f"{driver}:{i}" for i in range(n)],
            "label": "change",
            "cancelled": False,
            "ego_v_mps": np.asarray(v, float),
            "t_f_s": t_f,
            "t_f_status": np.where(np.isnan(t_f), "absent", "ok"),
            "t_nf_s": t_nf,
            "t_nf_status": np.where(np.isnan(t_nf), "absent", "ok"),
            "dv_nb_mps": dv_nb,
            "dv_nb_status": np.where(np.isnan(dv_nb), "absent", "ok"),
            "f_v_mps": np.full(n, 0.0) if f_v is None else np.asarray(f_v, float),
            "nf_v_mps": 0.0,
        }
    )


V = np.array([16.0, 18.0, 20.0, 22.0, 24.0, 26.0])


def test_exact_line_is_recovered():
    df = table("D1", V, 0.3 * V - 1.0, 0.2 * V + 0.5, 1.0 * V - 9.0)
    fits = fit_lines(df).set_index("indicator")
    assert fits.loc["t_f", "A"] == pytest.approx(0.3)
    assert fits.loc["t_f", "b"] == pytest.approx(-1.0)
    assert fits.loc["t_nf", "A"] == pytest.approx(0.2)
    assert fits.loc["dv_nb", "b"] == pytest.approx(-9.0)
    assert fits.loc["t_f", "r2"] == pytest.approx(1.0)
    paper = fits.loc[list(PAPER_INDICATORS)]
    assert (paper["status"] == "ok").all() and (paper["n"] == 6).all()
    assert (fits.drop(index=list(PAPER_INDICATORS))["status"] == "skipped").all()  # the table has no gaps


def test_ols_matches_hand_formulas_and_bands_contain_line():
    rng = np.random.default_rng(3)
    v = rng.uniform(16, 26, 40)
    y = 0.25 * v + 0.4 + rng.normal(0, 0.4, 40)
    fit = fit_line(v, y)
    A, b = np.polyfit(v, y, 1)
    assert fit.A == pytest.approx(A) and fit.b == pytest.approx(b)
    resid = y - (A * v + b)
    s2 = resid @ resid / 38
    se_A = np.sqrt(s2 / ((v - v.mean()) @ (v - v.mean())))
    assert fit.A_se == pytest.approx(se_A)
    q = sstats.t.ppf(0.975, 38)
    assert fit.A_lo == pytest.approx(A - q * se_A) and fit.A_hi == pytest.approx(A + q * se_A)
    bands = fit.bands(np.array([16.0, 21.0, 26.0]))
    assert np.all(bands["pi_lo"] < bands["ci_lo"]) and np.all(bands["ci_hi"] < bands["pi_hi"])
    # the confidence band at the mean speed is the CI of the mean: q * s / sqrt(n)
    mid = fit.bands(np.array([v.mean()]))
    assert (mid["ci_hi"] - mid["mean"])[0] == pytest.approx(q * np.sqrt(s2 / 40))
    # round trip through a fits-table row
    row = {
        k: getattr(fit, k)
        for k in ("A", "b", "A_se", "b_se", "A_lo", "A_hi", "b_lo", "b_hi", "r2", "n", "cov_Ab", "resid_sd", "df_resid")
    }
    assert LineFit.from_row(row) == fit


def test_pearson_and_spearman_match_scipy():
    rng = np.random.default_rng(1)
    v = rng.uniform(16, 26, 30)
    y = 0.2 * v + rng.normal(0, 1, 30)
    corr = correlate(table("D1", v, y)).set_index("indicator").loc["t_f"]
    r = sstats.pearsonr(v, y)
    rho = sstats.spearmanr(v, y)
    assert corr["pearson_r"] == pytest.approx(r.statistic)
    assert corr["pearson_p"] == pytest.approx(r.pvalue)
    assert corr["spearman_rho"] == pytest.approx(rho.statistic)
    assert corr["spearman_p"] == pytest.approx(rho.pvalue)
    assert corr["significant"] == (r.pvalue < 0.05)
    assert pearson(np.arange(5.0), 2 * np.arange(5.0)) == (1.0, 0.0)


def test_skipped_fits_say_why():
    few = table("FEW", V[:3], 0.3 * V[:3])
    flat = table("FLAT", np.full(6, 20.0) + np.linspace(0, 0.3, 6), 0.3 * V)
    none = table("NONE", V, np.full(6, np.nan))
    df = pd.concat([few, flat, none], ignore_index=True)
    fits = fit_lines(df, AnalysisSettings(min_fit_points=5, min_speed_spread_mps=1.0)).set_index(
        ["driver_id", "indicator"]
    )
    assert fits.loc[("FEW", "t_f"), "status"] == "skipped"
    assert fits.loc[("FEW", "t_f"), "reason"] == "too few defined values: 3 < 5"
    assert fits.loc[("FLAT", "t_f"), "reason"] == "no speed spread: 0.30 m/s < 1 m/s"
    assert fits.loc[("NONE", "t_f"), "reason"] == "no defined values (6 absent)"
    assert np.isnan(fits.loc[("NONE", "t_f"), "A"])
    corr = correlate(df).set_index(["driver_id", "indicator"])
    assert not corr.loc[("FEW", "t_f"), "significant"]
    assert corr.loc[("FEW", "t_f"), "reason"].startswith("too few")


def test_following_and_far_values_are_left_out_of_fits():
    y = 0.3 * V - 1.0
    y_out = y.copy()
    y_out[0] = 80.0  # decided while following a slow leader
    f_v = V - 5.0
    f_v[0] = V[0] - 0.2
    dv = V - 9.0
    df = table("D1", V, y_out, dv_nb=dv, f_v=f_v)
    df["dv_nb_status"] = ["far"] + ["ok"] * 5
    reasons = fit_reasons(df)
    assert list(reasons["t_f"]) == ["following"] + [""] * 5
    assert list(reasons["dv_nb"]) == ["far"] + [""] * 5
    fits = fit_lines(df).set_index("indicator")
    assert fits.loc["t_f", "n"] == 5 and fits.loc["t_f", "A"] == pytest.approx(0.3)
    assert fits.loc["dv_nb", "n"] == 5
    with_far = fit_lines(df, AnalysisSettings(fit_far_followers=True)).set_index("indicator")
    assert with_far.loc["dv_nb", "n"] == 6


def test_keep_states_and_cancelled_presses():
    df = table("D1", V, 0.3 * V - 1.0)
    keep = df.assign(label="keep", t_f_s=99.0)
    df.loc[0, "cancelled"] = True
    both = pd.concat([df, keep], ignore_index=True)
    assert fit_lines(both).set_index("indicator").loc["t_f", "n"] == 6
    assert fit_lines(both, AnalysisSettings(fit_cancelled=False)).set_index("indicator").loc["t_f", "n"] == 5


def test_front_gap_to_a_leader_pulling_away_is_left_out_of_fits():
    # a return to the right: the car ahead in the fast lane runs away at 3 m/s, so its gap
    # (120 m) is not a gap the driver accepts; the other five presses close in on a leader
    f_v = V - 2.0
    f_v[0] = V[0] + 3.0
    df = table("D1", V, 0.3 * V - 1.0, f_v=f_v).assign(f_gap_m=[120.0, 30.0, 31.0, 32.0, 33.0, 34.0])
    reasons = fit_reasons(df)
    assert list(reasons["gap_f"]) == ["receding"] + [""] * 5
    assert list(reasons["thw_f"]) == ["receding"] + [""] * 5
    assert list(reasons["dv_f"]) == [""] * 6  # the relative speed itself is still read
    assert fit_lines(df).set_index("indicator").loc["gap_f", "n"] == 5
    # the formulation without the rule stays available by name
    every = fit_reasons(df, AnalysisSettings(max_receding_mps=None))
    assert list(every["gap_f"]) == [""] * 6
