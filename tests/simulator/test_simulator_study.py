"""The study as a whole: determinism, drivers and styles, the typical drivers' lines."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from laneprint.reference import INDICATORS, PAPER_TABLE1, STYLES
from laneprint.simulator import StudySettings, simulate_study
from laneprint.simulator.drivers import style_counts


def test_same_seed_same_frames_other_seed_other_frames(small_settings, small_study):
    again = simulate_study(small_settings, seed=7)
    assert again.ground_truth == small_study.ground_truth
    for (m1, e1, t1), (m2, e2, t2) in zip(small_study.recordings, again.recordings):
        assert m1 == m2
        pd.testing.assert_frame_equal(e1, e2)
        pd.testing.assert_frame_equal(t1, t2)
    other = simulate_study(small_settings, seed=8)
    assert not np.allclose(
        other.recordings[0][1]["ego_v_mps"].iloc[:100], small_study.recordings[0][1]["ego_v_mps"].iloc[:100]
    )
    assert [d["press_t_s"] for d in other.decisions] != [d["press_t_s"] for d in small_study.decisions]


def test_no_global_random_state_used(small_settings):
    np.random.seed(1)
    a = simulate_study(small_settings, seed=3).ground_truth
    np.random.seed(2)
    b = simulate_study(small_settings, seed=3).ground_truth
    assert a == b


def test_style_counts():
    assert style_counts(10, (0.3, 0.4, 0.3)) == {"Defensive": 3, "Normal": 4, "Aggressive": 3}
    assert style_counts(3, (0.3, 0.4, 0.3)) == {"Defensive": 1, "Normal": 1, "Aggressive": 1}
    assert style_counts(1, (0.3, 0.4, 0.3)) == {"Defensive": 0, "Normal": 1, "Aggressive": 0}
    assert sum(style_counts(23, (0.3, 0.4, 0.3)).values()) == 23


def test_default_study_layout(default_study):
    gt = default_study.ground_truth
    assert len(default_study.recordings) == 40
    assert len(default_study.decisions) == 500
    ids = [m["session_id"] for m, _, _ in default_study.recordings]
    assert len(set(ids)) == 40 and "D03_S80" in ids
    per = pd.Series([d["session_id"] for d in default_study.decisions]).value_counts()
    assert set(per.tolist()) == {12, 13}
    styles = [d["style"] for d in gt["drivers"]]
    assert {s: styles.count(s) for s in STYLES} == {"Defensive": 3, "Normal": 4, "Aggressive": 3}
    typical = [d for d in gt["drivers"] if d["typical"]]
    assert sorted(d["style"] for d in typical) == sorted(STYLES)
    for d in typical:
        for k in INDICATORS:
            assert (d["lines"][k]["A"], d["lines"][k]["b"]) == PAPER_TABLE1[d["style"]][k]
    cases = pd.Series([d["case"] for d in default_study.decisions]).value_counts().to_dict()
    assert cases == {"clean": 340, "no_target_leader": 60, "far_follower": 40, "slowed": 40, "cancelled": 20}


def test_styles_stay_separable(default_study):
    """Every driver's t_f at the mid speed is nearer its own style's line than any other style's."""
    v_mid = 75 / 3.6
    for d in default_study.ground_truth["drivers"]:
        a, b = d["lines"]["t_f"]["A"], d["lines"]["t_f"]["b"]
        mine = a * v_mid + b
        dist = {s: abs(mine - (PAPER_TABLE1[s]["t_f"][0] * v_mid + PAPER_TABLE1[s]["t_f"][1])) for s in STYLES}
        assert min(dist, key=dist.get) == d["style"]


@pytest.mark.parametrize("style", STYLES)
def test_typical_drivers_scatter_around_table1(default_study, style):
    gt = default_study.ground_truth
    did = next(d["driver_id"] for d in gt["drivers"] if d["typical"] and d["style"] == style)
    mine = [d for d in default_study.decisions if d["driver_id"] == did]
    for k, key, slope_tol in (("t_f", "t_f_s", 0.1), ("t_nf", "t_nf_s", 0.1), ("dv_nb", "dv_nb_mps", 0.25)):
        pts = [(d["v_e_mps"], d[key]) for d in mine if d["from_preference"][k] and d["case"] != "slowed"]
        assert len(pts) >= 40
        v, y = np.array(pts).T
        slope, intercept = np.polyfit(v, y, 1)
        a, b = PAPER_TABLE1[style][k]
        assert slope == pytest.approx(a, abs=slope_tol)
        resid = y - (a * v + b)
        assert abs(resid.mean()) < 0.3 * (3 if k == "dv_nb" else 1)


def test_settings_reject_nonsense():
    with pytest.raises(ValueError):
        replace(StudySettings(), n_drivers=0)
    with pytest.raises(ValueError):
        replace(StudySettings(), decisions_per_driver=2)
    with pytest.raises(ValueError):
        replace(StudySettings(), share_slowed=0.9, share_no_target_leader=0.2)


def test_shipped_sample_logs_are_the_default_study(default_study):
    """sample_logs/ is what `laneprint simulate --out sample_logs --seed 0` writes today (no drift)."""
    import json
    from pathlib import Path

    folder = Path(__file__).resolve().parents[2] / "sample_logs"
    shipped = json.loads((folder / "ground_truth.json").read_text())
    files = shipped.pop("files")
    assert shipped.pop("format") == "mixed"
    assert shipped == json.loads(json.dumps(default_study.ground_truth))
    assert len(files) == 40 and len({f["session_id"] for f in files}) == 40
    for f in files:
        assert (folder / f["path"]).stat().st_size == f["bytes"]
    total = sum(p.stat().st_size for p in folder.iterdir())
    assert total < 25e6
