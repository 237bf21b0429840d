"""`laneprint simulate --engine sumo`: a tiny study through the real command line, ingested.

Needs Eclipse SUMO (`pip install -e '.[sumo]'`, part of the test extra); skipped
with that hint where neither libsumo nor traci can be imported.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.simulator.sumo.section import lane_change_starts
from laneprint.simulator.sumo.styles import STYLE_PARAMS, make_sumo_drivers
from laneprint.workspace import Workspace

runner = CliRunner()
TINY = ["--engine", "sumo", "--drivers", "3", "--minutes", "1", "--seed", "3"]
SESSIONS = [f"D0{d}_S{v}" for d in (1, 2, 3) for v in (60, 70, 80, 90)]
LANE_WIDTH_M = 3.5


def _sumo_or_skip() -> None:
    from laneprint.simulator.sumo.backend import check_available

    try:
        check_available()
    except UserError as exc:
        pytest.skip(f"libsumo/traci not importable here ({exc})")


def _simulate(out: Path) -> dict:
    res = runner.invoke(app, ["simulate", "--out", str(out), *TINY, "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> tuple[Path, dict]:
    _sumo_or_skip()
    out = tmp_path_factory.mktemp("sumo") / "study"
    return out, _simulate(out)


@pytest.fixture(scope="module")
def workspace(study, tmp_path_factory) -> tuple[Workspace, dict]:
    ws = tmp_path_factory.mktemp("sumo_ws") / "ws"
    res = runner.invoke(app, ["ingest", str(study[0]), "--workspace", str(ws), "--json"])
    assert res.exit_code == 0, res.output
    return Workspace(ws), json.loads(res.stdout)


# --- pure parts (no SUMO needed) ------------------------------------------------------


def test_lane_change_starts_are_the_first_samples_off_the_lane_centre():
    y = np.array([0, 0, 0.1, 1.0, 2.0, 3.0, 3.5, 3.5, 3.4, 2.0, 0.5, 0.0, 0.0])
    lane = np.array([0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 0, 0, 0])
    assert lane_change_starts(y, lane, LANE_WIDTH_M) == [(2, "left", 0), (8, "right", 1)]


def test_drivers_round_robin_typical_first_and_seeded():
    a = make_sumo_drivers(7, 0.1, np.random.default_rng(1))
    b = make_sumo_drivers(7, 0.1, np.random.default_rng(1))
    assert [d.style for d in a] == ["Defensive", "Normal", "Aggressive"] * 2 + ["Defensive"]
    assert [d.typical for d in a] == [True] * 3 + [False] * 4
    assert a[0].params == STYLE_PARAMS["Defensive"] and a == b
    assert a[3].params != STYLE_PARAMS["Defensive"] and set(a[3].params) == set(STYLE_PARAMS["Defensive"])


# --- a real run -----------------------------------------------------------------------


@pytest.mark.slow
def test_cli_writes_the_study(study):
    out, summary = study
    names = sorted(p.name for p in out.iterdir())
    expected = [f"{s}.mcap" for s in SESSIONS if s[2] in "13"] + [f"{s}.csv.gz" for s in SESSIONS if s[2] == "2"]
    assert names == sorted(expected + ["README.md", "ground_truth.json"])
    assert summary["engine"] == "sumo" and summary["recordings"] == 12 and summary["drivers"] == 3
    assert summary["decisions"] == sum(summary["decisions_per_driver"].values()) > 0
    assert "Eclipse SUMO" in (out / "README.md").read_text()


@pytest.mark.slow
def test_ground_truth_lists_drivers_styles_and_lane_changes(study):
    gt = json.loads((study[0] / "ground_truth.json").read_text())
    assert gt["engine"] == "sumo" and gt["seed"] == 3 and gt["generator"] == "laneprint.simulator"
    assert [(d["driver_id"], d["style"], d["typical"]) for d in gt["drivers"]] == [
        ("D01", "Defensive", True),
        ("D02", "Normal", True),
        ("D03", "Aggressive", True),
    ]
    assert all(set(d["sumo_params"]) == set(STYLE_PARAMS[d["style"]]) for d in gt["drivers"])
    assert {s["session_id"] for s in gt["sessions"]} == set(SESSIONS)
    assert len(gt["decisions"]) == study[1]["decisions"]
    for dec in gt["decisions"]:
        assert dec["target_lane"] == dec["from_lane"] + (1 if dec["direction"] == "left" else -1)
        assert dec["changed"] and dec["lane_flip_t_s"] > dec["press_t_s"]


@pytest.mark.slow
def test_ingest_accepts_every_file(workspace):
    _, res = workspace
    assert res["counts"]["ingested"] == 12 and res["counts"]["rejected"] == 0 and res["counts"]["warning"] == 0


@pytest.mark.slow
def test_presses_come_before_the_lane_flips(study, workspace):
    ws, _ = workspace
    gt = json.loads((study[0] / "ground_truth.json").read_text())
    n_presses = 0
    for meta, ego, traffic in ws.iter_recordings():
        btn = ego["lc_button"].to_numpy(dtype=bool)
        lane = ego["ego_lane"].to_numpy()
        y = ego["ego_y_m"].to_numpy()
        t = ego["t_s"].to_numpy()
        presses = np.flatnonzero(btn & ~np.r_[False, btn[:-1]])
        truth = [d["press_t_s"] for d in gt["decisions"] if d["session_id"] == meta["session_id"]]
        assert np.allclose(t[presses], truth, atol=1e-6)
        for p in presses:
            assert abs(y[p - 1] - lane[p - 1] * LANE_WIDTH_M) < 1e-3  # at the lane centre just before
            assert ego["lc_direction"].iloc[p] in ("left", "right")
            flip = p + int(np.argmax(lane[p:] != lane[p]))
            assert lane[flip] != lane[p] and 0.5 < t[flip] - t[p] < 3.0  # the flip comes half way through
        n_presses += len(presses)
        assert traffic["vehicle_id"].nunique() > 0
    assert n_presses == len(gt["decisions"]) > 0


@pytest.mark.slow
def test_same_seed_same_bytes(study, tmp_path):
    out, summary = study
    again = tmp_path / "again"
    assert _simulate(again)["decisions_per_driver"] == summary["decisions_per_driver"]
    for f in out.iterdir():
        assert (again / f.name).read_bytes() == f.read_bytes(), f.name


def test_sumo_drivers_follow_the_shares_and_equal_shares_keep_the_round_robin():
    """`--shares 2,4,3` gives 2/4/3 drivers; the default keeps D, N, A, D, ... and the same perturbations."""
    unequal = make_sumo_drivers(9, 0.1, np.random.default_rng(3), "ttc", (2, 4, 3))
    assert [d.style for d in unequal].count("Normal") == 4
    assert [d.style for d in unequal].count("Defensive") == 2
    assert sum(d.typical for d in unequal) == 3
    equal = make_sumo_drivers(9, 0.1, np.random.default_rng(3))
    assert [d.style for d in equal] == ["Defensive", "Normal", "Aggressive"] * 3
    assert [d.typical for d in equal] == [True] * 3 + [False] * 6
