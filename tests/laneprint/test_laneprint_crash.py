"""A few SIGKILLs of real `laneprint` processes (the harness of benchmarks/crash.py, which runs many):
killed mid-write, the workspace stays whole, the leftovers are repaired, the killed training is
shown as interrupted and resumes from its checkpoint, a re-run completes."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from ingest.pipeline import ingest_paths
from laneprint.crash_harness import Command, Context, _held_back_stored, _runs_complete, kill_once
from laneprint.workspace import Workspace

SAMPLE = Path(__file__).resolve().parents[2] / "sample_logs"


@pytest.fixture()
def base(tmp_path) -> tuple[Path, Context]:
    logs, held = tmp_path / "logs", tmp_path / "held"
    logs.mkdir()
    held.mkdir()
    for name in ("D02_S60.csv.gz", "D04_S60.csv.gz"):
        shutil.copy(SAMPLE / name, logs / name)
    shutil.copy(SAMPLE / "D01_S60.mcap", held / "D01_S60.mcap")
    ingest_paths([logs], Workspace(tmp_path / "base"))
    return tmp_path / "base", Context(held, "D02", "t")


@pytest.mark.slow
def test_a_training_killed_after_a_checkpoint_is_interrupted_then_resumed(base, tmp_path):
    train = Command(lambda c: ["train", "--style", "Normal", "--lines", "paper", "--scenes", "synthetic",
                               "--episodes", "3000", "--checkpoint-every", "5", "--no-evaluate", "--run-id", "r"],
                    _runs_complete, trains=True)
    res = kill_once("train", *base, delay_s=0.3, ws=tmp_path / "ws", timeout_s=120, cmd=train,
                    after=lambda ws: (ws / "runs" / "r" / "checkpoint.pt").exists())
    assert not res.finished_before_kill
    assert res.problems == []
    assert res.interrupted_runs == ["r"]  # by `laneprint runs` and the dashboard alike (else a problem)
    assert res.resumed["r"] >= 5  # from its checkpoint (the harness compares with checkpoint.pt), not from 0


@pytest.mark.slow
def test_an_ingest_killed_while_writing_a_recording(base, tmp_path):
    ingest = Command(lambda c: ["ingest", str(c.logs)], _held_back_stored)
    res = kill_once("ingest", *base, delay_s=0.0, ws=tmp_path / "ws", timeout_s=120, cmd=ingest,
                    after=lambda ws: any((ws / ".tmp").glob("*/*.parquet")))
    assert res.problems == []
    assert res.finished_before_kill or res.repaired >= 1  # its staging folder, removed by check --repair
