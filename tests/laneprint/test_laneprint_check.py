"""`laneprint check [--repair]`, locks that die with their process, and interrupted runs."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from ingest.pipeline import _claim_path, _session_key, ingest_paths
from laneprint.app.cli import app
from laneprint.locks import FileLock, is_locked
from laneprint.workspace import Workspace, atomic_write_json, content_id, exchange_paths, legacy_content_id

SAMPLE = Path(__file__).resolve().parents[2] / "sample_logs"
OLD = time.time() - 60  # an mtime past the creation grace


@pytest.fixture()
def ws(tmp_path) -> Workspace:
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("D02_S60.csv.gz", "D02_S70.csv.gz"):
        shutil.copy(SAMPLE / name, logs / name)
    w = Workspace(tmp_path / "ws")
    assert ingest_paths([logs], w).counts["ingested"] == 2
    return w


def _check(ws: Workspace, *args: str) -> tuple[int, dict]:
    out = CliRunner().invoke(app, ["check", "-w", str(ws.root), "--json", *args])
    return out.exit_code, json.loads(out.stdout)


def _kinds(report: dict) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for f in report["findings"]:
        out.setdefault(f["kind"], []).append(f"{f['path']}: {f['message']}")
    return out


def _old(path: Path) -> Path:
    os.utime(path, (OLD, OLD))
    return path


def test_a_whole_workspace_is_ok(ws):
    code, report = _check(ws)
    assert code == 0 and report["ok"] and report["n_recordings"] == 2 and report["findings"] == []
    human = CliRunner().invoke(app, ["check", "-w", str(ws.root)])
    assert human.exit_code == 0 and human.stdout.startswith("ok: 2 recordings")


def test_leftovers_are_reported_then_repaired_and_live_ones_kept(ws):
    rid = ws.recordings()["recording_id"].iloc[0]
    dead_dir = ws.root / ".tmp" / "deadbeef"  # a staging folder whose writer died
    dead_dir.mkdir()
    (dead_dir / "ego.parquet").write_bytes(b"PAR1 half")
    _old(dead_dir)
    dead_file = ws.recordings_dir / rid / ".meta.parquet.x1.tmp"
    dead_file.write_bytes(b"half")
    _old(dead_file)
    claim = ws.root / ".sessions" / _session_key("D09", "S1")
    claim.write_text("0123456789abcdef")  # an ingest died before storing this recording
    stale_rejection = ws.rejected_dir / f"{rid}.json"
    atomic_write_json(
        stale_rejection,
        {
            "content_hash": rid,
            "source_name": "a.csv",
            "source_path": "/a.csv",
            "format": "csv",
            "reason": "x",
            "rejected_at": "2026-11-30T00:00:00+00:00",
        },
    )
    live = ws.root / ".tmp" / "alive"
    live.mkdir()
    _old(live)
    lock = FileLock(live)
    lock.acquire()
    try:
        code, report = _check(ws)
        assert code == 1 and not report["ok"]
        leftovers = "\n".join(_kinds(report)["leftover"])
        for p in (
            ".tmp/deadbeef",
            f"recordings/{rid}/.meta.parquet.x1.tmp",
            f".sessions/{claim.name}",
            f"rejected/{rid}.json",
        ):
            assert p in leftovers
        assert ".tmp/alive: being written by a live process" in _kinds(report)["note"]

        code, report = _check(ws, "--repair")
        assert code == 0 and report["ok"] and len(report["repaired"]) == 4
        assert not dead_dir.exists() and not dead_file.exists() and not claim.exists()
        assert not stale_rejection.exists() and live.exists()
        assert len(ws.recordings()) == 2
    finally:
        lock.release()


def test_damaged_recordings_are_problems_repair_quarantines_the_unreadable(ws):
    a, b = ws.recordings()["recording_id"]
    ego = ws.recordings_dir / a / "ego.parquet"
    ego.write_bytes(ego.read_bytes()[: ego.stat().st_size // 2])  # half-written, visible
    (ws.recordings_dir / b / "traffic.parquet").unlink()
    shutil.copytree(ws.recordings_dir / b, ws.recordings_dir / "ffffffffffffffff")  # same session twice, wrong id
    human = CliRunner().invoke(app, ["check", "-w", str(ws.root)])
    assert human.exit_code == 1 and f"problem: recordings/{a}/ego.parquet: unreadable" in human.stdout
    code, report = _check(ws, "--repair")
    assert code == 1 and len(report["repaired"]) == 1
    assert report["repaired"][0].startswith(f"moved to quarantine/ recordings/{a}/ego.parquet (unreadable")
    problems = "\n".join(_kinds(report)["problem"])
    assert f"recordings/{b}/traffic.parquet: missing" in problems  # not unreadable: a person decides
    assert "recordings/ffffffffffffffff: meta says recording" in problems
    assert "is stored twice" in problems
    assert not (ws.recordings_dir / a).exists() and (ws.root / "quarantine" / "recordings" / a / "ego.parquet").exists()


def test_a_changed_source_is_a_note_and_an_older_workspace_s_ids_still_match(ws):
    cat = ws.recordings().set_index("recording_id")
    a, b = cat.index
    source = Path(cat.loc[a, "source_path"])
    assert a == content_id(source.read_bytes())
    # a recording stored by a version that named recordings by SHA-256: its source still matches
    legacy = legacy_content_id(Path(cat.loc[b, "source_path"]).read_bytes())
    meta = ws.recordings_dir / b / "meta.parquet"
    m = pd.read_parquet(meta).assign(recording_id=legacy)
    m.to_parquet(meta, index=False)
    (ws.recordings_dir / b).rename(ws.recordings_dir / legacy)
    claim = _claim_path(ws, *cat.loc[b, ["driver_id", "session_id"]])
    claim.write_text(legacy)
    source.write_bytes(source.read_bytes() + b"\n")
    code, report = _check(ws)
    assert code == 0, report["findings"]
    notes = _kinds(report)
    assert list(notes) == ["note"] and len(notes["note"]) == 1
    assert (
        notes["note"][0].startswith(f"recordings/{a}: its source")
        and "changed since it was ingested" in notes["note"][0]
    )


def test_a_lock_dies_with_its_process(tmp_path):
    path = tmp_path / "x.lock"
    code = (
        "import sys, time; from laneprint.locks import FileLock; FileLock(sys.argv[1]).acquire(); "
        "print('held', flush=True); time.sleep(60)"
    )
    proc = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        assert is_locked(path) and not FileLock(path).acquire(blocking=False)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert not is_locked(path)
    assert FileLock(path).acquire(blocking=False)


def test_exchange_swaps_two_folders(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x").write_text("a")
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "x").write_text("b")
    assert exchange_paths(tmp_path / "a", tmp_path / "b")
    assert (tmp_path / "a" / "x").read_text() == "b" and (tmp_path / "b" / "x").read_text() == "a"


def _fake_run(ws: Workspace, rid: str, state: str) -> Path:
    d = ws.runs_dir / rid
    d.mkdir(parents=True)
    atomic_write_json(
        d / "config.json",
        {
            "run_id": rid,
            "target": {"kind": "driver", "name": "D02"},
            "reward": "decisions",
            "seed": 0,
            "dqn": {"episodes": 4},
        },
    )
    atomic_write_json(d / "status.json", {"state": state, "pid": 1, "episode": 2, "episodes": 4})
    (d / "metrics.jsonl").write_text('{"episode": 1}\n{"episode": 2}\n{"epis')  # killed mid-line
    return d


def test_a_running_status_without_its_lock_is_interrupted(ws):
    from dashboard.jobs import run_status

    d = _fake_run(ws, "r1", "running")
    runs = CliRunner().invoke(app, ["runs", "-w", str(ws.root), "--json"])
    assert runs.exit_code == 0 and json.loads(runs.stdout)["runs"][0]["state"] == "interrupted"
    st = run_status(ws, "r1")
    assert st["state"] == "interrupted" and "laneprint train --resume r1" in st["message"]
    code, report = _check(ws)
    assert code == 0, report  # interrupted is not damage: a note saying how to resume
    assert _kinds(report)["note"] == [
        "runs/r1: training interrupted at episode 2: `laneprint train --resume r1` "
        "continues from the start (no checkpoint); 1 half-written metrics line(s), "
        "dropped on resume"
    ]
    assert json.loads((d / "status.json").read_text())["state"] == "interrupted"  # the file says so too
    with FileLock(d / "run.lock"):  # a resume: it holds the lock and writes 'running'
        atomic_write_json(d / "status.json", {"state": "running", "pid": 1, "episode": 2, "episodes": 4})
        assert (
            json.loads(CliRunner().invoke(app, ["runs", "-w", str(ws.root), "--json"]).stdout)["runs"][0]["state"]
            == "running"
        )
        assert run_status(ws, "r1")["state"] == "running"
    done = _fake_run(ws, "r2", "done")
    code, report = _check(ws)
    assert code == 1 and "runs/r2: state done but no weights.pt" in "\n".join(_kinds(report)["problem"])
    shutil.rmtree(done)
    empty = ws.runs_dir / "r3"
    empty.mkdir()
    (empty / "run.lock").touch()
    code, report = _check(ws, "--repair")
    assert code == 0 and not empty.exists()


def test_check_of_a_missing_workspace_is_one_line(tmp_path):
    out = CliRunner().invoke(app, ["check", "-w", str(tmp_path / "none")])
    assert out.exit_code == 1 and "no workspace at" in out.output and "Traceback" not in out.output
