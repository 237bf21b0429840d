"""`laneprint simulate --engine sumo --lanes 3`: a three-lane highway.

Settings and option errors are fast; a tiny study (3 drivers, 1 minute a section:
marked slow) runs through the real command line and is ingested and analysed: the
ego changes from every lane, both ways from the middle one, and the analysis finds
the target lane of every press. The real run needs Eclipse SUMO (skipped with the
install hint otherwise).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.simulator.sumo.settings import LANES, SumoSettings, family_settings
from laneprint.workspace import Workspace

runner = CliRunner()
TINY3 = ["--engine", "sumo", "--lanes", "3", "--drivers", "3", "--minutes", "1", "--seed", "3"]


# --- fast parts ---------------------------------------------------------------------


def test_lanes_settings():
    assert LANES == (2, 3) and SumoSettings().n_lanes == 2 and family_settings() == SumoSettings()
    three = family_settings("ttc", 3)
    assert three.n_lanes == 3 and "middle" in three.ahead_streams
    assert [three.stream_lane(s) for s in ("slow", "middle", "left", "fast")] == [0, 1, 2, 2]
    assert [SumoSettings().stream_lane(s) for s in ("slow", "left", "fast")] == [0, 1, 1]
    acc = family_settings("acceptance", 3)
    assert acc.n_lanes == 3 and acc.car_follow_model == "IDM" and "middle" in acc.ahead_streams
    with pytest.raises(ValueError, match="n_lanes"):
        family_settings("ttc", 4)
    with pytest.raises(ValueError, match="n_lanes"):
        SumoSettings(n_lanes=1)


@pytest.mark.parametrize("lanes", ["1", "7"])
def test_bad_lanes_is_one_line(lanes, tmp_path):
    res = runner.invoke(app, ["simulate", "--engine", "sumo", "--lanes", lanes, "--out", str(tmp_path / "x")])
    assert res.exit_code == 1 and f"--lanes {lanes}: a SUMO highway has 2 or 3 lanes" in res.output
    assert "Traceback" not in res.output and not (tmp_path / "x").exists()


def test_lanes_is_for_sumo(tmp_path):
    res = runner.invoke(app, ["simulate", "--lanes", "3", "--out", str(tmp_path / "x")])
    assert res.exit_code == 1 and "--lanes are for --engine sumo" in res.output


# --- a real three-lane study ------------------------------------------------------------


@pytest.fixture(scope="module")
def three(tmp_path_factory) -> tuple[Path, dict, Workspace]:
    from laneprint.simulator.sumo.backend import check_available

    try:
        check_available()
    except UserError as exc:
        pytest.skip(f"libsumo/traci not importable here ({exc})")
    root = tmp_path_factory.mktemp("sumo3")
    res = runner.invoke(app, ["simulate", "--out", str(root / "study"), *TINY3, "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    ws = root / "ws"
    for cmd in (["ingest", str(root / "study")], ["analyze"]):
        r = runner.invoke(app, [*cmd, "-w", str(ws), "--json"])
        assert r.exit_code == 0, r.output
    return root / "study", summary, Workspace(ws)


@pytest.mark.slow
def test_three_lane_study_changes_from_every_lane(three):
    study, summary, _ = three
    gt = json.loads((study / "ground_truth.json").read_text())
    assert gt["n_lanes"] == 3 and gt["settings"]["n_lanes"] == 3 and summary["lanes"] == 3
    assert set(summary["changes_by_lane"]) == {"0>1", "1>0", "1>2", "2>1"}  # both ways from the middle lane
    assert sum(summary["changes_by_lane"].values()) == summary["decisions"]
    readme = (study / "README.md").read_text()
    assert "--lanes 3" in readme and "three-lane road" in readme and "3 lanes" in readme
    assert summary["collisions"] == 0


@pytest.mark.slow
def test_three_lane_study_ingests_and_the_analysis_finds_every_target_lane(three):
    study, summary, ws = three
    lanes = set()
    for _, ego, traffic in ws.iter_recordings():
        lanes |= set(ego["ego_lane"].unique()) | set(traffic["lane"].unique())
    assert lanes == {0, 1, 2}
    truth = pd.DataFrame(json.loads((study / "ground_truth.json").read_text())["decisions"])
    dec = ws.read_table("analysis", "decisions")
    presses = dec[dec["label"] == "change"][["session_id", "press_t_s", "ego_lane", "target_lane"]]
    m = truth.merge(presses, on="session_id", suffixes=("", "_found"))
    m = m[np.isclose(m["press_t_s"], m["press_t_s_found"], atol=1e-6)]
    assert len(m) == len(truth) == len(presses) == summary["decisions"]
    assert (m["ego_lane"] == m["from_lane"]).all() and (m["target_lane_found"] == m["target_lane"]).all()
    middle = m[m["from_lane"] == 1]
    assert set(middle["target_lane"]) == {0, 2}  # presses to both sides from the middle lane
