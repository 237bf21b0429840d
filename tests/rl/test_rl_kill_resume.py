"""kill -9 of `train` with each learner at three moments: the run reads 'interrupted' everywhere (`laneprint
runs`, its status.json, the dashboard, `check`), and `train --resume` ends it 'done' with the figures, the
weights and the episodes of an uninterrupted run with the same seed (every learner is deterministic: the
DQN's checkpoint holds its generators, the trees and the learner choice are seeded, and the DQN `auto`
keeps is saved before the config names it).

The process is killed by the signal it would get from outside, SIGKILL, sent the moment the run writes a
chosen status (`KILLER` wraps `RunWriter.status`): the moments are exact, not a race against a sleep."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.workspace import Workspace
from rl.problem.rewards import ReferenceLines
from tests.support.rl_workspaces import FAST_CLI, analysed_workspace, session_decisions, write_style_analysis

#: `laneprint train` at several moments: a process that imports what training needs once (no torch op, no
#: thread pool yet: safe to fork), then per moment forks a child running `laneprint ARGS...` that SIGKILLs
#: itself once its run's status starts with MESSAGE at EPISODE or later (whether or not that throttled status
#: reached the file: the file keeps an older one). argv: a JSON list of [message, episode, args]; prints the
#: children's wait statuses as a JSON list.
KILLER = """
import json, os, signal, sys
import sklearn.ensemble, torch  # noqa: F401 (imported once for every child)
from rl import runs
from laneprint.app.cli import app
status = runs.RunWriter.status
codes = []
for message, episode, args in json.loads(sys.argv[1]):
    pid = os.fork()
    if pid == 0:
        def deadly(self, state, ep, text="", force=True):
            status(self, state, ep, text, force)
            if text.startswith(message) and ep >= episode:
                os.kill(os.getpid(), signal.SIGKILL)
        runs.RunWriter.status = deadly
        try:
            app(args, prog_name="laneprint")
        finally:
            os._exit(3)  # not killed: the moment never came
    _, code = os.waitpid(pid, 0)
    codes.append(os.waitstatus_to_exitcode(code))
print(json.dumps(codes))
"""

#: Small settings: checkpoints every 50 episodes (so a kill mid-training resumes from one), few trees.
SMALL = "[dqn]\ncheckpoint_every = 50\n[trees]\ntrees = 20\niterations = 4\n"

# learner -> (workspace, options, three moments (status message it starts with, episode at least))
LEARNERS = {
    # before its first checkpoint (it starts over), after two (metrics past them dropped), evaluating
    "dqn": (
        "one",
        ["--learner", "dqn", "--episodes", "150", *FAST_CLI],
        [("training", 0), ("training", 110), ("evaluating", 0)],
    ),
    # before its first Q function, half way through them, evaluating
    "trees": (
        "one",
        ["--learner", "trees"],
        [("fitting the tree Q functions", 0), ("tree Q fitted", 2), ("evaluating", 0)],
    ),
    # four sessions: inner folds, the trees chosen. As the fleet starts (the trees' inner fits beside it, in a
    # forked process that dies with the run), during the inner DQNs' training, half way through the chosen
    # trees' fit on every approach
    "auto": (
        "sessions",
        ["--learner", "auto", "--episodes", "120", *FAST_CLI],
        [("choosing the learner: training", 0), ("choosing the learner: training", 60), ("tree Q fitted", 2)],
    ),
    # one session, nothing to hold out: the DQN taken at once. While it trains (in the choice's fleet), once
    # the config names it (before its first checkpoint of the run's own), evaluating
    "auto-dqn": (
        "one",
        ["--learner", "auto", "--episodes", "120", *FAST_CLI],
        [("choosing the learner: training", 60), ("training", 0), ("evaluating", 0)],
    ),
}


def _workspace(root: Path, kind: str) -> Workspace:
    if kind == "one":
        ws = analysed_workspace(root)
    else:
        lines = ReferenceLines.paper("Normal")
        ws = Workspace(root)
        write_style_analysis(ws, session_decisions(lines, 4, 3), lines)
    (root / "small.toml").write_text(SMALL)
    return ws


def _args(root: Path, run_id: str, extra: list[str]) -> list[str]:
    return [
        "train",
        "--style",
        "Normal",
        "--run-id",
        run_id,
        "-w",
        str(root),
        "--json",
        "--config",
        str(root / "small.toml"),
        *extra,
    ]


def _same_weights(a: Path, b: Path) -> bool:
    wa, wb = torch.load(a, weights_only=True), torch.load(b, weights_only=True)
    return wa.keys() == wb.keys() and all(
        torch.equal(x, wb[k]) if isinstance(x, torch.Tensor) else x == wb[k] for k, x in wa.items()
    )


def _episodes(folder: Path) -> list[dict]:
    """metrics.jsonl without its clock."""
    path = folder / "metrics.jsonl"
    rows = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


@pytest.mark.slow
@pytest.mark.parametrize("learner", list(LEARNERS))
def test_killed_at_three_moments_each_run_reads_interrupted_and_resumes_to_the_uninterrupted_figures(tmp_path, learner):
    from dashboard.jobs import run_status

    kind, extra, moments = LEARNERS[learner]
    ws = _workspace(tmp_path, kind)
    whole = CliRunner().invoke(app, _args(tmp_path, "whole", extra))
    assert whole.exit_code == 0, whole.output
    expected = json.loads(whole.stdout)
    assert expected["state"] == "done" and expected["evaluation"]
    if learner.startswith("auto"):
        assert expected["learner_choice"]["learner"] == ("trees" if kind == "sessions" else "dqn")
    jobs = [[message, episode, _args(tmp_path, f"k{k}", extra)] for k, (message, episode) in enumerate(moments)]
    killed = subprocess.run(
        [sys.executable, "-c", KILLER, json.dumps(jobs)], capture_output=True, text=True, timeout=600
    )
    assert killed.returncode == 0, killed.stderr[-3000:]
    assert json.loads(killed.stdout.splitlines()[-1]) == [-9] * len(moments), killed.stderr[-3000:]
    for k in range(len(moments)):  # as the killed processes left them
        assert json.loads((tmp_path / "runs" / f"k{k}" / "status.json").read_text())["state"] == "running"
    for k, (message, episode) in enumerate(moments):
        run_id = f"k{k}"
        folder = tmp_path / "runs" / run_id
        runs = json.loads(CliRunner().invoke(app, ["runs", "-w", str(tmp_path), "--json"]).stdout)["runs"]
        assert {r["run_id"]: r["state"] for r in runs}[run_id] == "interrupted"
        status = json.loads((folder / "status.json").read_text())
        assert status["state"] == "interrupted" and f"--resume {run_id}" in status["message"]
        assert run_status(ws, run_id)["state"] == "interrupted"
        checked = json.loads(CliRunner().invoke(app, ["check", "-w", str(tmp_path), "--json"]).stdout)
        assert not any(f["kind"] == "problem" for f in checked["findings"]), checked["findings"]
        again = CliRunner().invoke(app, ["train", "--resume", run_id, "-w", str(tmp_path), "--json"])
        assert again.exit_code == 0, (message, again.output)
        out = json.loads(again.stdout)
        assert out["state"] == "done" and json.loads((folder / "status.json").read_text())["state"] == "done"
        assert out["evaluation"] == expected["evaluation"], (message, episode)
        assert out.get("learner_choice", {}).get("learner") == expected.get("learner_choice", {}).get("learner")
        assert _same_weights(folder / "weights.pt", tmp_path / "runs" / "whole" / "weights.pt"), (message, episode)
        assert _episodes(folder) == _episodes(tmp_path / "runs" / "whole"), (message, episode)


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
