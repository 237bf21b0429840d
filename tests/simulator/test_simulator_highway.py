"""`laneprint simulate --engine highway`: drivers that are highway-env IDM + MOBIL vehicles.

Small and fast: a one-section, one-minute study of two drivers in memory, and a
half-minute study through the command line, ingested. Needs highway-env (the
`highway` extra, part of the test extra); skipped where it cannot be imported.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.schemas import EGO, TRAFFIC
from laneprint.simulator.highway.settings import HighwaySettings, simulator_text, study_world
from laneprint.simulator.drivers import style_order
from laneprint.simulator.highway.styles import STYLE_PARAMS, make_highway_drivers, true_parameter_ari
from laneprint.simulator.highway.study import section_densities, simulate_highway_study, study_drivers

pytest.importorskip("highway_env")

runner = CliRunner()
TINY = replace(HighwaySettings(), n_drivers=2, speed_limits_kph=(60,), minutes=1.0, warmup_s=5.0)
LANE_WIDTH_M = TINY.lane_width_m


@pytest.fixture(scope="module")
def tiny():
    return simulate_highway_study(TINY, seed=4)


@pytest.fixture(scope="module")
def cli_study(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("highway") / "study"
    res = runner.invoke(
        app,
        [
            "simulate",
            "--engine",
            "highway",
            "--drivers",
            "2",
            "--minutes",
            "0.5",
            "--seed",
            "2",
            "--out",
            str(out),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    return out, json.loads(res.stdout)


# --- the drivers (no simulation) ---------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_true_parameters_cluster_into_the_styles(seed):
    """k-means (k = 3) on the default study's standardised true parameters recovers the styles exactly."""
    drivers = study_drivers(HighwaySettings(), seed)
    assert [d.style for d in drivers] == ["Defensive", "Normal", "Aggressive"] * 3
    assert true_parameter_ari(drivers) == 1.0


def test_styles_are_ordered_and_drivers_seeded():
    d, n, a = (STYLE_PARAMS[s] for s in ("Defensive", "Normal", "Aggressive"))
    assert 1.8 <= d["TIME_WANTED"] <= 2.2 and 0.8 <= a["TIME_WANTED"] <= 1.0
    for key in ("TIME_WANTED", "LANE_CHANGE_MIN_ACC_GAIN", "POLITENESS"):
        assert d[key] > n[key] > a[key]
    braking = [p["LANE_CHANGE_MAX_BRAKING_IMPOSED"] for p in (d, n, a)]
    assert braking == sorted(braking) and braking[0] < braking[2] / 3  # a large safety margin vs a small one
    first = make_highway_drivers(9, 0.1, np.random.default_rng(5))
    assert first == make_highway_drivers(9, 0.1, np.random.default_rng(5))
    assert [x.typical for x in first] == [True] * 3 + [False] * 6 and first[0].params == d


def test_unequal_groups():
    assert style_order(9, (2, 4, 3)) == [
        "Defensive",
        "Normal",
        "Aggressive",
        "Defensive",
        "Normal",
        "Aggressive",
        "Normal",
        "Aggressive",
        "Normal",
    ]
    drivers = study_drivers(replace(HighwaySettings(), style_shares=(2, 4, 3)), 0)
    assert [sum(x.style == s for x in drivers) for s in ("Defensive", "Normal", "Aggressive")] == [2, 4, 3]
    assert true_parameter_ari(drivers) == 1.0


def test_section_densities_are_stratified_and_seeded():
    s = HighwaySettings()
    dens = np.array(section_densities(s, 7))
    assert dens.shape == (4, 2) and (dens == np.array(section_densities(s, 7))).all()
    spacing_s = 1000.0 / (dens * np.array(s.speed_limits_kph)[:, None] / 3.6)
    for k, (lo, hi) in enumerate((s.lane_spacing_s[0], s.lane_spacing_s[2])):
        strata = np.floor((spacing_s[:, k] - lo) / (hi - lo) * 4 + 1e-6)
        assert sorted(strata) == [0, 1, 2, 3]  # one light, one busy section, and two between


def test_simulator_text_round_trips():
    assert simulator_text("1.12.1") == "highway-env 1.12.1 (laneprint simulate --engine highway)"
    assert study_world(simulator_text("1.12.1", 3)) == 3 and study_world("Eclipse SUMO 1.28.0") is None


# --- a tiny study in memory ------------------------------------------------------------------


def test_frames_have_the_log_columns(tiny):
    assert len(tiny.recordings) == 2
    for meta, ego, traffic in tiny.recordings:
        assert list(ego.columns) == [c.name for c in EGO.columns]
        assert list(traffic.columns) == [c.name for c in TRAFFIC.columns]
        assert meta["simulator"] == simulator_text(tiny.ground_truth["highway_env_version"])
        t = ego["t_s"].to_numpy()
        assert t[0] == 0 and np.allclose(np.diff(t), 0.1) and len(t) == 600
        assert set(traffic["t_s"]) <= set(t) and traffic["vehicle_id"].nunique() > 5


def test_lanes_are_numbered_from_the_right(tiny):
    """LOG_FORMAT: lane 0 is the rightmost, y grows to the left (highway-env's run the other way)."""
    for _, ego, traffic in tiny.recordings:
        assert ego["ego_lane"].iloc[0] == 0 and abs(ego["ego_y_m"].iloc[0]) < 0.01  # starts in the right lane
        for frame, lane, y in ((ego, "ego_lane", "ego_y_m"), (traffic, "lane", "y_m")):
            assert set(frame[lane]) <= {0, 1}
            assert (np.abs(frame[y] - frame[lane] * LANE_WIDTH_M) <= LANE_WIDTH_M / 2 + 1e-9).all()
        # the slow stream drives on the right, the fast one on the left
        v = traffic.groupby("lane")["v_mps"].median()
        assert v[0] < v[1]


def test_presses_match_the_ground_truth(tiny):
    gt = tiny.ground_truth
    assert gt["engine"] == "highway" and gt["n_lanes"] == 2 and gt["seed"] == 4
    assert {
        "generator",
        "version",
        "highway_env_version",
        "settings",
        "style_params",
        "drivers",
        "sessions",
        "decisions",
        "true_parameter_ari",
    } <= set(gt)
    assert [set(d["params"]) for d in gt["drivers"]] == [set(STYLE_PARAMS["Defensive"])] * 2
    for meta, ego, _ in tiny.recordings:
        btn = ego["lc_button"].to_numpy(dtype=bool)
        edges = np.flatnonzero(btn & ~np.r_[False, btn[:-1]])
        mine = [d for d in gt["decisions"] if d["session_id"] == meta["session_id"]]
        pressed = [d for d in mine if d["pressed"]]
        assert np.allclose(ego["t_s"].to_numpy()[edges], [d["press_t_s"] for d in pressed])
        assert list(ego["lc_direction"].iloc[edges]) == [d["direction"] for d in pressed]
        for d in mine:
            assert d["target_lane"] == d["from_lane"] + (1 if d["direction"] == "left" else -1)
            assert d["missed"] == (not d["pressed"]) and (d["press_t_s"] is None) == d["missed"]
            assert 0.3 <= d["reaction_s"] <= 1.0
            if d["changed"]:
                assert d["lane_flip_t_s"] > d["decision_t_s"] and not d["aborted"]
    assert sum(d["pressed"] for d in gt["decisions"]) > 0


@pytest.mark.slow
def test_same_seed_same_study_whatever_the_jobs(tiny):
    again = simulate_highway_study(TINY, seed=4, jobs=2)
    assert again.ground_truth == tiny.ground_truth
    for (_, e1, t1), (_, e2, t2) in zip(tiny.recordings, again.recordings):
        pd.testing.assert_frame_equal(e1, e2)
        pd.testing.assert_frame_equal(t1, t2)
    other = simulate_highway_study(TINY, seed=5)
    assert not other.recordings[0][1].equals(tiny.recordings[0][1])


# --- the command line ----------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_writes_a_study_that_ingest_accepts(cli_study, tmp_path):
    out, summary = cli_study
    sessions = [f"D0{d}_S{v}" for d in (1, 2) for v in (60, 70, 80, 90)]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"{s}.csv.gz" for s in sessions] + ["README.md", "ground_truth.json"]
    )
    assert summary["engine"] == "highway" and summary["recordings"] == 8 and summary["format"] == "csv"
    assert summary["presses"] == sum(summary["presses_per_driver"].values())
    assert "highway-env" in (out / "README.md").read_text()
    res = runner.invoke(app, ["ingest", str(out), "--workspace", str(tmp_path / "ws"), "--json"])
    assert res.exit_code == 0, res.output
    counts = json.loads(res.stdout)["counts"]  # 'warning': half a minute without a press
    assert counts["ingested"] + counts["warning"] == 8 and counts["rejected"] == 0


@pytest.mark.parametrize(
    "args, message",
    [
        (["--family", "ttc"], "--family is for --engine sumo"),
        (["--shares", "1,2"], "--shares '1,2'"),
        (["--lanes", "4"], "--lanes 4"),
        (["--decisions", "20"], "--decisions is for --engine synthetic"),
    ],
)
def test_cli_refuses_options_that_do_not_apply(args, message, tmp_path):
    res = runner.invoke(app, ["simulate", "--engine", "highway", "--out", str(tmp_path / "x"), *args])
    assert res.exit_code == 1 and message in res.output
