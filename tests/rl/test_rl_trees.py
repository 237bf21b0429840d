"""The tree learner (`--learner trees`): fitted Q iteration, its torch module, and the commands that use it."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import torch
from sklearn.ensemble import HistGradientBoostingRegressor
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.workspace import Workspace
from rl.baselines.imitation import labelled_states
from rl.learners.choice import inner_folds, session_of
from rl.learners.dqn import q_values
from rl.learners.trees import _SKLEARN_THRESHOLDS, TreeQNetwork, _thresholds_batched, fit_tree_q, fitted_q_data
from rl.problem.env import EnvConfig, approaches_from_decisions, formulation_config
from rl.problem.rewards import CHANGE, KEEP, ReferenceLines, RewardSettings
from rl.runs import load_weights
from rl.settings import TREES_PRESS_SCALE_S, AutoSettings, TreeQSettings
from tests.support.rl_workspaces import FAST_CLI, analysed_workspace, session_decisions, write_style_analysis

LINES = ReferenceLines.paper("Normal")
SMALL = TreeQSettings(trees=40, iterations=4, learning_rate=0.2)


@pytest.mark.slow
def test_the_module_predicts_what_the_ensembles_predict():
    rng = np.random.default_rng(0)
    x = rng.random((2000, 6)).astype(np.float32)
    x[rng.random(x.shape) < 0.05] = np.nan  # a missing value goes the way the trees learnt
    fit = lambda y, n: HistGradientBoostingRegressor(max_iter=n, max_leaf_nodes=9).fit(x, y)  # noqa: E731
    target = np.nan_to_num(x)
    change, keep = fit((target[:, 0] > 0.3) + target[:, 1], 30), fit(np.sin(6 * target[:, 2]), 20)
    net = TreeQNetwork.from_ensembles({CHANGE: change, KEEP: keep}, x[:1])
    q = q_values(net, x)
    assert np.abs(q[:, CHANGE] - change.predict(x)).max() < 1e-5
    assert np.abs(q[:, KEEP] - keep.predict(x)).max() < 1e-5
    again = TreeQNetwork.from_state_dict(net.state_dict())  # what a run's weights.pt holds
    assert torch.equal(again(torch.as_tensor(x)), net(torch.as_tensor(x)))


def test_the_weighted_bins_are_scikit_learns_to_the_bit():
    rng = np.random.default_rng(0)
    for trial in range(40):
        n = int(rng.integers(50, 3000))
        x = rng.normal(size=n) * 10.0 ** int(rng.integers(-3, 4))
        if trial % 3 == 0:  # ties
            x = np.round(x, 1)
        if trial % 4 == 0:
            x[rng.random(n) < 0.1] = np.nan
        w = np.where(rng.random(n) < 0.1, 2.0, 1.0) if trial % 2 else rng.random(n) * 3
        w[rng.random(n) < 0.05 * (trial % 5 == 0)] = 0.0
        ours, theirs = _thresholds_batched(x, 255, w), _SKLEARN_THRESHOLDS(x, 255, w)
        assert ours.dtype == theirs.dtype and np.array_equal(ours, theirs)


@pytest.mark.slow
def test_fitted_q_iteration_changes_at_the_press_and_keeps_before():
    dec = session_decisions(LINES, 4, 8)
    approaches, _ = approaches_from_decisions(dec)
    cfg = formulation_config(LINES)
    data = fitted_q_data(approaches, cfg)
    assert data["end"].sum() == len(approaches) and data["r_change"][data["end"]].min() == 1.0
    assert (data["press"] == data["end"]).all()  # two lanes: every approach ends at its press
    net = fit_tree_q(approaches, cfg, SMALL)
    x, y = labelled_states(approaches, cfg)
    acts = q_values(net, x).argmax(axis=1)
    said_change = acts == CHANGE
    assert said_change[y == 1].mean() >= 0.9  # the presses
    assert (~said_change[y == 0]).mean() >= 0.8  # the states before them


def test_the_tree_learner_needs_the_decisions_reward(tmp_path):
    analysed_workspace(tmp_path)
    res = CliRunner().invoke(
        app, ["train", "--style", "Normal", "--learner", "trees", "--reward", "timing", "-w", str(tmp_path)]
    )
    assert res.exit_code == 1 and "needs the decisions reward" in res.output
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())  # nothing half written
    fleet = CliRunner().invoke(app, ["train", "--styles", "all", "--learner", "auto", "-w", str(tmp_path)])
    assert fleet.exit_code == 1 and "--learner auto fits one style or driver" in fleet.output
    approaches, _ = approaches_from_decisions(session_decisions(LINES, 2, 4))
    with pytest.raises(UserError, match="decisions"):
        fit_tree_q(approaches, EnvConfig(lines=LINES), SMALL)  # synthetic scenes, timing reward


@pytest.mark.slow
def test_train_evaluate_export_and_check_a_tree_run(tmp_path):
    ws = analysed_workspace(tmp_path)
    res = CliRunner().invoke(
        app, ["train", "--style", "Normal", "--learner", "trees", "--run-id", "t1", "-w", str(tmp_path), "--json"]
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["learner"] == "trees" and out["state"] == "done"
    agent = next(r for r in out["evaluation"] if r["who"] == "agent")
    assert agent["recall"] >= 0.9
    config = json.loads((tmp_path / "runs" / "t1" / "config.json").read_text())
    assert config["learner"] == "trees" and config["trees"]["iterations"] == TreeQSettings().iterations
    assert isinstance(load_weights(ws, "t1"), TreeQNetwork)
    exported = CliRunner().invoke(app, ["export", "t1", "-w", str(tmp_path), "--json"])
    assert exported.exit_code == 0, exported.output
    doc = json.loads((tmp_path / "exports" / "t1" / "policy.json").read_text())
    assert doc["run"]["learner"] == "trees"
    assert all(s["actions_agree"] == s["n_states"] for s in json.loads(exported.stdout)["check"]["sets"].values())
    checked = CliRunner().invoke(app, ["check", "-w", str(tmp_path), "--json"])
    assert "runs/t1" not in checked.stdout, checked.stdout
    again = CliRunner().invoke(app, ["train", "--resume", "t1", "-w", str(tmp_path), "--json"])
    assert again.exit_code == 0, again.output  # fitted in one go: a resume fits it again, same settings
    assert json.loads(again.stdout)["state"] == "done"
    assert len(json.loads((tmp_path / "runs" / "t1" / "config.json").read_text())["resumed_at"]) == 1


@pytest.mark.slow
def test_default_learner_killed_while_choosing_resumes(tmp_path):
    """kill -9 while `auto` chooses its learner: the run reads interrupted, and --resume ends it done."""
    import signal
    import subprocess
    import sys
    import time

    analysed_workspace(tmp_path)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "laneprint.app.cli",
            "train",
            "--style",
            "Normal",
            "--run-id",
            "k1",
            "--episodes",
            "300",
            "-w",
            str(tmp_path),
            "--json",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    status = tmp_path / "runs" / "k1" / "status.json"
    deadline = time.time() + 120
    while time.time() < deadline and not (status.exists() and "choosing" in status.read_text()):
        time.sleep(0.2)
    assert "choosing" in status.read_text()
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    runs = json.loads(CliRunner().invoke(app, ["runs", "-w", str(tmp_path), "--json"]).stdout)["runs"]
    assert runs[0]["state"] == "interrupted"
    again = CliRunner().invoke(app, ["train", "--resume", "k1", "-w", str(tmp_path), "--json"])
    assert again.exit_code == 0, again.output
    out = json.loads(again.stdout)
    assert out["state"] == "done" and out["learner_choice"]["learner"] in ("dqn", "trees")


@pytest.mark.slow
def test_crossval_with_the_tree_learner_says_so(tmp_path):
    write_style_analysis(Workspace(tmp_path), session_decisions(LINES, 4, 6), LINES)
    res = CliRunner().invoke(
        app,
        [
            "crossval",
            "--style",
            "Normal",
            "--folds",
            "2",
            "--learner",
            "trees",
            "--bootstrap",
            "50",
            "-w",
            str(tmp_path),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["learner"] == "trees" and "trees" in out and "dqn" not in out
    assert out["env"]["reward"]["press_scale_s"] == TREES_PRESS_SCALE_S  # the trees' own sharp reward
    agent = next(r for r in out["summary"] if r["who"] == "agent")
    assert agent["balanced_accuracy"] > 0.7


def test_the_inner_folds_hold_out_every_session_once_and_keep_each_driver_to_fit_on():
    dec = pd.concat([session_decisions(LINES, 4, 3, driver=d, seed=i) for i, d in enumerate(("D01", "D02"))])
    dec = pd.concat([dec, session_decisions(LINES, 1, 3, driver="D03", seed=7)])  # one session: always fitted on
    approaches, _ = approaches_from_decisions(dec)
    pairs = inner_folds(approaches, 3, seed=0)
    sessions = lambda apps: {session_of(a.decision_id) for a in apps}  # noqa: E731
    assert len(pairs) == 3
    held_out = [sessions(held) for _, held in pairs]
    assert sorted(s for h in held_out for s in h) == sorted(
        sessions(approaches) - sessions([a for a in approaches if a.driver_id == "D03"])
    )  # every session of a driver with two or more, once
    for fit, held in pairs:
        assert not sessions(fit) & sessions(held) and len(fit) + len(held) == len(approaches)
        assert {a.driver_id for a in fit} == {"D01", "D02", "D03"}
    assert [sessions(h) for _, h in inner_folds(approaches, 3, seed=0)] == held_out  # seeded
    assert [sessions(h) for _, h in inner_folds(approaches, 3, seed=1)] != held_out


@pytest.mark.slow
def test_auto_chooses_a_learner_per_fold_and_per_run(tmp_path):
    write_style_analysis(Workspace(tmp_path), session_decisions(LINES, 8, 4), LINES)
    res = CliRunner().invoke(
        app,
        [
            "crossval",
            "--style",
            "Normal",
            "--folds",
            "2",
            "--learner",
            "auto",
            "--episodes",
            "200",
            "--bootstrap",
            "50",
            "-w",
            str(tmp_path),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["learner"] == "auto"
    for fold in out["per_fold"]:
        assert fold["learner"] in ("dqn", "trees") and set(fold["learner_scores"]) == {"dqn", "trees"}
        sc = fold["learner_scores"]
        for name, sides in fold["learner_scores_by_side"].items():  # the score is the mean over the sides
            assert set(sides) <= {"left", "right"} and sc[name] == pytest.approx(
                np.mean(list(sides.values())), abs=1e-4
            )
        assert fold["learner"] == ("trees" if sc["trees"] > sc["dqn"] + AutoSettings().margin else "dqn")
    trained = CliRunner().invoke(
        app,
        [
            "train",
            "--style",
            "Normal",
            "--learner",
            "auto",
            "--episodes",
            "200",
            "--run-id",
            "a1",
            "-w",
            str(tmp_path),
            "--json",
            *FAST_CLI,
        ],
    )
    assert trained.exit_code == 0, trained.output
    config = json.loads((tmp_path / "runs" / "a1" / "config.json").read_text())
    choice = config["learner_choice"]
    assert config["learner"] == choice["learner"] and choice["folds"] == AutoSettings().folds
    assert choice["n_holdout"] == choice["n_train"]  # eight sessions a driver: every one scored once
    scale = config["env"]["reward"]["press_scale_s"]
    assert scale == (TREES_PRESS_SCALE_S if choice["learner"] == "trees" else RewardSettings().press_scale_s)
    bad = CliRunner().invoke(
        app, ["crossval", "--style", "Normal", "--learner", "auto", "--reward", "timing", "-w", str(tmp_path)]
    )
    assert bad.exit_code == 1 and "decisions reward" in bad.output


def test_the_default_learner_is_auto_for_one_target_and_the_dqn_otherwise(tmp_path):
    """Without --learner, one style on the decisions reward takes `auto`; the paper's formulation
    (which the trees cannot fit) and fleets take the DQN instead of refusing."""
    from rl.settings import default_learner

    assert default_learner("decisions", "recorded") == "auto"
    assert default_learner("decisions", "recorded", fleet=True) == "dqn"
    assert default_learner("timing", "synthetic") == "dqn"
    analysed_workspace(tmp_path)
    plain = CliRunner().invoke(
        app,
        ["train", "--style", "Normal", "--episodes", "200", "--run-id", "d1", "-w", str(tmp_path), "--json", *FAST_CLI],
    )
    assert plain.exit_code == 0, plain.output
    config = json.loads((tmp_path / "runs" / "d1" / "config.json").read_text())
    assert config["learner_choice"]["learner"] == config["learner"]  # chosen across the inner folds
    paper = CliRunner().invoke(
        app,
        [
            "train",
            "--style",
            "Normal",
            "--lines",
            "paper",
            "--episodes",
            "20",
            "--run-id",
            "p1",
            "-w",
            str(tmp_path),
            "--json",
            *FAST_CLI,
        ],
    )
    assert paper.exit_code == 0, paper.output
    config = json.loads((tmp_path / "runs" / "p1" / "config.json").read_text())
    assert config.get("learner", "dqn") == "dqn" and "learner_choice" not in config
