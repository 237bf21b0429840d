"""`laneprint simulate` and `write_study`: files, formats, refusals, atomic writes."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.app.simulator.output import write_study
from laneprint.simulator import StudySettings, simulate_study

runner = CliRunner()
TINY = ["--drivers", "2", "--decisions", "4", "--seed", "5"]


def _run(*args: str):
    return runner.invoke(app, ["simulate", *args])


def test_cli_mixed_writes_each_session_once(tmp_path):
    out = tmp_path / "study"
    res = _run("--out", str(out), *TINY, "--json")
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["drivers"] == 2 and summary["recordings"] == 8 and summary["decisions"] == 8
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        [f"D01_S{v}.mcap" for v in (60, 70, 80, 90)]
        + [f"D02_S{v}.csv.gz" for v in (60, 70, 80, 90)]
        + ["README.md", "ground_truth.json"]
    )
    assert summary["bytes"] == sum(p.stat().st_size for p in out.iterdir())
    gt = json.loads((out / "ground_truth.json").read_text())
    assert gt["generator"] == "laneprint.simulator" and gt["seed"] == 5
    assert {f["path"] for f in gt["files"]} == set(names) - {"README.md", "ground_truth.json"}
    assert "laneprint simulate --out sample_logs --seed 5" in (out / "README.md").read_text()
    assert not list(tmp_path.glob(".study.tmp-*"))


def test_cli_both_and_replacing_a_previous_study(tmp_path):
    out = tmp_path / "study"
    assert _run("--out", str(out), *TINY, "--format", "both").exit_code == 0
    assert len(list((out / "csv").glob("*.csv.gz"))) == 8
    assert len(list((out / "mcap").glob("*.mcap"))) == 8
    # a previous study is replaced without --force; its files that the new one lacks go away
    res = _run("--out", str(out), *TINY, "--format", "mcap")
    assert res.exit_code == 0, res.output
    assert not (out / "csv").exists() and not (out / "mcap").exists()
    assert len(list(out.glob("*.mcap"))) == 8


def test_cli_refuses_a_foreign_folder_unless_forced(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    res = _run("--out", str(out), *TINY)
    assert res.exit_code == 1
    assert "not empty" in res.output and "--force" in res.output
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    res = _run("--out", str(out), *TINY, "--force")
    assert res.exit_code == 0
    assert (out / "notes.txt").read_text() == "keep me"
    assert (out / "ground_truth.json").exists()


def test_cli_rejects_bad_options(tmp_path):
    res = _run("--out", str(tmp_path / "x"), "--format", "parquet")
    assert res.exit_code == 1 and "unknown --format" in res.output
    res = _run("--out", str(tmp_path / "x"), "--drivers", "0")
    assert res.exit_code == 1 and "--drivers" in res.output
    assert not (tmp_path / "x").exists()


def test_a_failed_write_leaves_nothing(tmp_path, monkeypatch):
    study = simulate_study(replace(StudySettings(), n_drivers=1, decisions_per_driver=4), seed=1)
    import laneprint.app.simulator.output as output

    calls = {"n": 0}
    real = output.write_csv

    def flaky(path, meta, ego, traffic):
        calls["n"] += 1
        if calls["n"] == 2:
            raise OSError("disk full")
        real(path, meta, ego, traffic)

    monkeypatch.setattr(output, "write_csv", flaky)
    with pytest.raises(OSError):
        write_study(study, tmp_path / "s", "csv")
    assert list(tmp_path.iterdir()) == []


def test_write_study_refuses_a_file(tmp_path):
    study = simulate_study(replace(StudySettings(), n_drivers=1, decisions_per_driver=4), seed=1)
    (tmp_path / "f").write_text("x")
    with pytest.raises(UserError):
        write_study(study, tmp_path / "f")


@pytest.fixture(scope="module")
def both_formats(tmp_path_factory):
    """One driver, 26 decisions (every case), written as CSV and as MCAP."""
    out = tmp_path_factory.mktemp("sim") / "study"
    assert _run("--out", str(out), "--drivers", "1", "--decisions", "26", "--format", "both").exit_code == 0
    return out, json.loads((out / "ground_truth.json").read_text())


@pytest.mark.parametrize("kind", ["csv", "mcap"])
def test_written_logs_ingest_back_with_the_same_presses_and_indicators(
    tmp_path, both_formats, kind, indicators_at, presses
):
    """simulate -> files -> ingest -> the presses and the indicators of the ground truth."""
    from ingest.pipeline import ingest_paths
    from laneprint.workspace import Workspace

    out, gt = both_formats
    assert {d["case"] for d in gt["decisions"]} == {"clean", "slowed", "no_target_leader", "far_follower", "cancelled"}
    ws = Workspace(tmp_path / f"ws_{kind}")
    rep = ingest_paths([out / kind], ws)
    assert rep.counts["ingested"] == 4 and rep.counts["rejected"] == 0
    seen = 0
    for meta, ego, traffic in ws.iter_recordings():
        mine = [d for d in gt["decisions"] if d["session_id"] == meta["session_id"]]
        assert meta["driver_id"] == meta["session_id"][:3]
        assert presses(ego) == pytest.approx([d["press_t_s"] for d in mine], abs=1e-6)
        for d in mine:
            got = indicators_at(ego, traffic, d["press_t_s"], d["target_lane"])
            for k, key in (("t_f", "t_f_s"), ("t_nf", "t_nf_s"), ("dv_nb", "dv_nb_mps")):
                if d[key] is None:
                    assert got[k] is None
                elif d["case"] != "slowed" or k != "t_f":  # a creeping TTC is ill-conditioned after mm rounding
                    assert got[k] == pytest.approx(d[key], abs=0.02)
            seen += 1
    assert seen == 26


def test_ground_truth_reads_back_as_a_table(both_formats, tmp_path):
    from laneprint.app.simulator.output import read_ground_truth
    from laneprint.simulator import decisions_frame

    out, gt = both_formats
    again = read_ground_truth(out)
    assert again == gt
    df = decisions_frame(again)
    assert len(df) == 26
    assert {"press_t_s", "case", "line.t_f", "from_preference.dv_nb", "style", "typical"} <= set(df.columns)
    assert df["typical"].all() and df["style"].iloc[0] == "Normal"
    with pytest.raises(UserError, match="not found"):
        read_ground_truth(tmp_path)
