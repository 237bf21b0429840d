"""Fleet training: batched agents learn what they would alone, in ordinary run folders, and resume."""

import json
from dataclasses import replace
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
import torch
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.workspace import Workspace
from rl.learners.dqn import DQNTrainer
from rl.problem.env import EnvConfig, approaches_from_decisions, formulation_config
from rl.fleet.batch import FleetMember, FleetTrainer
from rl.fleet.runs import read_fleet
from rl.problem.rewards import ReferenceLines
from rl.runs import load_run
from rl.settings import DQNSettings
from tests.support.rl_workspaces import rule_driver_decisions

STYLES = {"D01": "Defensive", "D02": "Aggressive"}
FAST = ["--num-envs", "8", "--batch-size", "64", "--learning-starts", "200"]


def _members(n_agents: int = 3, episodes: int = 200) -> list[FleetMember]:
    members = []
    for i, style in enumerate(["Defensive", "Normal", "Aggressive"][:n_agents]):
        lines = ReferenceLines.paper(style)
        approaches, _ = approaches_from_decisions(rule_driver_decisions(lines, 20, seed=i))
        settings = DQNSettings(
            episodes=episodes + 50 * i,
            episodes_per_approach=0,
            learning_starts=200,
            seed=i,
            checkpoint_every=0,
            num_envs=8,
            batch_size=64,
        )
        members.append(FleetMember(formulation_config(lines, "decisions"), settings, approaches))
    return members


def test_fleet_agents_compute_what_they_would_alone():
    members = _members()
    alone = [DQNTrainer(m.env_config, m.settings, m.approaches).train() for m in members]
    finished = {}
    FleetTrainer(members).train(on_finish=lambda i, policy, state: finished.__setitem__(i, (policy, state)))
    for i, trainer in enumerate(alone):
        policy, state = finished[i]
        assert state["counters"]["episodes_done"] == trainer.episodes_done  # agents of different lengths
        assert state["counters"]["updates"] == trainer.updates and state["counters"]["averaging"]
        for key, value in trainer.policy_net.state_dict().items():
            torch.testing.assert_close(policy[key], value, rtol=0, atol=1e-4)


def test_a_fleet_agents_checkpoint_resumes_alone():
    members = _members(2, episodes=120)
    states = {}
    FleetTrainer(members).train(on_finish=lambda i, policy, state: states.__setitem__(i, state))
    m = members[1]
    trainer = DQNTrainer(m.env_config, m.settings, m.approaches)
    trainer.load_state_dict(states[1])
    assert trainer.episodes_done == m.settings.episodes and trainer.optimizer.state_dict()["state"]
    trainer.settings = replace(m.settings, episodes=m.settings.episodes + 20)
    trainer.train()
    assert trainer.episodes_done == m.settings.episodes + 20


def analysed_two_drivers(root) -> Workspace:
    """Two rule-following drivers of different styles, each its own lines (a hand-made analysis)."""
    ws = Workspace(root).ensure()
    decisions, refs, styles = [], [], []
    for i, (driver, style) in enumerate(STYLES.items()):
        lines = ReferenceLines.paper(style)
        decisions.append(
            rule_driver_decisions(lines, 24, seed=i, cfg=EnvConfig(lines=lines), driver_id=driver).assign(
                decision_id=lambda d, p=driver: p + ":" + d["decision_id"]
            )
        )
        for scope, name in (("driver", driver), ("style", style)):
            refs += [
                {
                    "scope": scope,
                    "name": name,
                    "kind": "typical" if scope == "style" else "driver",
                    "indicator": k,
                    "A": a,
                    "b": b,
                    "A_lo": None,
                    "A_hi": None,
                    "b_lo": None,
                    "b_hi": None,
                    "r2": None,
                    "n": 24,
                    "source": f"{driver}",
                }
                for k, (a, b) in (("t_f", lines.t_f), ("t_nf", lines.t_nf), ("dv_nb", lines.dv_nb))
            ]
        styles.append({"driver_id": driver, "style": style, "is_typical": True})
    ws.write_tables(
        "analysis",
        {
            "decisions": pd.concat(decisions, ignore_index=True),
            "reference_lines": pd.DataFrame(refs),
            "styles": pd.DataFrame(styles),
        },
        meta={},
    )
    return ws


@pytest.mark.slow
def test_fleet_of_every_driver_learns_in_ordinary_run_folders(tmp_path):
    ws = analysed_two_drivers(tmp_path)
    res = CliRunner().invoke(
        app, ["train", "--drivers", "all", "--episodes", "1200", "-w", str(tmp_path), "--json", *FAST]
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    fleet = read_fleet(ws, out["fleet_id"])
    assert fleet["state"] == "done" and len(fleet["runs"]) == 2
    for run_id, summary in zip(fleet["runs"], out["summaries"]):
        run = load_run(ws, run_id)
        assert run["config"]["fleet_id"] == out["fleet_id"] and run["status"]["state"] == "done"
        assert list(run["metrics"]["episode"]) == list(range(1, 1201)) and run["has_weights"]
        rows = {r["who"]: r for r in run["evaluation"]["summary"]}
        assert rows["agent"]["recall"] >= 0.95, (run_id, rows)
        assert rows["agent"]["balanced_accuracy"] > rows["greedy"]["balanced_accuracy"], (run_id, rows)
        assert summary["state"] == "done"
    # each agent is an ordinary run: `evaluate` works on it
    res = CliRunner().invoke(app, ["evaluate", fleet["runs"][0], "-w", str(tmp_path), "--json"])
    assert res.exit_code == 0, res.output


def test_fleet_needs_known_targets(tmp_path):
    analysed_two_drivers(tmp_path)
    res = CliRunner().invoke(app, ["train", "--drivers", "D01,D09", "-w", str(tmp_path)])
    assert res.exit_code == 1 and "unknown driver(s) D09" in res.output
    res = CliRunner().invoke(app, ["train", "--drivers", "all", "--style", "Normal", "-w", str(tmp_path)])
    assert res.exit_code == 1 and "exactly one of" in res.output


@pytest.mark.slow
def test_a_killed_fleet_resumes(tmp_path):
    ws = analysed_two_drivers(tmp_path)
    cmd = [
        sys.executable,
        "-m",
        "laneprint.app.cli",
        "train",
        "--drivers",
        "all",
        "--episodes",
        "400",
        "--checkpoint-every",
        "50",
        "--run-id",
        "f1",
        "-w",
        str(tmp_path),
        "--json",
        *FAST,
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    checkpoints = [tmp_path / "runs" / f"f1-{d.lower()}-s0" / "checkpoint.pt" for d in STYLES]
    deadline = time.time() + 120
    while time.time() < deadline and not all(p.exists() for p in checkpoints):
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert all(p.exists() for p in checkpoints), proc.stderr.read()
    assert read_fleet(ws, "f1")["state"] == "running"  # as the killed process left it
    res = CliRunner().invoke(app, ["train", "--resume", "f1", "-w", str(tmp_path), "--json", "--no-evaluate"])
    assert res.exit_code == 0, res.output
    assert read_fleet(ws, "f1")["state"] == "done"
    for run_id in read_fleet(ws, "f1")["runs"]:
        run = load_run(ws, run_id)
        assert run["status"]["state"] == "done" and run["has_weights"]
        assert list(run["metrics"]["episode"]) == list(range(1, 401))


@pytest.mark.slow
def test_the_ray_backend_trains_the_same_agents_as_the_local_one(tmp_path):
    pytest.importorskip("ray")
    from laneprint.parallel import backend_session

    ws = analysed_two_drivers(tmp_path)
    args = ["train", "--drivers", "all", "--episodes", "150", "-w", str(tmp_path), "--json", "--no-evaluate", *FAST]
    assert CliRunner().invoke(app, [*args, "--run-id", "local"]).exit_code == 0
    with backend_session("ray", num_cpus=2):  # a local Ray instance with 2 CPUs: one shard per driver
        res = CliRunner().invoke(app, [*args, "--run-id", "onray", "--backend", "ray"])
    assert res.exit_code == 0, res.output
    assert read_fleet(ws, "onray")["backend"] == "ray" and read_fleet(ws, "onray")["state"] == "done"
    for driver in STYLES:
        local = torch.load(tmp_path / "runs" / f"local-{driver.lower()}-s0" / "weights.pt", weights_only=True)
        on_ray = torch.load(tmp_path / "runs" / f"onray-{driver.lower()}-s0" / "weights.pt", weights_only=True)
        for key, value in local.items():
            torch.testing.assert_close(on_ray[key], value, rtol=0, atol=1e-4)


def test_a_fleet_killed_before_its_first_checkpoint_starts_its_metrics_afresh(tmp_path):
    from rl.fleet.runs import create_fleet, fleet_targets

    ws = analysed_two_drivers(tmp_path)
    settings = DQNSettings(episodes=120, episodes_per_approach=0, num_envs=8, batch_size=64, learning_starts=200)
    fleet = create_fleet(ws, fleet_targets(ws, drivers="all"), [0], settings, fleet_id="f0")
    stale = tmp_path / "runs" / fleet["runs"][0] / "metrics.jsonl"
    stale.write_text("".join(json.dumps({"episode": e}) + "\n" for e in (1, 2, 3)))  # killed at episode 3
    res = CliRunner().invoke(app, ["train", "--resume", "f0", "-w", str(tmp_path), "--json", "--no-evaluate"])
    assert res.exit_code == 0, res.output
    for run_id in fleet["runs"]:
        assert list(load_run(ws, run_id)["metrics"]["episode"]) == list(range(1, 121))


def test_stacked_environments_step_exactly_as_each_agents_own():
    from rl.problem.env import make_vec_env
    from rl.problem.stacked import StackedReplayEnvs, stack_envs

    members = _members()

    def envs():
        return [
            make_vec_env(m.env_config, 8, np.random.default_rng([m.settings.seed, 1]), m.approaches) for m in members
        ]

    alone, together = envs(), envs()
    stack = stack_envs(together)
    assert isinstance(stack, StackedReplayEnvs)
    rng = np.random.default_rng(0)
    for _ in range(60):
        actions = rng.integers(0, 2, (len(members), 8))
        out = stack.step(actions)
        for k, env in enumerate(alone):
            own = env.step(actions[k])
            for key in ("obs", "final_obs", "reward", "terminated", "truncated", "reached_leader"):
                np.testing.assert_array_equal(out[key][k], own[key])
    stack.scatter()
    for a, b in zip(alone, together):  # same state and the same draws from each agent's generator
        assert a.rng.bit_generator.state == b.rng.bit_generator.state
        for key, value in a.state_dict().items():
            other = b.state_dict()[key]
            if isinstance(value, dict):
                for name in value:
                    np.testing.assert_array_equal(value[name], other[name])
            else:
                np.testing.assert_array_equal(value, other)
