"""Two ingests, an analysis and a training running at once on one workspace: nothing
duplicated, nothing lost, and `laneprint check` finds the workspace whole."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ingest.pipeline import ingest_paths
from laneprint.app.check import check_workspace
from laneprint.workspace import Workspace, content_id
from rl.runs import read_metrics

SAMPLE = Path(__file__).resolve().parents[2] / "sample_logs"


def _laneprint(*args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "laneprint.app.cli", *args, "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


@pytest.mark.slow
def test_two_ingests_an_analysis_and_a_training_at_once(tmp_path):
    base, a, b = tmp_path / "base", tmp_path / "a", tmp_path / "b"
    for d in (base, a, b):
        d.mkdir()
    for name in ("D02_S60.csv.gz", "D04_S60.csv.gz", "D06_S60.csv.gz"):
        shutil.copy(SAMPLE / name, base / name)
    shared = ["D02_S70.csv.gz", "D04_S70.csv.gz", "D06_S70.csv.gz"]  # given to both ingests
    for name in shared + ["D02_S80.csv.gz"]:
        shutil.copy(SAMPLE / name, a / name)
    for name in shared + ["D04_S80.csv.gz"]:
        shutil.copy(SAMPLE / name, b / name)
    ws = Workspace(tmp_path / "ws")
    assert ingest_paths([base], ws).counts["ingested"] == 3

    w = str(ws.root)
    procs = {
        "ingest a": _laneprint("ingest", str(a), "-w", w),
        "ingest b": _laneprint("ingest", *[str(b / n) for n in reversed(sorted(p.name for p in b.iterdir()))], "-w", w),
        "analyze": _laneprint("analyze", "-w", w),
        "train": _laneprint(
            "train",
            "--style",
            "Normal",
            "--lines",
            "paper",
            "--scenes",
            "synthetic",
            "--episodes",
            "30",
            "--checkpoint-every",
            "10",
            "--no-evaluate",
            "--run-id",
            "r",
            "-w",
            w,
        ),
    }
    outs = {k: p.communicate(timeout=240) for k, p in procs.items()}
    for k, p in procs.items():
        assert p.returncode == 0, f"{k}: {outs[k][1][-500:]}"

    counts = [json.loads(outs[k][0])["counts"] for k in ("ingest a", "ingest b")]
    assert sum(c["ingested"] for c in counts) == 5  # 3 shared + 1 own each, each stored by one of the two
    assert all(c["ingested"] + c["duplicate"] == 4 and c["rejected"] == 0 for c in counts)
    cat = ws.recordings()
    all_files = [p for d in (base, a, b) for p in d.iterdir()]
    assert sorted(cat["recording_id"]) == sorted({content_id(p.read_bytes()) for p in all_files})
    assert not cat.duplicated(["driver_id", "session_id"]).any() and len(cat) == 8

    assert json.loads(outs["analyze"][0])  # stored an analysis of what was there when it started
    assert ws.read_meta("analysis")["n_recordings"] >= 3
    status = json.loads((ws.runs_dir / "r" / "status.json").read_text())
    assert status["state"] == "done" and list(read_metrics(ws.runs_dir / "r" / "metrics.jsonl")["episode"]) == list(
        range(1, 31)
    )
    report = check_workspace(ws)
    assert report["ok"], report["findings"]
    assert not list((ws.root / ".tmp").iterdir())
