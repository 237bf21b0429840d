"""The analysis completes on awkward input and says what it skipped and why."""

import numpy as np
import pandas as pd
import pytest

from clustering.pipeline import analyze_tables
from indicators.settings import AnalysisSettings
from tests.support.synthetic_decisions import make_decision_table


def awkward_table() -> pd.DataFrame:
    df, _ = make_decision_table(9, 20, seed=7, keep_per_press=2)
    presses = df["label"] == "change"
    # ONE: a driver with a single decision
    one = df[(df["driver_id"] == "D0000") & (df["decision_id"] == "r0000:0")].assign(driver_id="ONE")
    # FLAT: a section with no speed spread (all presses at 70 km/h)
    flat = df[df["driver_id"] == "D0001"].assign(driver_id="FLAT", ego_v_mps=70 / 3.6)
    # NONF: no target-lane leader at any press (t_nf undefined for the whole driver)
    nonf = df[df["driver_id"] == "D0002"].assign(
        driver_id="NONF", t_nf_s=np.nan, nf_present=False, t_nf_status="absent"
    )
    # KEEPONLY: states but no press
    keep_only = df[(df["driver_id"] == "D0003") & ~presses].assign(driver_id="KEEPONLY")
    return pd.concat([df, one, flat, nonf, keep_only], ignore_index=True)


def test_awkward_drivers_complete_with_reasons():
    out = analyze_tables(awkward_table(), AnalysisSettings(features="auto"))
    fits = out["fits"].set_index(["driver_id", "indicator"])
    skipped = out["skipped"]
    why = {(r.what, r.id): r.reason for r in skipped.itertuples()}

    assert fits.loc[("ONE", "t_f"), "status"] == "skipped"
    assert fits.loc[("ONE", "t_f"), "reason"] == "too few defined values: 1 < 5"
    assert fits.loc[("FLAT", "t_f"), "reason"].startswith("no speed spread: 0.00 m/s")
    assert fits.loc[("NONF", "t_nf"), "reason"] == "no defined values (20 absent)"
    assert fits.loc[("NONF", "t_f"), "status"] == "ok"
    assert why[("indicator", "NONF:t_nf")] == "no defined values (20 absent)"
    assert why[("driver", "KEEPONLY")] == "no presses (only keep states)"
    assert ("driver", "KEEPONLY") in why
    # every press value left out of a fit is listed with its reason
    values = skipped[skipped["what"] == "value"]
    assert (
        (values["id"] == "r0002:0:t_nf") & (values["reason"] == "t_nf undefined: no leader in the target lane")
    ).any()

    st = out["styles"].set_index("driver_id")
    # every driver with any feature gets a style and says how
    for d in ("ONE", "FLAT", "NONF"):
        assert st.loc[d, "style"] in ("Defensive", "Normal", "Aggressive")
    assert st.loc["ONE", "assigned_by"] == "nearest centre"
    assert "only 1 presses" in st.loc["ONE", "note"]
    assert "t_nf: no defined values, imputed" in st.loc["NONF", "note"]
    assert "no speed spread, median used" in st.loc["FLAT", "note"]
    assert st.loc["KEEPONLY", "style"] == "unassigned" and st.loc["KEEPONLY", "cluster"] == -1
    assert not st.loc[["ONE", "KEEPONLY"], "is_typical"].any()
    corr = out["correlations"].set_index(["driver_id", "indicator"])
    assert not corr.loc[("ONE", "t_f"), "significant"]


def test_no_presses_at_all_still_completes():
    df = awkward_table()
    out = analyze_tables(df[df["label"] == "keep"])
    assert (out["fits"]["status"] == "skipped").all()
    assert (out["styles"]["style"] == "unassigned").all()
    assert len(out["reference_lines"][out["reference_lines"]["kind"] != "paper"]) == 0
    assert (out["skipped"]["what"] == "driver").any()


@pytest.mark.slow
def test_heavy_tailed_ttc_does_not_move_styles():
    df, truth = make_decision_table(9, 40, seed=11, keep_per_press=0)
    fast = AnalysisSettings(n_bootstrap=0)
    base = analyze_tables(df, fast)["styles"].set_index("driver_id")["style"]
    # a tenth of every driver's presses made while following a slow leader: TTC 20-200 s,
    # closing speed unknown in this table (so not flagged 'following'): only robustness helps
    rng = np.random.default_rng(0)
    tail = rng.random(len(df)) < 0.1
    noisy = df.copy()
    noisy.loc[tail, "t_f_s"] = rng.uniform(20, 200, tail.sum())
    styles = analyze_tables(noisy, fast)["styles"].set_index("driver_id")["style"]
    assert (styles == base).all()
    assert (styles == pd.Series(truth)).all()
