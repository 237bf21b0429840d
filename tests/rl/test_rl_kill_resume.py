"""kill -9 of `train` with each learner: the run reads 'interrupted' everywhere (`laneprint runs`, its
status.json, the dashboard), and `train --resume` ends it 'done'; the trees, deterministic, end with the
figures of an uninterrupted run."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from tests.support.rl_workspaces import FAST_CLI, analysed_workspace

# learner -> (extra options, the status message at which the process is killed)
LEARNERS = {
    "dqn": (["--learner", "dqn", "--episodes", "400", *FAST_CLI], "training"),
    "trees": (["--learner", "trees"], "fitting the tree Q functions"),
    "auto": (["--learner", "auto", "--episodes", "300"], "choosing"),
}


def _train(ws: Path, run_id: str, extra: list[str]) -> list[str]:
    return [sys.executable, "-m", "laneprint.app.cli", "train", "--style", "Normal", "--run-id", run_id,
            "-w", str(ws), "--json", *extra]


def _kill_at(cmd: list[str], status: Path, message: str, metrics: Path | None = None) -> None:
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 120
        while time.time() < deadline:
            text = status.read_text() if status.exists() else ""
            if message in text and (metrics is None or (metrics.exists() and metrics.read_text().count("\n") >= 3)):
                break
            if proc.poll() is not None:
                pytest.fail(f"the training ended before it could be killed ({text})")
            time.sleep(0.05)
        else:
            pytest.fail(f"the training never reached {message!r}")
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()


@pytest.mark.slow
@pytest.mark.parametrize("learner", list(LEARNERS))
def test_killed_run_reads_interrupted_everywhere_and_resumes_done(tmp_path, learner):
    from dashboard.jobs import run_status

    ws = analysed_workspace(tmp_path)
    extra, message = LEARNERS[learner]
    folder = tmp_path / "runs" / "k"
    _kill_at(_train(tmp_path, "k", extra), folder / "status.json", message,
             folder / "metrics.jsonl" if learner == "dqn" else None)
    assert json.loads((folder / "status.json").read_text())["state"] == "running"  # as the killed process left it
    runs = json.loads(CliRunner().invoke(app, ["runs", "-w", str(tmp_path), "--json"]).stdout)["runs"]
    assert [r["state"] for r in runs] == ["interrupted"]
    status = json.loads((folder / "status.json").read_text())
    assert status["state"] == "interrupted" and "--resume k" in status["message"]
    assert run_status(ws, "k")["state"] == "interrupted"
    checked = json.loads(CliRunner().invoke(app, ["check", "-w", str(tmp_path), "--json"]).stdout)
    assert not any(f["kind"] == "problem" for f in checked["findings"]), checked["findings"]
    again = CliRunner().invoke(app, ["train", "--resume", "k", "-w", str(tmp_path), "--json"])
    assert again.exit_code == 0, again.output
    out = json.loads(again.stdout)
    assert out["state"] == "done"
    assert json.loads((folder / "status.json").read_text())["state"] == "done"
    if learner == "trees":  # deterministic: the figures of an uninterrupted run
        whole = CliRunner().invoke(app, ["train", "--style", "Normal", "--run-id", "whole", "-w", str(tmp_path),
                                         "--json", *extra])
        assert whole.exit_code == 0, whole.output
        assert json.loads(whole.stdout)["evaluation"] == out["evaluation"]


def test_a_status_left_running_is_written_interrupted_once_its_process_is_gone(tmp_path):
    from rl.runs import RUN_LOCK, mark_interrupted
    from laneprint.locks import FileLock

    folder = tmp_path / "r"
    folder.mkdir()
    (folder / "status.json").write_text(json.dumps({"state": "running", "episode": 7}))
    live = FileLock(folder / RUN_LOCK)
    live.acquire()
    try:  # a live trainer: left alone
        assert mark_interrupted(folder, {"state": "running"})["state"] == "running"
        assert json.loads((folder / "status.json").read_text())["state"] == "running"
    finally:
        live.release()
    out = mark_interrupted(folder, {"state": "running"})
    assert out["state"] == "interrupted" and "episode 7" in out["message"]
    assert json.loads((folder / "status.json").read_text())["state"] == "interrupted"
    (folder / "status.json").write_text(json.dumps({"state": "done", "episode": 9}))
    assert mark_interrupted(folder, {"state": "running"})["state"] == "done"  # it had just finished: re-read
