"""Run folders and the `train` / `evaluate` commands, including SIGTERM and resume."""

import json
import signal
import subprocess
import sys
import time

import pytest
import torch
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.workspace import Workspace
from rl.learners.dqn import q_network
from rl.plots import decision_agreement, indicators_at_decisions, training_curves
from rl.runs import Target, list_runs, load_run, replay_env
from tests.support.rl_workspaces import FAST_CLI as FAST, analysed_workspace


def test_train_needs_an_analysis_or_paper_lines(tmp_path):
    res = CliRunner().invoke(app, ["train", "--style", "Normal", "-w", str(tmp_path)])
    assert res.exit_code == 1
    assert "run `laneprint analyze` first or pass --lines paper" in res.output


def test_train_with_paper_lines_writes_the_run_folder(tmp_path):
    res = CliRunner().invoke(
        app,
        [
            "train",
            "--style",
            "Normal",
            "--lines",
            "paper",
            "--episodes",
            "150",
            "--run-id",
            "r1",
            "-w",
            str(tmp_path),
            "--json",
            "--average-from",
            "0.2",
            *FAST,
        ],
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["run_id"] == "r1" and out["state"] == "done"
    run = load_run(Workspace(tmp_path), "r1")
    assert run["status"]["state"] == "done" and run["status"]["episode"] == 150
    assert list(run["metrics"]["episode"]) == list(range(1, 151))
    assert {"loss", "mean_step_reward", "epsilon", "length", "changed", "return", "env_steps", "wall_s"} <= set(
        run["metrics"].columns
    )
    cfg = run["config"]
    assert cfg["lines"]["source"] == "Table 1 (Normal)" and cfg["reward"] == "timing" and cfg["seed"] == 0
    assert cfg["dqn"]["average_from"] == 0.2 and cfg["dqn"]["num_envs"] == 8
    assert "git_commit" in cfg["code_version"] and len(cfg["data_fingerprint"]) == 16
    net = q_network()
    net.load_state_dict(torch.load(run["folder"] / "weights.pt", weights_only=True))
    assert "analyze" in out["evaluation_note"]  # nothing to evaluate against yet
    runs = list_runs(Workspace(tmp_path))
    assert runs.loc[0, "run_id"] == "r1" and runs.loc[0, "state"] == "done"
    assert training_curves(run["metrics"]).data
    res = CliRunner().invoke(
        app, ["train", "--style", "Normal", "--lines", "paper", "--run-id", "r1", "-w", str(tmp_path)]
    )
    assert res.exit_code == 1 and "exists already" in res.output
    res = CliRunner().invoke(
        app, ["train", "--style", "Normal", "--lines", "paper", "--average-from", "2", "-w", str(tmp_path)]
    )
    assert res.exit_code == 1 and "average_from must be in [0, 1]" in res.output  # refused before training


def test_evaluate_against_the_drivers(tmp_path):
    ws = analysed_workspace(tmp_path)
    res = CliRunner().invoke(
        app,
        [
            "train",
            "--style",
            "Normal",
            "--episodes",
            "100",
            "--run-id",
            "r2",
            "--no-evaluate",
            "-w",
            str(tmp_path),
            *FAST,
        ],
    )
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(app, ["evaluate", "r2", "-w", str(tmp_path), "--json"])
    assert res.exit_code == 0, res.output
    ev = json.loads(res.stdout)
    assert ev["typical_driver"] == "D01" and ev["n_decisions_typical"] == 12
    rows = {r["who"]: r for r in ev["summary_typical"]}
    assert set(rows) == {"agent", "greedy", "imitation", "driver"}
    assert rows["driver"]["recall"] == 1.0 and rows["driver"]["timing_mae_s"] == 0.0
    assert 0.0 <= rows["agent"]["balanced_accuracy"] <= 1.0
    run = load_run(ws, "r2")
    assert len(run["eval_states"]) == ev["n_states_members"]
    assert indicators_at_decisions(run["eval_changes"], run["config"]["lines"]).data
    assert decision_agreement(run["eval_states"]).data
    assert CliRunner().invoke(app, ["evaluate", "nope", "-w", str(tmp_path)]).exit_code == 1
    env = replay_env(ws, Target("style", "Normal"))
    assert len(env.approaches) == 12
    obs, info = env.reset(seed=0, options={"approach": 3})
    assert info["decision_id"] == env.approaches[3].decision_id and info["recorded"]


@pytest.mark.slow
def test_sigterm_cancels_cleanly_and_resume_finishes(tmp_path):
    cmd = [
        sys.executable,
        "-m",
        "laneprint.app.cli",
        "train",
        "--style",
        "Normal",
        "--lines",
        "paper",
        "--episodes",
        "10000000",
        "--run-id",
        "sig",
        "-w",
        str(tmp_path),
        "--json",
        *FAST,
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    metrics = tmp_path / "runs" / "sig" / "metrics.jsonl"
    deadline = time.time() + 60
    while time.time() < deadline and not (metrics.exists() and metrics.stat().st_size > 300):
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    assert json.loads(stdout)["state"] == "cancelled"
    status = json.loads((tmp_path / "runs" / "sig" / "status.json").read_text())
    assert status["state"] == "cancelled" and status["pid"] == proc.pid
    assert (tmp_path / "runs" / "sig" / "checkpoint.pt").exists()
    done = status["episode"]
    res = CliRunner().invoke(
        app, ["train", "--resume", "sig", "--episodes", str(done + 40), "-w", str(tmp_path), "--json"]
    )
    assert res.exit_code == 0, res.output
    run = load_run(Workspace(tmp_path), "sig")
    assert run["status"]["state"] == "done"
    assert list(run["metrics"]["episode"]) == list(range(1, done + 41))


def test_a_run_too_short_to_learn_says_so(tmp_path):
    import json as _json

    from typer.testing import CliRunner

    from laneprint.app.cli import app

    res = CliRunner().invoke(
        app,
        [
            "train",
            "--style",
            "Normal",
            "--lines",
            "paper",
            "--episodes",
            "3",
            "--no-evaluate",
            "--run-id",
            "short",
            "-w",
            str(tmp_path),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    doc = _json.loads(res.stdout)
    assert doc["warning"].startswith("the agent never learnt") and "--learning-starts" in doc["warning"]
    ok = CliRunner().invoke(
        app,
        [
            "train",
            "--style",
            "Normal",
            "--lines",
            "paper",
            "--episodes",
            "3",
            "--learning-starts",
            "10",
            "--batch-size",
            "8",
            "--no-evaluate",
            "--run-id",
            "learns",
            "-w",
            str(tmp_path),
            "--json",
        ],
    )
    assert ok.exit_code == 0, ok.output
    assert "warning" not in _json.loads(ok.stdout)
