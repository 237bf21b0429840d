"""A run too short to learn is said before it starts (issue 23, building item 4): the estimate of
the transitions a run collects, the check, and `laneprint train` / `crossval` printing it first."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from rl.problem.env import EnvConfig
from rl.settings import DQNSettings, approach_steps, expected_transitions, learning_check
from tests.support.rl_workspaces import analysed_workspace


def test_expected_transitions_by_hand():
    # epsilon 1 throughout: a random action changes lane with probability 1/2 at each step;
    # approaches of 3 steps: 1 + 1/2 + 1/4 = 1.75 steps per episode
    s = DQNSettings(episodes=4, eps_start=1.0, eps_end=1.0)
    assert expected_transitions(s, 3) == pytest.approx(4 * 1.75)
    assert expected_transitions(s, 1) == pytest.approx(4.0)  # one-step approaches: one transition each
    # no exploration: every episode runs its approach to the end
    assert expected_transitions(DQNSettings(episodes=10, eps_start=0.0, eps_end=0.0), 7) == pytest.approx(70, rel=1e-6)


def test_approach_steps():
    recorded = EnvConfig(scenes="recorded", dt_s=0.5, replay_late_s=10.0)
    assert approach_steps(recorded, 110, 10) == (11 + 20, "the target's recorded approaches")
    assert approach_steps(recorded, 0, 0) == (None, "")
    assert approach_steps(EnvConfig(scenes="synthetic", t_f0_s=(1.0, 25.0), dt_s=0.5))[0] == 26.0


def test_check_verdicts_and_the_fewest_episodes():
    never = learning_check(DQNSettings(episodes=300), 31, "x")
    assert never.verdict == "never" and never.expected < 2000
    assert "the agent would learn nothing" in never.message and "learning starts after 2,000" in never.message
    assert f"at least about {never.needed_episodes:,} episodes (--episodes)" in never.message
    assert expected_transitions(DQNSettings(episodes=never.needed_episodes), 31) >= 2000
    assert expected_transitions(DQNSettings(episodes=never.needed_episodes - 1), 31) < 2000
    late = learning_check(DQNSettings(episodes=never.needed_episodes + 20), 31, "x")
    assert late.verdict == "late" and "near the end" in late.message
    assert learning_check(DQNSettings(episodes=10_000), 31, "x").verdict == ""
    assert learning_check(DQNSettings(episodes=300, learning_starts=500), 31, "x").verdict == ""
    assert learning_check(DQNSettings(episodes=3), None).verdict == ""  # nothing known: no check


def test_the_estimate_bounds_real_runs(tmp_path):
    """Real 300-episode runs (recorded scenes, seeds 0-2) collect no more than the estimate, and at least half."""
    ws = analysed_workspace(tmp_path)
    for seed in range(3):
        res = CliRunner().invoke(
            app,
            [
                "train",
                "--style",
                "Normal",
                "--episodes",
                "300",
                "--seed",
                str(seed),
                "--no-evaluate",
                "--run-id",
                f"r{seed}",
                "-w",
                str(tmp_path),
                "--json",
            ],
        )
        assert res.exit_code == 0, res.output
        doc = json.loads(res.stdout)
        expected = doc["learning_check"]["expected_transitions"]
        assert 0.5 * expected <= doc["env_steps"] <= expected, (seed, doc["env_steps"], expected)
    assert ws.runs_dir.is_dir()


def test_train_warns_before_the_run_starts(tmp_path, monkeypatch):
    analysed_workspace(tmp_path)
    import rl.runs

    def never_called(*args, **kwargs):
        raise AssertionError("the check comes first")

    monkeypatch.setattr(rl.runs, "train_run", never_called)
    res = CliRunner().invoke(app, ["train", "--style", "Normal", "--episodes", "300", "-w", str(tmp_path)])
    assert "Traceback" not in res.stderr
    first = res.stderr.strip().splitlines()[0]
    assert first.startswith("warning: 300 episodes make at most about"), res.stderr
    assert "the agent would learn nothing" in res.stderr and "--learning-starts" in res.stderr


def test_train_short_run_still_runs_and_a_run_that_can_learn_says_nothing(tmp_path):
    analysed_workspace(tmp_path)
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
    assert res.exit_code == 0, res.output  # warned, not refused: a smoke test or a run to resume later
    doc = json.loads(res.stdout)
    assert doc["learning_check"]["verdict"] == "never" and doc["learning_check"]["targets"] == ["style Normal"]
    assert "warning: 3 episodes make at most about" in res.stderr
    ok = CliRunner().invoke(
        app,
        [
            "train",
            "--style",
            "Normal",
            "--episodes",
            "3",
            "--learning-starts",
            "5",
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
    assert "learning_check" not in json.loads(ok.stdout) and "warning" not in ok.stderr


def test_crossval_warns_before_the_folds(tmp_path, monkeypatch):
    analysed_workspace(tmp_path)
    import rl.evaluation.crossval_store as store

    def never_called(*args, **kwargs):
        raise AssertionError("the check comes first")

    monkeypatch.setattr(store, "run_crossval", never_called)
    res = CliRunner().invoke(
        app, ["crossval", "--style", "Normal", "--folds", "2", "--episodes", "40", "-w", str(tmp_path)]
    )
    assert res.stderr.strip().startswith("warning: 40 episodes make at most about"), res.stderr
