"""Recorded scenes, the `decisions` reward, the imitation benchmark and held-out cross-validation."""

import json

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.workspace import Workspace
from rl.evaluation.crossval import CrossvalSettings, assign_folds, crossvalidate
from rl.learners.dqn import DQNSettings, DQNTrainer
from rl.problem.env import EnvConfig, LaneChangeDecisionEnv, VecReplayEnv, approaches_from_decisions
from rl.evaluation.evaluate import agent_policy, evaluate_policies, greedy_policy
from rl.baselines.imitation import ImitationClassifier
from rl.problem.rewards import CHANGE, KEEP, ReferenceLines, RewardSettings, decisions_step_reward
from rl.settings import resolve_formulation
from tests.support.rl_workspaces import rule_driver_decisions, session_decisions, write_style_analysis

LINES = ReferenceLines.paper("Normal")
DECISIONS_ENV = EnvConfig(
    lines=LINES, reward=RewardSettings(name="decisions"), scenes="recorded", observation="indicators"
)
FAST = dict(num_envs=8, batch_size=128, learning_starts=300, episodes_per_approach=0.0)


def sessions(n_sessions: int, per_session: int, driver: str = "D01", seed: int = 0) -> pd.DataFrame:
    """Decisions of a rule driver over several sessions (recordings)."""
    return session_decisions(LINES, n_sessions, per_session, driver, seed)


def test_decisions_reward_pays_the_press_and_charges_a_passed_up_moment():
    s = RewardSettings(name="decisions", press_scale_s=2.0, pass_penalty=0.5)
    t = np.array([-4.0, -1.0, 0.0, 0.5, 0.0, -1.0])
    act = np.array([CHANGE, CHANGE, CHANGE, CHANGE, KEEP, KEEP])
    r, terms = decisions_step_reward(t, act, s)
    assert r.tolist() == pytest.approx([-1.0, 0.5, 1.0, 0.75, -0.5, 0.0])
    assert terms["press"][:4].tolist() == pytest.approx([-1.0, 0.5, 1.0, 0.75])
    assert terms["pass"].tolist() == pytest.approx([0, 0, 0, 0, -0.5, 0])


def test_decisions_reward_needs_recorded_scenes():
    with pytest.raises(UserError, match="recorded scenes"):
        EnvConfig(reward=RewardSettings(name="decisions"))
    assert resolve_formulation(None, None, None) == ("decisions", "recorded", "acceptance")
    assert resolve_formulation(None, None, None, lines="paper") == ("timing", "synthetic", "paper")
    assert resolve_formulation("timing", "recorded", None) == ("timing", "recorded", "paper")


def test_replay_env_walks_the_recorded_approach_then_runs_on_past_the_press():
    approaches, _ = approaches_from_decisions(rule_driver_decisions(LINES, 1, seed=0, window_s=1.0))
    env = VecReplayEnv(DECISIONS_ENV, approaches, 1, np.random.default_rng(0))
    env.index[:] = 0
    env.scene.put(np.array([0]), env.states.take(np.array([0])))
    seen = [float(env.t_from_press()[0])]
    for _ in range(3):
        out = env.step(np.array([KEEP]))
        seen.append(float(env.t_from_press()[0]))
        assert not out["terminated"][0]
    assert seen == pytest.approx([-1.0, -0.5, 0.0, 0.5])  # two not-yet states, the press, then run on
    assert out["reward"][0] == pytest.approx(-DECISIONS_ENV.reward.pass_penalty)  # kept at the press
    out = env.step(np.array([CHANGE]))  # half a second late
    assert out["terminated"][0] and out["reward"][0] == pytest.approx(1 - 0.5 / 2.0)


def test_replay_env_truncates_after_the_late_window():
    approaches, _ = approaches_from_decisions(rule_driver_decisions(LINES, 1, seed=0, window_s=0.5))
    cfg = EnvConfig(
        lines=LINES, reward=RewardSettings(name="decisions"), scenes="recorded", replay_late_s=1.0, end_at_leader=False
    )
    env = VecReplayEnv(cfg, approaches, 1, np.random.default_rng(0))
    env.index[:] = 1  # the press
    env.scene.put(np.array([0]), env.states.take(np.array([1])))
    truncated = [bool(env.step(np.array([KEEP]))["truncated"][0]) for _ in range(3)]
    assert truncated == [False, False, True]


def test_gym_env_replays_with_the_decisions_reward():
    approaches, _ = approaches_from_decisions(rule_driver_decisions(LINES, 2, seed=0, window_s=1.0))
    env = LaneChangeDecisionEnv(DECISIONS_ENV, approaches=approaches)
    obs, _ = env.reset(seed=0, options={"approach": 0})
    assert obs.shape == env.observation_space.shape == (14,)
    env.step(KEEP)
    env.step(KEEP)
    _, reward, terminated, _, info = env.step(CHANGE)  # at the press
    assert terminated and reward == pytest.approx(1.0) and info["terms"]["press"] == pytest.approx(1.0)


@pytest.mark.slow
def test_agent_on_recorded_scenes_learns_the_drivers_moment():
    dec = rule_driver_decisions(LINES, 40, seed=0, window_s=4.0)
    approaches, _ = approaches_from_decisions(dec)
    trainer = DQNTrainer(DECISIONS_ENV, DQNSettings(episodes=2500, seed=0, **FAST), approaches=approaches).train()
    ev = evaluate_policies(
        {"agent": agent_policy(trainer.policy_net, DECISIONS_ENV), "greedy": greedy_policy(DECISIONS_ENV)},
        approaches,
        DECISIONS_ENV,
    )
    rows = {r["who"]: r for r in ev["summary"]}
    assert rows["agent"]["balanced_accuracy"] >= 0.85
    assert rows["agent"]["timing_mae_s"] < rows["greedy"]["timing_mae_s"]


def test_recorded_scenes_get_episodes_in_proportion_to_the_approaches():
    s = DQNSettings(episodes=10000, episodes_per_approach=30.0)
    assert s.resolved_episodes(None).episodes == 10000  # synthetic scenes: as given
    assert s.resolved_episodes(150).episodes == 4500
    assert s.resolved_episodes(10).episodes == 2000 and s.resolved_episodes(1000).episodes == 10000
    approaches, _ = approaches_from_decisions(rule_driver_decisions(LINES, 100, seed=0, window_s=1.0))
    trainer = DQNTrainer(DECISIONS_ENV, DQNSettings(num_envs=8), approaches=approaches)
    assert trainer.settings.episodes == 3000 and trainer.settings.episodes_per_approach == 0.0


def test_imitation_classifier_separates_presses_from_not_yet_states():
    approaches, _ = approaches_from_decisions(rule_driver_decisions(LINES, 60, seed=0, window_s=4.0))
    clf = ImitationClassifier(random_state=0).fit(approaches, DECISIONS_ENV)
    ev = evaluate_policies({"imitation": clf.policy(DECISIONS_ENV)}, approaches, DECISIONS_ENV)
    assert ev["summary"][0]["balanced_accuracy"] >= 0.85


def test_folds_deal_every_drivers_sessions_and_are_seeded():
    s = pd.DataFrame(
        {
            "recording_id": [f"{d}-{k}" for d in ("A", "B") for k in range(4)],
            "driver_id": [d for d in ("A", "B") for _ in range(4)],
            "speed_limit_kph": [60.0, 70.0, 80.0, 90.0] * 2,
        }
    )
    folds = assign_folds(s, CrossvalSettings(folds=4, seed=1))
    assert folds == assign_folds(s, CrossvalSettings(folds=4, seed=1))
    for d in ("A", "B"):
        assert sorted(folds[f"{d}-{k}"] for k in range(4)) == [0, 1, 2, 3]
    assert folds != assign_folds(s, CrossvalSettings(folds=4, seed=2))
    by_section = assign_folds(s, CrossvalSettings(folds=2, split="section"))
    assert by_section["A-0"] == by_section["B-1"] == 0 and by_section["A-3"] == 1


def test_session_folds_keep_every_speed_section_in_training():
    """Three drivers, one session per section: a fold never holds out two sessions of one section
    (a random deal did, and scored extrapolation over speed as a new session)."""
    s = pd.DataFrame(
        {
            "recording_id": [f"{d}-{k}" for d in ("A", "B", "C") for k in range(4)],
            "driver_id": [d for d in ("A", "B", "C") for _ in range(4)],
            "speed_limit_kph": [60.0, 70.0, 80.0, 90.0] * 3,
        }
    )
    for seed in range(5):
        folds = assign_folds(s, CrossvalSettings(folds=4, seed=seed))
        s["fold"] = s["recording_id"].map(folds)
        assert (s.groupby(["fold", "speed_limit_kph"]).size() == 1).all()
        assert sorted(s.groupby("fold").size()) == [3, 3, 3, 3]


@pytest.mark.slow
def test_crossval_scores_every_decision_once_on_sessions_not_trained_on():
    dec = sessions(4, 8)
    res = crossvalidate(
        dec,
        ["D01"],
        ["D01"],
        DECISIONS_ENV,
        DQNSettings(episodes=300, **FAST),
        CrossvalSettings(folds=4, n_bootstrap=50),
    )
    assert [r["who"] for r in res["summary"]] == ["agent", "greedy", "imitation"]
    for r in res["summary"]:
        lo, hi = r["balanced_accuracy_ci"]
        assert lo <= r["balanced_accuracy"] <= hi and r["n_decisions"] == 32
    assert res["n_decisions_scored"] == res["n_decisions_total"] == 32 and res["scored_share"] == 1.0
    held = [set(f["sessions"]) for f in res["per_fold"]]
    assert len(held) == 4 and all(len(h) == 1 for h in held) and len(set.union(*held)) == 4
    assert all(f["n_train_decisions"] == 24 for f in res["per_fold"])
    states = res["states"]
    assert states.groupby("decision_id")["fold"].nunique().max() == 1


@pytest.mark.slow
def test_crossval_command_prints_one_row_per_policy(tmp_path):
    write_style_analysis(Workspace(tmp_path), sessions(4, 6), LINES)
    res = CliRunner().invoke(
        app,
        [
            "crossval",
            "--style",
            "Normal",
            "--folds",
            "2",
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
    rows = {r["who"]: r for r in out["summary"]}
    assert set(rows) == {"agent", "greedy", "imitation"}
    for r in rows.values():
        assert {
            "balanced_accuracy",
            "balanced_accuracy_ci",
            "recall",
            "specificity",
            "timing_mae_s",
            "never_rate",
            "n_decisions",
            "n_states",
        } <= set(r)
    assert (tmp_path / "crossval" / out["crossval_id"] / "result.json").exists()
    bad = CliRunner().invoke(app, ["crossval", "--style", "Normal", "--folds", "9", "-w", str(tmp_path)])
    assert bad.exit_code == 1 and "--folds" in bad.output


@pytest.mark.slow
def test_crossval_scores_each_direction_apart_with_the_pooled_fields(tmp_path):
    dec = sessions(4, 6)
    # the second half of every session's presses return to the right: target lane below the ego's
    right = dec["decision_id"].str.split(":").str[-1].astype(int) % 2 == 1
    dec.loc[right, ["ego_lane", "target_lane"]] = [1, 0]
    write_style_analysis(Workspace(tmp_path), dec, LINES)
    res = CliRunner().invoke(
        app,
        [
            "crossval",
            "--style",
            "Normal",
            "--folds",
            "2",
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
    by_dir = out["summary_by_direction"]
    assert {(r["direction"], r["who"]) for r in by_dir} == {
        (d, w) for d in ("left", "right") for w in ("agent", "greedy", "imitation")
    }
    for r in by_dir:
        assert set(out["summary"][0]) <= set(r)
    n = {d: {r["n_decisions"] for r in by_dir if r["direction"] == d} for d in ("left", "right")}
    assert n == {"left": {12}, "right": {12}} and out["summary"][0]["n_decisions"] == 24
    text = CliRunner().invoke(
        app,
        [
            "crossval",
            "--style",
            "Normal",
            "--folds",
            "2",
            "--episodes",
            "200",
            "--bootstrap",
            "50",
            "-w",
            str(tmp_path),
        ],
    )
    assert "by direction" in text.output and "right" in text.output
