"""`analyze` on a real workspace and `laneprint analyze` end to end."""

import json
from dataclasses import replace

import pytest
from typer.testing import CliRunner

from rich.console import Console

from clustering.cli import render
from clustering.pipeline import analyze
from indicators.settings import AnalysisSettings
from indicators.stats import INDICATORS
from tests.support.synthetic_decisions import catalogue_row, make_recording
from laneprint.app.cli import app
from laneprint.simulator import StudySettings, simulate_study
from laneprint.workspace import Workspace

STUDY = replace(StudySettings(), n_drivers=6, speed_limits_kph=(60, 90), decisions_per_driver=16)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    ws = Workspace(tmp_path_factory.mktemp("ws")).ensure()
    study = simulate_study(STUDY, seed=3)
    for meta, ego, traffic in study.recordings:
        ws.write_recording(catalogue_row(meta, ego, traffic), ego, traffic)
    # a recording without any press
    meta, ego, traffic = make_recording(
        10, 10, 20.0, [(0, 0)], vehicles=[("A", 60, 15, 0, 4.5)], recording_id="nopress0000000000", driver_id="D01"
    )
    ws.write_recording(catalogue_row(meta, ego, traffic), ego, traffic)
    return ws, study


@pytest.fixture(scope="module")
def report(workspace):
    return analyze(workspace[0], AnalysisSettings(n_bootstrap=20))


def test_analyze_writes_stage_and_report(workspace, report):
    ws, study = workspace
    for name in ("decisions", "correlations", "fits", "styles", "reference_lines", "skipped"):
        assert ws.has_table("analysis", name)
    meta = ws.read_meta("analysis")
    assert meta["data_fingerprint"] == ws.fingerprint()
    # what the analysis decided, as every result records it (issue 48); the same hashed from the stored tables
    from laneprint.workspace import analysis_fingerprint

    stored = {n: ws.read_table("analysis", n) for n in ("styles", "reference_lines")}
    assert meta["analysis_fingerprint"] == ws.analysis_fingerprint() == analysis_fingerprint(stored)
    assert report["analysis_fingerprint"] == meta["analysis_fingerprint"]
    assert meta["settings"]["far_follower_m"] == 100.0 and meta["code"]["version"]
    assert set(report["drivers"]) == {d["driver_id"] for d in study.ground_truth["drivers"]}
    assert report["summary"]["n_presses"] == 6 * 16
    skipped = ws.read_table("analysis", "skipped")
    assert ((skipped["what"] == "recording") & (skipped["id"] == "nopress0000000000")).any()
    refs = ws.read_table("analysis", "reference_lines")
    for style in report["styles"]:  # noqa: B007 - read by the query string (@style)
        assert len(
            refs.query("scope == 'style' and kind == 'typical' and name == @style and direction == 'both'")
        ) == len(INDICATORS)
    assert set(report["styles"]) <= {"Defensive", "Normal", "Aggressive"}
    truth = {d["driver_id"]: d["style"] for d in study.ground_truth["drivers"]}
    assert {d: info["style"] for d, info in report["drivers"].items()} == truth
    json.dumps(report)  # JSON-ready


@pytest.mark.slow
def test_cli_json(workspace):
    ws, _ = workspace
    res = CliRunner().invoke(
        app,
        [
            "analyze",
            "-w",
            str(ws.root),
            "--json",
            "--far-follower-m",
            "120",
            "--choose-k",
            "silhouette",
            "--extrapolate-features",
        ],
    )
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["settings"]["far_follower_m"] == 120.0 and doc["settings"]["choose_k"] == "silhouette"
    assert doc["settings"]["feature_extrapolate"] is True
    assert "drivers" in doc and "styles" in doc and "skipped" in doc


def test_human_summary(workspace, report):
    ws, _ = workspace
    console = Console(record=True, width=100)
    render(report, console)
    text = console.export_text()
    assert "analysis of 6 driver(s): 96 presses" in text
    assert "typical" in text and f"stored in {ws.root}/analysis" in text


def test_cli_errors_are_one_line(tmp_path):
    runner = CliRunner()
    empty = runner.invoke(app, ["analyze", "-w", str(tmp_path / "ws")])
    assert empty.exit_code == 1
    assert empty.stderr.strip().count("\n") == 0
    assert "no recordings in workspace" in empty.stderr and "laneprint ingest" in empty.stderr
    bad = runner.invoke(app, ["analyze", "-w", str(tmp_path / "ws"), "--choose-k", "elbow"])
    assert bad.exit_code == 1 and "--choose-k" in bad.stderr


def test_workspace_without_any_press_completes(tmp_path):
    ws = Workspace(tmp_path / "ws").ensure()
    meta, ego, traffic = make_recording(
        10, 10, 20.0, [(0, 0)], vehicles=[("A", 60, 15, 0, 4.5)], recording_id="nopress", driver_id="D07"
    )
    ws.write_recording(catalogue_row(meta, ego, traffic), ego, traffic)
    report = analyze(ws)
    assert report["drivers"]["D07"]["style"] == "unassigned"
    assert report["drivers"]["D07"]["fits"][0]["reason"] == "no presses"
    reasons = {(r["what"], r["id"]): r["reason"] for r in report["skipped"]}
    assert reasons[("recording", "nopress")] == "no lane-change button presses"
    assert reasons[("driver", "D07")] in ("no style: no presses", "no decisions in any recording")
    assert len(ws.read_table("analysis", "decisions")) == 0


def test_a_recording_whose_following_cannot_be_read_keeps_its_decisions(workspace, tmp_path, monkeypatch):
    import clustering.pipeline as pipeline

    ws = workspace[0]
    full = ws.read_table("analysis", "decisions")
    calls = []

    def broken_once(meta, ego, traffic, settings):
        calls.append(meta["recording_id"])
        if len(calls) == 1:
            raise ValueError("a broken traffic table")
        return real(meta, ego, traffic, settings)

    real = pipeline.following_episodes
    monkeypatch.setattr(pipeline, "following_episodes", broken_once)
    decisions, skipped, n_rec, following = pipeline.extract_all(ws, AnalysisSettings())
    assert len(decisions) == len(full)  # every recording's decisions, the broken one's too
    assert [s["reason"] for s in skipped if s["id"] == calls[0]] == [
        "steady-following extraction failed: ValueError: a broken traffic table"
    ]
    assert calls[0] not in set(following["recording_id"]) and n_rec == len(calls)


@pytest.mark.slow
def test_heldout_reading_end_to_end(workspace, tmp_path):
    """`--features heldout`: the reading chosen on held-out behaviour, stored with its scores; each
    driver's behaviour parameters with intervals; every style described; confidence capped by
    the rule of succession; the human summary shows the choice and the descriptions."""
    ws, study = workspace
    res = CliRunner().invoke(app, ["analyze", "-w", str(ws.root), "--features", "heldout", "--json"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.stdout)
    feats = rep["summary"]["features"]
    assert feats["requested"] == "heldout"
    cands = {c["name"]: c for c in feats["candidates"]}
    assert any(n.startswith("behaviour:") for n in cands) and sum(c["chosen"] for c in cands.values()) == 1
    assert all(c["heldout_ll"] is not None and c["heldout_ll"] < 0 for c in cands.values())
    assert set(rep["summary"]["style_descriptions"]) == set(rep["styles"])
    assert all(" s" in t or " m" in t for t in rep["summary"]["style_descriptions"].values())
    for info in rep["drivers"].values():
        assert info["confidence"] <= (info["n_decisions"] + 1) / (info["n_decisions"] + 2) + 1e-9
    beh = ws.read_table("analysis", "behaviour")
    ok = beh[(beh["informed_by"] > 0) & beh["value"].notna()]
    assert len(ok) and ((ok["lo"] <= ok["value"]) & (ok["value"] <= ok["hi"])).all()
    text = CliRunner().invoke(app, ["analyze", "-w", str(ws.root), "--features", "heldout"]).stdout
    assert "held-out log-likelihood" in text and "Defensive:" in text


def test_unknown_behaviour_parameter_is_one_line(workspace):
    res = CliRunner().invoke(app, ["analyze", "-w", str(workspace[0].root), "--features", "behaviour:wrong"])
    assert res.exit_code == 1 and "unknown behaviour parameter" in res.output and "Traceback" not in res.output


@pytest.mark.slow
@pytest.mark.parametrize("features", ["consensus", "separated", "reliable"])
def test_chosen_readings_end_to_end(workspace, features):
    """`--features consensus|separated|reliable` run through the command line: one chosen reading, stored with
    its scores, every driver with a style or a reason."""
    ws, _ = workspace
    res = CliRunner().invoke(app, ["analyze", "-w", str(ws.root), "--features", features, "--json"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.stdout)
    feats = rep["summary"]["features"]
    assert feats["requested"] == features
    assert sum(c["chosen"] for c in feats["candidates"]) == 1
    assert set(rep["summary"]["style_descriptions"]) == set(rep["styles"])
    text = CliRunner().invoke(app, ["analyze", "-w", str(ws.root), "--features", features]).stdout
    assert "chosen by the data" in text
