"""Lines per direction: overtaking (to the left) and returning (to the right) read apart."""

import numpy as np
import pandas as pd
import pytest

from clustering.pipeline import analyze_tables
from indicators.directions import fits_by_direction, press_counts
from indicators.settings import AnalysisSettings
from tests.support.synthetic_decisions import make_decision_table
from rl.problem.rewards import ReferenceLines


def two_sided(n_right: int) -> pd.DataFrame:
    """Table 1 drivers whose first `n_right` presses of each driver return to the right, with
    t_f there twice as long: a different line on each side."""
    dec, _ = make_decision_table(6, 40, seed=3)
    idx = dec["decision_id"].str.split(":").str[-1].astype(int)
    right = idx < n_right
    dec.loc[right, ["ego_lane", "target_lane"]] = [1, 0]
    dec.loc[right, "t_f_s"] *= 2.0
    return dec


def test_each_side_gets_its_own_line_where_it_has_enough_presses():
    dec = two_sided(20)
    assert press_counts(dec) == {"left": 120, "right": 120}
    f = fits_by_direction(dec, AnalysisSettings(), sorted(dec["driver_id"].unique()), ("t_f",))
    f = f.set_index(["driver_id", "direction"])
    assert (f["status"] == "ok").all()
    for d in dec["driver_id"].unique():  # the right-hand line is about twice the left-hand one
        v = 22.0
        left, right = (f.loc[(d, s), "A"] * v + f.loc[(d, s), "b"] for s in ("left", "right"))
        assert right / left == pytest.approx(2.0, rel=0.25)


def test_a_side_with_too_few_presses_says_the_pooled_line_stands():
    dec = two_sided(3)
    f = fits_by_direction(dec, AnalysisSettings(), sorted(dec["driver_id"].unique()), ("t_f",))
    right = f[f["direction"] == "right"]
    assert (right["status"] == "skipped").all()
    assert right["reason"].str.endswith("to the right: the pooled line stands").all()


def test_reference_lines_carry_the_direction_and_the_agents_read_both():
    out = analyze_tables(two_sided(20), AnalysisSettings(n_bootstrap=0))
    refs = out["reference_lines"]
    assert set(refs["direction"]) == {"both", "left", "right"}
    style = refs[(refs["scope"] == "style") & (refs["kind"] == "typical")]["name"].iloc[0]
    sel = refs[(refs["scope"] == "style") & (refs["kind"] == "typical") & (refs["name"] == style)]
    both = sel[(sel["direction"] == "both") & (sel["indicator"] == "t_f")].iloc[0]
    lines = ReferenceLines.from_table(refs, style=style)
    assert lines.t_f == (both["A"], both["b"])
    assert set(sel["direction"]) == {"both", "left", "right"}
    assert np.isfinite(out["fits_by_direction"]["A"]).any()
