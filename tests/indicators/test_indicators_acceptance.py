"""Gaps, headways and relative speeds at a decision: values by hand, and the undefined rules."""

import numpy as np
import pandas as pd
import pytest

from indicators.acceptance import add_acceptance
from indicators.decisions import extract_decisions
from indicators.settings import AnalysisSettings
from tests.support.synthetic_decisions import make_recording


def scene(**cols) -> pd.DataFrame:
    base = {
        "ego_v_mps": [20.0],
        "f_gap_m": [np.nan],
        "f_v_mps": [np.nan],
        "nf_gap_m": [np.nan],
        "nf_v_mps": [np.nan],
        "nb_gap_m": [np.nan],
        "nb_v_mps": [np.nan],
    }
    base.update({k: [v] for k, v in cols.items()})
    return pd.DataFrame(base)


def test_headways_and_relative_speeds_by_hand():
    d = add_acceptance(scene(f_gap_m=30.0, f_v_mps=15.0, nf_gap_m=50.0, nf_v_mps=22.0, nb_gap_m=24.0, nb_v_mps=24.0))
    row = d.iloc[0]
    assert row["thw_f_s"] == pytest.approx(1.5)  # 30 m / 20 m/s
    assert row["dv_f_mps"] == pytest.approx(5.0)  # closing in on the leader
    assert row["dv_nf_mps"] == pytest.approx(-2.0)  # the target-lane leader pulls away
    assert row["thw_nb_s"] == pytest.approx(1.0)  # the follower needs 24 m / 24 m/s to reach the ego
    assert all(row[f"{i}_status"] == "ok" for i in ("gap_f", "thw_f", "dv_f", "gap_nf", "dv_nf", "gap_nb", "thw_nb"))


def test_undefined_values_are_nan_with_a_reason_never_a_sentinel():
    d = add_acceptance(scene(nb_gap_m=140.0, nb_v_mps=0.0), AnalysisSettings(far_follower_m=100.0))
    row = d.iloc[0]
    assert np.isnan(row["thw_f_s"]) and row["thw_f_status"] == "absent" and row["gap_f_status"] == "absent"
    assert np.isnan(row["dv_nf_mps"]) and row["dv_nf_status"] == "absent"
    assert row["gap_nb_status"] == "far" and row["nb_gap_m"] == 140.0  # kept, left out of fits
    assert np.isnan(row["thw_nb_s"]) and row["thw_nb_status"] == "stopped"  # a standing follower has no headway
    slow = add_acceptance(scene(ego_v_mps=0.1, f_gap_m=5.0, f_v_mps=0.0)).iloc[0]
    assert np.isnan(slow["thw_f_s"]) and slow["thw_f_status"] == "stopped" and slow["gap_f_status"] == "ok"


def test_extracted_decisions_carry_the_acceptance_indicators():
    # ego at 25 m/s; leader 40 m ahead (centres) at 25 m/s: not closing, so t_f is undefined
    meta, ego, traffic = make_recording(
        10,
        10,
        25.0,
        [(0, 0), (6.0, 1)],
        presses=[(5.0, 0.3, "left")],
        vehicles=[("L", 40.0, 25.0, 0, 4.5), ("B", -30.0, 24.0, 1, 4.5)],
    )
    dec, _ = extract_decisions(meta, ego, traffic, AnalysisSettings())
    press = dec[dec["label"] == "change"].iloc[0]
    assert press["t_f_status"] == "not_closing" and np.isnan(press["t_f_s"])
    assert press["f_gap_m"] == pytest.approx(40.0 - 4.5)
    assert press["thw_f_s"] == pytest.approx((40.0 - 4.5) / 25.0)
    assert press["dv_f_mps"] == pytest.approx(0.0)
    assert press["nb_gap_m"] == pytest.approx(35.0 - 4.5)  # at t = 5 the follower, 1 m/s slower, is 35 m behind
    assert press["thw_nb_s"] == pytest.approx((35.0 - 4.5) / 24.0)
    assert press["gap_nf_status"] == "absent"
