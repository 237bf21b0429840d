"""The environment: gymnasium contract, dynamics, observation, replay mode."""

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest
from gymnasium.utils.env_checker import check_env

import rl
from rl.problem.env import EnvConfig, LaneChangeDecisionEnv, VecLaneChangeEnv, approaches_from_decisions, sample_scenes
from rl.problem.rewards import ReferenceLines
from rl.problem.scene import Scene, indicators, observe
from tests.support.rl_workspaces import rule_driver_decisions


def one_scene(**kw) -> Scene:
    base = dict(
        v_e=20.0,
        x_e=0.0,
        f_present=True,
        v_f=10.0,
        x_f=54.5,
        hl_f=4.5,
        nf_present=True,
        v_nf=12.0,
        x_nf=44.5,
        hl_nf=4.5,
        nb_present=True,
        v_nb=9.0,
        x_nb=-24.5,
        hl_nb=4.5,
    )
    base.update(kw)
    return Scene(**{k: np.atleast_1d(np.asarray(v)) for k, v in base.items()})


def test_registered_and_passes_check_env():
    env = gym.make(rl.ENV_ID)
    check_env(env.unwrapped)
    obs, _ = env.reset(seed=3)
    assert obs.shape == (8,) and obs.dtype == np.float32
    assert (obs > 0).all() and (obs <= 1).all()


def test_indicators_hand_computed():
    ind = indicators(one_scene())
    assert ind.t_f[0] == pytest.approx(50.0 / 10.0)  # gap 54.5 - 4.5 = 50 m, closing 10 m/s
    assert ind.t_nf[0] == pytest.approx(40.0 / 8.0)
    assert ind.dv_nb[0] == pytest.approx(11.0)
    far = indicators(one_scene(x_nb=-110.0))  # gap 105.5 m > 100 m: no influence
    assert not far.dv_nb_ok[0] and np.isnan(far.dv_nb[0])
    pulling_away = indicators(one_scene(v_nf=25.0))
    assert not pulling_away.t_nf_ok[0]


def test_ttc_falls_by_dt_per_step_and_change_ends_episode():
    env = LaneChangeDecisionEnv(EnvConfig(dt_s=0.5))
    _, info = env.reset(seed=1)
    _, _, term, trunc, info2 = env.step(1)
    if info["t_f"] is not None and info2["t_f"] is not None:
        assert info["t_f"] - info2["t_f"] == pytest.approx(0.5)
    assert not term and not trunc
    _, _, term, _, info3 = env.step(0)
    assert term and info3["changed"]


def test_absent_and_out_of_range_vehicles_are_shown_at_the_edges():
    obs = observe(one_scene(nf_present=False, nb_present=False), range_m=150.0, v_max_mps=40.0)[0]
    assert obs[5] == 1.0 and obs[4] == pytest.approx(20.0 / 40.0)  # nothing ahead in the target lane
    assert obs[7] == pytest.approx(1e-3) and obs[6] == pytest.approx(0.5)
    beyond = observe(one_scene(x_f=400.0), range_m=150.0, v_max_mps=40.0)[0]
    assert beyond[3] == 1.0 and beyond[2] == pytest.approx(0.5)
    assert observe(one_scene(), 150.0, 40.0)[0, 1] == 0.5  # the ego is the centre


def test_reset_is_seeded_and_vec_env_matches_model():
    a, _ = LaneChangeDecisionEnv().reset(seed=7)
    b, _ = LaneChangeDecisionEnv().reset(seed=7)
    np.testing.assert_array_equal(a, b)
    vec = VecLaneChangeEnv(EnvConfig(), 4, np.random.default_rng(0))
    out = vec.step(np.ones(4, int))
    assert out["obs"].shape == (4, 8) and out["reward"].shape == (4,)


def test_replay_mode_follows_the_recorded_states_then_extrapolates():
    lines = ReferenceLines.paper("Normal")
    dec = rule_driver_decisions(lines, 3, seed=0, window_s=1.0, every_s=0.5)
    approaches, skipped = approaches_from_decisions(dec)
    assert len(approaches) == 3 and sum(skipped.values()) == 0
    a = approaches[0]
    assert len(a) == 3 and a.t_s[-1] == a.press_t_s
    env = LaneChangeDecisionEnv(EnvConfig(lines=lines), approaches=approaches)
    _, info = env.reset(seed=0, options={"approach": 0})
    recorded_tf = dec[dec.decision_id == a.decision_id]["t_f_s"].to_numpy()
    assert info["t_f"] == pytest.approx(recorded_tf[0])
    _, _, _, _, info = env.step(1)
    assert info["t_f"] == pytest.approx(recorded_tf[1])
    env.step(1)
    _, _, _, _, info = env.step(1)  # past the press: the press scene moved on by dt
    assert info["recorded"] is False
    assert info["t_f"] == pytest.approx(recorded_tf[2] - 0.5)


def test_presses_without_a_closing_leader_are_replayed_unless_the_study_rule_is_asked():
    dec = rule_driver_decisions(ReferenceLines.paper("Normal"), 4, seed=0, window_s=1.0)
    press = dec.index[(dec.decision_id == dec.decision_id.iloc[0]) & (dec.label == "change")]
    dec.loc[press, ["t_f_status", "t_f_s"]] = ["not_closing", np.nan]
    approaches, skipped = approaches_from_decisions(dec)
    assert len(approaches) == 4 and not any(skipped.values())  # the driver decided there too: scored
    approaches, skipped = approaches_from_decisions(dec, include_following=False)
    assert len(approaches) == 3 and skipped["no_closing_leader"] == 1


def test_a_decision_without_its_press_row_is_counted_not_replayed():
    dec = rule_driver_decisions(ReferenceLines.paper("Normal"), 4, seed=0, window_s=1.0)
    first = dec.decision_id.iloc[0]
    dec = dec[~((dec.decision_id == first) & (dec.label == "change"))]
    approaches, skipped = approaches_from_decisions(dec)
    assert len(approaches) == 3 and skipped["no_press"] == 1


def test_sample_scenes_put_leaders_ahead():
    s = sample_scenes(np.random.default_rng(0), EnvConfig(), 500)
    assert (s.x_f - s.x_e - s.hl_f > 0).all() and (s.x_nb < s.x_e).all()
    assert (s.v_e > s.v_f).all()


def test_trains_unchanged_with_stable_baselines3():
    sb3 = pytest.importorskip("stable_baselines3")
    import torch

    torch.set_num_threads(1)
    model = sb3.DQN(
        "MlpPolicy",
        gym.make(rl.ENV_ID),
        learning_starts=50,
        buffer_size=500,
        batch_size=16,
        policy_kwargs={"net_arch": [16]},
        seed=0,
        device="cpu",
    )
    model.learn(total_timesteps=200)
    action, _ = model.predict(LaneChangeDecisionEnv().reset(seed=0)[0], deterministic=True)
    assert int(action) in (0, 1)


def _middle_lane(dec: pd.DataFrame, decision_ids) -> pd.DataFrame:
    """`dec` with the decisions `decision_ids` made from the middle lane of three (to the left); their other
    side (lane 0) holds the target lane's vehicles 30 m further on, the rest keep two lanes' columns."""
    dec = dec.copy()
    mid = dec["decision_id"].isin(decision_ids).to_numpy()
    dec["ego_lane"], dec["target_lane"] = np.where(mid, 1, 0), np.where(mid, 2, 1)
    dec["other_lane"] = np.where(mid, 0, -1)
    for role in ("nf", "nb"):
        dec[f"other_{role}_present"] = mid & dec[f"{role}_present"].to_numpy()
        for q, shift in (("x_m", 30.0), ("v_mps", 0.0), ("gap_m", 30.0 if role == "nf" else -30.0)):
            dec[f"other_{role}_{q}"] = np.where(dec[f"other_{role}_present"], dec[f"{role}_{q}"] + shift, np.nan)
        dec[f"other_{role}_id"] = None
    return dec


def test_approaches_from_a_middle_lane_carry_the_side_not_taken():
    dec = rule_driver_decisions(ReferenceLines.paper("Normal"), 3, seed=0, window_s=1.0, every_s=0.5)
    first = dec["decision_id"].iloc[0]
    approaches, _ = approaches_from_decisions(_middle_lane(dec, [first]))
    a = next(x for x in approaches if x.decision_id == first)
    assert a.other is not None and len(a.other) == len(a)
    assert a.scene.left.all() and not a.other.left.any()  # the driver went left; the other side is the right
    np.testing.assert_allclose(a.other.x_nf, a.scene.x_nf + 30.0)
    np.testing.assert_allclose(a.other.hl_nf, a.scene.hl_nf)  # gap and position moved alike: same lengths
    np.testing.assert_array_equal(a.other.x_f, a.scene.x_f)  # the ego lane's leader is the same
    assert all(x.other is None for x in approaches if x.decision_id != first)
    assert all(x.other is None for x in approaches_from_decisions(dec)[0])  # a table without the columns


def test_sides_not_taken_are_replayed_as_approaches_without_a_press():
    from rl.problem.env import NO_PRESS_S, VecReplayEnv, replayed_approaches
    from rl.problem.rewards import CHANGE, KEEP, RewardSettings

    dec = rule_driver_decisions(ReferenceLines.paper("Normal"), 2, seed=0, window_s=1.0, every_s=0.5)
    approaches, _ = approaches_from_decisions(_middle_lane(dec, dec["decision_id"].unique()[:1]))
    cfg = EnvConfig(scenes="recorded", observation="direction", reward=RewardSettings(name="decisions"))
    n = sum(len(a) for a in approaches)
    env = VecReplayEnv(cfg, approaches, 2, np.random.default_rng(0))
    assert len(env.t_rel) == n + len(approaches[0]) and env.no_press.sum() == len(approaches[0])
    assert replayed_approaches(approaches, cfg) == 3
    assert replayed_approaches(approaches, replace(cfg, other_side=False)) == 2
    first_other = n  # the side not taken follows the recorded approaches
    assert (env.t_rel[first_other:] == -NO_PRESS_S).all()
    # a change there is one far too early (the floor), a keep pays 0 and at its last state ends the episode
    env.index[:] = [first_other, env.last[first_other]]
    env.scene = env.states.take(env.index)
    out = env.step(np.array([CHANGE, KEEP]))
    assert out["reward"].tolist() == [-1.0, 0.0]
    assert out["terminated"].tolist() == [True, False] and out["truncated"].tolist() == [False, True]
    # off: only the driver's side, as before the setting
    off = VecReplayEnv(replace(cfg, other_side=False), approaches, 2, np.random.default_rng(0))
    assert len(off.t_rel) == n and not off.no_press.any()


def test_the_setting_changes_nothing_without_a_side_not_taken():
    from rl.problem.env import VecReplayEnv
    from rl.problem.rewards import RewardSettings

    approaches, _ = approaches_from_decisions(rule_driver_decisions(ReferenceLines.paper("Normal"), 4, seed=1))
    cfg = EnvConfig(scenes="recorded", observation="indicators", reward=RewardSettings(name="decisions"))
    runs = []
    for on in (True, False):
        env, rng = (
            VecReplayEnv(replace(cfg, other_side=on), approaches, 4, np.random.default_rng(3)),
            np.random.default_rng(5),
        )
        runs.append([env.step(rng.integers(2, size=4))["obs"] for _ in range(50)])
    np.testing.assert_array_equal(np.stack(runs[0]), np.stack(runs[1]))


def test_runs_from_before_the_setting_replay_only_the_drivers_side():
    d = EnvConfig().to_dict()
    del d["other_side"]
    assert EnvConfig.from_dict(d).other_side is False and EnvConfig().other_side is True


def test_train_names_the_setting_and_two_lanes_train_alike(tmp_path):
    import json

    import torch
    from typer.testing import CliRunner

    from laneprint.app.cli import app
    from rl.runs import load_weights, run_dir
    from tests.support.rl_workspaces import FAST_CLI, analysed_workspace

    ws = analysed_workspace(tmp_path)  # a two-lane analysis: no side not taken anywhere
    for flag, run in (("--other-side", "on"), ("--driver-side-only", "off")):
        res = CliRunner().invoke(
            app,
            [
                "train",
                "--style",
                "Normal",
                "--episodes",
                "100",
                "--seed",
                "3",
                flag,
                "--run-id",
                run,
                "--no-evaluate",
                "-w",
                str(tmp_path),
                *FAST_CLI,
            ],
        )
        assert res.exit_code == 0, res.output
    configs = {r: json.loads((run_dir(ws, r) / "config.json").read_text())["env"] for r in ("on", "off")}
    assert configs["on"]["other_side"] is True and configs["off"]["other_side"] is False
    on, off = load_weights(ws, "on").state_dict(), load_weights(ws, "off").state_dict()
    assert all(torch.equal(on[k], off[k]) for k in on)
