"""`laneprint simulate --engine sumo --family acceptance`: styles that differ in the gaps they accept.

The styles' parameters ordered as docs/history/sumo.md documents them (fast), and a tiny study
(3 drivers, 1 minute a section, ~15 s: marked slow) through the real command line,
ingested. The real run needs Eclipse SUMO (skipped with the install hint otherwise).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.simulator.sumo.scenario import routes_xml
from laneprint.simulator.sumo.settings import DEFAULT_FAMILY, FAMILIES, SumoSettings, family_settings
from laneprint.simulator.sumo.styles import (
    ACCEPTANCE_STYLE_PARAMS,
    FAMILY_STYLE_PARAMS,
    STYLE_PARAMS,
    make_sumo_drivers,
)

runner = CliRunner()
TINY = ["--engine", "sumo", "--family", "acceptance", "--drivers", "3", "--minutes", "1", "--seed", "5"]
D, N, A = (ACCEPTANCE_STYLE_PARAMS[s] for s in ("Defensive", "Normal", "Aggressive"))


# --- pure parts (no SUMO needed) ------------------------------------------------------


def test_families_default_first_and_settings_per_family():
    assert FAMILIES[0] == DEFAULT_FAMILY == "ttc" and "acceptance" in FAMILIES
    assert family_settings() == SumoSettings()
    acc = family_settings("acceptance")
    assert acc.family == "acceptance" and acc.car_follow_model == "IDM" and acc.ahead_streams == ("slow",)
    assert family_settings("acceptance", minutes=2).minutes == 2
    # gap-waiting drivers press a third as often: their studies drive three times as long by default
    assert (family_settings("ttc").minutes, family_settings("acceptance").minutes) == (5.0, 15.0)
    assert family_settings("acceptance", 3).minutes == 15.0
    with pytest.raises(ValueError, match="unknown family"):
        family_settings("nope")
    assert FAMILY_STYLE_PARAMS["ttc"] is STYLE_PARAMS and FAMILY_STYLE_PARAMS["acceptance"] is ACCEPTANCE_STYLE_PARAMS


def test_acceptance_styles_differ_in_what_they_accept_as_documented():
    assert set(D) == set(N) == set(A)
    # headways and standstill gaps they keep: Defensive longest, Aggressive shortest (docs/history/sumo.md's table)
    assert D["tau"] >= 1.8 * N["tau"] and N["tau"] >= 1.8 * A["tau"]
    assert D["minGap"] > N["minGap"] > A["minGap"]
    # gaps they accept: lcAssertive divides the safe gaps, so larger accepts shorter ones
    assert D["lcAssertive"] < N["lcAssertive"] < A["lcAssertive"]
    # desired speed and the IDM braking they accept
    assert D["speedFactor"] < N["speedFactor"] < A["speedFactor"]
    assert D["decel"] < N["decel"] < A["decel"] and D["accel"] < N["accel"] < A["accel"]
    assert D["lcKeepRight"] >= N["lcKeepRight"] and D["lcCooperative"] > N["lcCooperative"] > A["lcCooperative"]
    # what sets the ttc family's times to collision is left at SUMO's defaults here
    assert not {"lcSpeedGainLookahead", "lcKeepRightAcceptanceTime", "sigma"} & set(D)


def test_acceptance_drivers_are_seeded_and_keep_their_styles_order():
    a = make_sumo_drivers(9, 0.1, np.random.default_rng(4), "acceptance")
    assert a == make_sumo_drivers(9, 0.1, np.random.default_rng(4), "acceptance")
    assert a[0].params == D and a[1].params == N and a[2].params == A
    tau = {s: [d.params["tau"] for d in a if d.style == s] for s in ("Defensive", "Normal", "Aggressive")}
    assert min(tau["Defensive"]) > max(tau["Normal"]) and min(tau["Normal"]) > max(tau["Aggressive"])


def test_routes_carry_the_family_car_following_model():
    assert 'carFollowModel="IDM"' in routes_xml(D, family_settings("acceptance"))
    assert 'carFollowModel="Krauss"' in routes_xml(STYLE_PARAMS["Normal"], SumoSettings())


@pytest.mark.parametrize(
    "args, message",
    [
        (["--engine", "sumo", "--family", "nope"], "error: unknown --family 'nope'; choose one of ttc, acceptance"),
        (["--family", "acceptance"], "--family"),  # "error: --minutes, ..., --family ... are for --engine sumo"
    ],
)
def test_bad_family_is_one_line(tmp_path, args, message):
    res = runner.invoke(app, ["simulate", "--out", str(tmp_path / "x"), *args])
    text = res.output.replace("\n", " ")
    assert res.exit_code != 0 and "Traceback" not in text and text.startswith("error: ")
    assert message in text and ("are for --engine sumo" in text or "unknown --family" in text)
    assert not (tmp_path / "x").exists()


# --- a real run -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> tuple[Path, dict]:
    from laneprint.simulator.sumo.backend import check_available

    try:
        check_available()
    except UserError as exc:
        pytest.skip(f"libsumo/traci not importable here ({exc})")
    out = tmp_path_factory.mktemp("sumo_acc") / "study"
    res = runner.invoke(app, ["simulate", "--out", str(out), *TINY, "--json"])
    assert res.exit_code == 0, res.output
    return out, json.loads(res.stdout)


@pytest.mark.slow
def test_cli_writes_an_acceptance_study(study):
    out, summary = study
    assert summary["engine"] == "sumo" and summary["family"] == "acceptance" and summary["recordings"] == 12
    gt = json.loads((out / "ground_truth.json").read_text())
    assert gt["family"] == "acceptance" and gt["car_follow_model"] == "IDM"
    assert gt["settings"]["family"] == "acceptance" and gt["style_params"] == ACCEPTANCE_STYLE_PARAMS
    assert [d["sumo_params"] for d in gt["drivers"]] == [D, N, A]
    assert len(gt["decisions"]) == summary["decisions"] > 0
    readme = (out / "README.md").read_text()
    assert "--family acceptance" in readme and "IDM car following" in readme


@pytest.mark.slow
def test_acceptance_logs_ingest(study, tmp_path):
    res = runner.invoke(app, ["ingest", str(study[0]), "--workspace", str(tmp_path / "ws"), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["counts"]["rejected"] == 0 and out["counts"]["ingested"] + out["counts"]["warning"] == 12
    warned = [f for f in out["files"] if f["status"] == "warning"]  # a 1-minute section may hold no press
    assert all(
        f["n_presses"] == 0 and len(f["warnings"]) == 1 and "no lane-change button presses" in f["warnings"][0]
        for f in warned
    )
    assert sum(f["n_presses"] for f in out["files"]) == study[1]["decisions"]
