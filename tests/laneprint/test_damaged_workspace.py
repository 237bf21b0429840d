"""A workspace that cannot be written, fills up, or holds a damaged file: one line per file, the rest
of the batch tried, the report printed, nothing half written; `check --repair` truthful and able to
set a damaged recording aside in quarantine/ so that the rest of the workspace works."""

from __future__ import annotations

import errno
import json
import os
import shutil
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

import laneprint.workspace as workspace_module
from clustering.pipeline import analyze
from indicators.settings import AnalysisSettings
from tests.support.synthetic_decisions import catalogue_row
from ingest.pipeline import ingest_paths
from ingest.writers import write_csv
from laneprint.app.check import check_workspace
from laneprint.app.cli import app
from laneprint.simulator import StudySettings, simulate_study
from laneprint.workspace import Workspace
from tests.ingest.conftest import make_recording

GARBAGE = b"PAR1 this is not a parquet file at all " * 20


def _logs(folder: Path, n: int) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    meta, ego, traffic = make_recording(seconds=4.0, hz=20)
    paths = []
    for k in range(n):
        p = folder / f"log{k}.csv"
        write_csv(p, dict(meta, session_id=f"s{k}"), ego.assign(ego_x_m=ego["ego_x_m"] + k), traffic)
        paths.append(p)
    return paths


def _one_line(text: str) -> None:
    assert "Traceback" not in text and len(text.strip().splitlines()) == 1, text


def _read_only(monkeypatch):
    """Files cannot be created anywhere in the workspace (as a read-only mount; the tests may run as root,
    for whom permission bits do not hold)."""

    def refuse(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system", kwargs.get("dir"))

    monkeypatch.setattr(workspace_module.tempfile, "mkstemp", refuse)


def test_ingest_into_a_read_only_workspace_is_one_line(tmp_path, monkeypatch):
    _logs(tmp_path / "logs", 2)
    Workspace(tmp_path / "ws").ensure()
    _read_only(monkeypatch)
    out = CliRunner().invoke(app, ["ingest", str(tmp_path / "logs"), "-w", str(tmp_path / "ws")])
    assert out.exit_code == 1 and "cannot write to workspace" in out.output and "Read-only" in out.output
    _one_line(out.output)


def test_analyze_in_a_read_only_workspace_is_one_line(tmp_path, monkeypatch):
    ws = Workspace(tmp_path / "ws")
    ingest_paths(_logs(tmp_path / "logs", 2), ws)
    _read_only(monkeypatch)
    out = CliRunner().invoke(app, ["analyze", "-w", str(ws.root), "--json"])
    assert out.exit_code == 1 and "cannot write to workspace" in out.output
    _one_line(out.output)


def test_a_write_error_of_the_machine_is_one_line_in_any_command(tmp_path, monkeypatch):
    ws = Workspace(tmp_path / "ws")
    ingest_paths(_logs(tmp_path / "logs", 2), ws)

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(ws.root / "analysis"))

    monkeypatch.setattr(Workspace, "write_tables", full)
    out = CliRunner().invoke(app, ["analyze", "-w", str(ws.root), "--json"])
    assert out.exit_code == 1 and "No space left on device" in out.output
    _one_line(out.output)


def test_disk_full_on_the_fourth_file_the_rest_are_tried_and_reported(tmp_path, monkeypatch):
    _logs(tmp_path / "logs", 6)
    real = workspace_module._write_parquet
    calls = {"ego": 0}

    def filling(df, path, schema):
        if isinstance(path, Path) and path.name == "ego.parquet":
            calls["ego"] += 1
            if calls["ego"] == 4:
                path.write_bytes(b"PAR1 half")  # a half-written file, then the disk is full
                raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(df, path, schema)

    monkeypatch.setattr(workspace_module, "_write_parquet", filling)
    out = CliRunner().invoke(app, ["ingest", str(tmp_path / "logs"), "-w", str(tmp_path / "ws"), "--json"])
    assert out.exit_code == 0, out.output
    res = json.loads(out.stdout)
    assert res["counts"]["ingested"] == 5 and res["counts"]["rejected"] == 1
    (bad,) = [f for f in res["files"] if f["status"] == "rejected"]
    assert Path(bad["source"]).name == "log3.csv" and "No space left on device" in bad["reason"]
    ws = Workspace(tmp_path / "ws")
    assert not (ws.recordings_dir / bad["recording_id"]).exists()  # nothing half written
    assert list((ws.root / ".tmp").iterdir()) == [] and len(ws.recordings()) == 5
    assert check_workspace(ws)["ok"]
    # the human summary is printed all the same; the file goes in once there is room
    monkeypatch.setattr(workspace_module, "_write_parquet", real)
    again = CliRunner().invoke(app, ["ingest", str(tmp_path / "logs"), "-w", str(tmp_path / "ws")])
    assert again.exit_code == 0 and "1 ingested" in again.output and "Traceback" not in again.output


# --- a damaged file among the recordings ----------------------------------------------------------

STUDY = replace(StudySettings(), n_drivers=6, speed_limits_kph=(60, 90), decisions_per_driver=12)


@pytest.fixture(scope="module")
def study_ws(tmp_path_factory):
    ws = Workspace(tmp_path_factory.mktemp("ws")).ensure()
    for meta, ego, traffic in simulate_study(STUDY, seed=5).recordings:
        ws.write_recording(catalogue_row(meta, ego, traffic), ego, traffic)
    return ws


@pytest.fixture()
def damaged(study_ws, tmp_path):
    """A copy of the study's workspace with a garbage meta.parquet and a garbage ego.parquet."""
    ws = Workspace(tmp_path / "ws")
    shutil.copytree(study_ws.root, ws.root)
    a, b = sorted(p.name for p in ws.recordings_dir.iterdir())[:2]
    (ws.recordings_dir / a / "meta.parquet").write_bytes(GARBAGE)
    (ws.recordings_dir / b / "ego.parquet").write_bytes(GARBAGE)
    return ws, a, b


@pytest.mark.slow
def test_a_garbage_parquet_is_named_and_left_out_by_ingest_analyze_and_report(damaged, tmp_path):
    ws, a, b = damaged
    assert len(ws.recordings()) == len(list(ws.recordings_dir.iterdir())) - 1
    assert f"recordings/{a}/meta.parquet" in ws.damaged
    out = CliRunner().invoke(app, ["ingest", *map(str, _logs(tmp_path / "logs", 1)), "-w", str(ws.root)])
    assert out.exit_code == 0 and "1 ingested" in out.output and "Traceback" not in out.output
    assert f"note: recordings/{a}/meta.parquet: damaged" in out.output and "quarantine/" in out.output
    result = analyze(ws, AnalysisSettings(n_bootstrap=5))
    skipped = {s["id"]: s["reason"] for s in result["skipped"]}
    assert "damaged" in skipped[f"recordings/{a}/meta.parquet"] and "cannot be read" in skipped[b]
    from dashboard.report import write_report

    written = write_report(ws, tmp_path / "r.html", assets=False, svg=False)
    assert Path(written["report"]).exists()


def test_check_repair_quarantines_the_damaged_and_says_so(damaged):
    ws, a, b = damaged
    first = check_workspace(ws)
    assert not first["ok"] and any(f["path"] == f"recordings/{a}/meta.parquet" for f in first["findings"])
    out = CliRunner().invoke(app, ["check", "-w", str(ws.root), "--repair"])
    assert "Traceback" not in out.output
    assert f"repaired: moved to quarantine/ recordings/{a}/meta.parquet" in out.output
    assert f"repaired: moved to quarantine/ recordings/{b}/ego.parquet" in out.output
    assert (ws.root / "quarantine" / "recordings" / a).is_dir() and not (ws.recordings_dir / a).exists()
    after = check_workspace(ws)
    assert after["ok"], after["findings"]
    assert ws.damaged == {} and len(ws.recordings()) == len(list(ws.recordings_dir.iterdir()))


@pytest.mark.slow
def test_a_damaged_analysis_table_is_one_line_in_the_report_and_quarantined(damaged, tmp_path):
    ws, _, _ = damaged
    check_workspace(ws, repair=True)
    analyze(ws, AnalysisSettings(n_bootstrap=5))
    (ws.root / "analysis" / "styles.parquet").write_bytes(GARBAGE)
    out = CliRunner().invoke(app, ["report", "-w", str(ws.root), "--no-assets", "--no-svg"])
    assert out.exit_code == 1 and "analysis/styles.parquet is damaged" in out.output
    _one_line(out.output)
    res = check_workspace(ws, repair=True)
    assert any(r.startswith("moved to quarantine/ analysis/styles.parquet") for r in res["repaired"])


def test_check_repair_says_what_it_could_not_remove(tmp_path, monkeypatch):
    ws = Workspace(tmp_path / "ws").ensure()
    dead = ws.root / ".tmp" / "deadbeef"
    dead.mkdir()
    (dead / "x").write_bytes(b"x")
    os.utime(dead, (0, 0))

    def refuse(path, *args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(
        shutil,
        "rmtree",
        lambda path, onerror=None, **kw: onerror(
            os.rmdir, str(path), (PermissionError, PermissionError(errno.EACCES, "Permission denied", str(path)), None)
        ),
    )
    res = check_workspace(ws, repair=True)
    assert res["repaired"] == [] and not res["ok"] and dead.exists()
    (f,) = [f for f in res["findings"] if f["path"] == ".tmp/deadbeef"]
    assert f["kind"] == "problem" and "could not be removed: Permission denied" in f["message"]
