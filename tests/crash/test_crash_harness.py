"""A few SIGKILLs of real `laneprint` processes (the harness of benchmarks/crash.py, which runs many):
killed mid-write, the workspace stays whole, the leftovers are repaired, the killed training is
shown as interrupted and resumes from its checkpoint, a re-run completes."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

from ingest.pipeline import ingest_paths
from crash_harness import (
    Command,
    Context,
    _held_back_stored,
    _runs_complete,
    kill_live,
    kill_once,
    plan_kill,
    run_until,
)
from laneprint.workspace import Workspace

SAMPLE = Path(__file__).resolve().parents[2] / "sample_logs"
BURN = [sys.executable, "-c", "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.6: pass"]


def test_a_process_is_killed_once_it_has_used_the_cpu_time_drawn():
    res = run_until(BURN, at_cpu_s=0.3)
    assert not res.finished and res.returncode == -9  # SIGKILLed, live
    assert 0.3 <= res.cpu_s < 0.6
    done = run_until(BURN, at_cpu_s=float("inf"))
    assert done.finished and done.returncode == 0 and done.cpu_s >= 0.6


def test_an_attempt_that_finishes_first_is_redrawn_from_its_own_measurement():
    """An estimate far too long (the machine was busier, or the command does less): the first attempt
    finishes, is not a kill, and the next moment, drawn from its measured CPU time, hits it live."""
    attempts = []

    def start(at: float):
        attempts.append(run_until(BURN, at))
        return attempts[-1]

    last, fraction, work, early = kill_live(start, np.random.default_rng(0), 0.0, work_s=30.0)
    assert [a.finished for a in attempts] == [True, False] and early == 1
    assert not last.finished and 0.6 <= work < 2.0  # the fresh measurement
    assert last.cpu_s == pytest.approx(fraction * work, abs=0.1)  # at its drawn moment (0.02 s polls)


def test_kill_moments_are_seeded_and_inside_the_work():
    draws = [plan_kill(np.random.default_rng([11, i]), 1.0, 5.0) for i in range(50)]
    assert draws == [plan_kill(np.random.default_rng([11, i]), 1.0, 5.0) for i in range(50)]
    assert all(0.05 <= f <= 0.95 and at == pytest.approx(1.0 + 4.0 * f) for f, at in draws)


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
    # 10000 episodes: 3000 could all run (about 2 s of CPU) before the poll saw the first checkpoint
    train = Command(
        lambda c: [
            "train",
            "--style",
            "Normal",
            "--lines",
            "paper",
            "--scenes",
            "synthetic",
            "--episodes",
            "10000",
            "--checkpoint-every",
            "5",
            "--no-evaluate",
            "--run-id",
            "r",
        ],
        _runs_complete,
        trains=True,
    )
    res = kill_once(
        "train",
        *base,
        at_cpu_s=0.0,
        ws=tmp_path / "ws",
        timeout_s=120,
        cmd=train,
        after=lambda ws: (ws / "runs" / "r" / "checkpoint.pt").exists(),
    )
    assert not res.finished_before_kill
    assert res.problems == []
    assert res.interrupted_runs == ["r"]  # by `laneprint runs` and the dashboard alike (else a problem)
    assert res.resumed["r"] >= 5  # from its checkpoint (the harness compares with checkpoint.pt), not from 0


@pytest.mark.slow
def test_an_ingest_killed_while_writing_a_recording(base, tmp_path):
    ingest = Command(lambda c: ["ingest", str(c.logs)], _held_back_stored)
    res = kill_once(
        "ingest",
        *base,
        at_cpu_s=0.0,
        ws=tmp_path / "ws",
        timeout_s=120,
        cmd=ingest,
        after=_writing_a_recording,
    )
    assert res.problems == []
    assert res.finished_before_kill or res.repaired >= 1  # its staging folder, removed by check --repair


def _writing_a_recording(ws) -> bool:
    """Whether a staging folder of `ws` holds a table yet; the ingest may move the folder away while it is
    listed (a race of the test's probe, not of the ingest)."""
    try:
        return any((ws / ".tmp").glob("*/*.parquet"))
    except FileNotFoundError:
        return False
