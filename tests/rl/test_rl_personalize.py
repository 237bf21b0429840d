"""`laneprint personalize`: a driver's agent from its first K decisions, through the command line."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from typer.testing import CliRunner

from indicators.settings import AnalysisSettings
from laneprint.app.cli import app
from laneprint.workspace import Workspace
from rl.personalize.split import decision_order, first_decisions, holdout_split
from clustering.pipeline import stored_settings
from rl.personalize.style import estimate_style, fit_population
from rl.problem.rewards import ReferenceLines
from tests.support.rl_workspaces import FAST_CLI, session_decisions

#: Two drivers per style of Table 1, three sessions of six decisions each.
DRIVERS = {
    "D01": "Defensive",
    "D02": "Defensive",
    "D03": "Normal",
    "D04": "Normal",
    "D05": "Aggressive",
    "D06": "Aggressive",
}
TINY = ["--base-episodes", "60", "--episodes", "40", *FAST_CLI]


def _decisions() -> pd.DataFrame:
    parts = [
        session_decisions(ReferenceLines.paper(style), 3, 6, driver=d, seed=10 * i)
        for i, (d, style) in enumerate(DRIVERS.items())
    ]
    return pd.concat(parts, ignore_index=True)


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> Workspace:
    """A hand-made analysis of six drivers in three styles (the decisions table, styles, lines, settings)."""
    ws = Workspace(tmp_path_factory.mktemp("personalize")).ensure()
    dec = _decisions()
    styles = pd.DataFrame(
        {
            "driver_id": list(DRIVERS),
            "style": list(DRIVERS.values()),
            "is_typical": [True, False] * 3,
            "cluster": [0, 0, 1, 1, 2, 2],
        }
    )
    refs = pd.DataFrame(
        [
            {"scope": "style", "name": s, "kind": "typical", "indicator": ind, "A": a, "b": b, "source": "Table 1"}
            for s in ("Defensive", "Normal", "Aggressive")
            for ind in ("t_f", "t_nf", "dv_nb")
            for a, b in [getattr(ReferenceLines.paper(s), ind)]
        ]
    )
    ws.write_tables(
        "analysis",
        {"decisions": dec, "styles": styles, "reference_lines": refs},
        meta={"settings": AnalysisSettings(min_cluster_decisions=3).to_dict()},
    )
    return ws


def _run(ws: Workspace, *args: str):
    return CliRunner().invoke(app, ["personalize", *args, "-w", str(ws.root)])


def test_first_k_decisions_are_the_earliest_in_time_order() -> None:
    rows = _decisions()
    rows = rows[rows["driver_id"] == "D03"]
    first = first_decisions(rows, 8)
    assert decision_order(first) == decision_order(rows)[:8]
    assert sorted(first["session_id"].unique()) == ["D03-rec0", "D03-rec1"]  # 6 of the first session, 2 of the next
    train, test = holdout_split(rows, 1)
    assert set(test["session_id"]) == {"D03-rec2"} and "D03-rec2" not in set(train["session_id"])


def test_style_of_a_few_decisions_has_a_confidence(study: Workspace) -> None:
    dec = study.read_table("analysis", "decisions")
    pop = fit_population(dec, ["D01", "D02", "D03", "D04", "D06"], stored_settings(study))
    est = estimate_style(pop, first_decisions(dec[dec["driver_id"] == "D05"], 6), n_bootstrap=50, seed=1)
    assert est.style == "Aggressive"
    assert 0 < est.confidence <= 1 and sum(est.bootstrap.values()) == pytest.approx(1.0)
    assert sum(est.posterior.values()) == pytest.approx(1.0)
    again = estimate_style(pop, first_decisions(dec[dec["driver_id"] == "D05"], 6), n_bootstrap=50, seed=1)
    assert again == est  # seeded


@pytest.mark.slow
def test_personalize_uses_only_the_first_k_decisions_and_leaves_a_complete_run(study: Workspace) -> None:
    res = _run(
        study,
        "--driver",
        "D03",
        "--decisions",
        "5",
        "--from",
        "style",
        "--fine-tune",
        "--run-id",
        "p5",
        "--json",
        *TINY,
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    dec = study.read_table("analysis", "decisions")
    expected = decision_order(dec[dec["driver_id"] == "D03"])[:5]
    folder = study.runs_dir / "p5"
    config = json.loads((folder / "config.json").read_text())
    assert config["kind"] == "personalized" and config["decisions"] == 5
    assert config["decision_ids"] == expected
    assert config["target"] == {"kind": "driver", "name": "D03"}
    assert config["base"]["from"] == "style" and config["base"]["style"] == out["style"]["style"]
    assert "D03" not in config["base"]["drivers"]
    assert out["style"]["style"] in ("Defensive", "Normal", "Aggressive")
    assert 0 < out["style"]["confidence"] <= 1
    assert out["later_decisions"]["n_decisions"] == 18 - 5  # scored on the decisions it did not see
    for name in (
        "config.json",
        "status.json",
        "metrics.jsonl",
        "weights.pt",
        "checkpoint.pt",
        "evaluation.json",
        "base_weights.pt",
        "personalize.json",
    ):
        assert (folder / name).exists(), name
    assert json.loads((folder / "status.json").read_text())["state"] == "done"
    assert len((folder / "metrics.jsonl").read_text().splitlines()) == 40

    runs = CliRunner().invoke(app, ["runs", "-w", str(study.root), "--json"])
    assert any(r["run_id"] == "p5" and r["state"] == "done" for r in json.loads(runs.stdout)["runs"])
    ev = CliRunner().invoke(app, ["evaluate", "p5", "-w", str(study.root), "--json"])
    assert ev.exit_code == 0, ev.output
    # scored on the decisions it was not given, its comparators fitted on the same K (issue 48)
    evaluation = json.loads((folder / "evaluation.json").read_text())
    assert evaluation["scored_on"] == "held out: the 13 decisions not given"
    assert evaluation["split"] == {"given": 5, "held_out": 13} and evaluation["n_decisions_members"] == 13
    assert {r["who"] for r in evaluation["summary"]} >= {"agent", "greedy", "imitation", "driver"}
    from rl.runs import personalized_split

    split = personalized_split(dec, ["D03"], expected)
    assert set(split["given"]["decision_id"]) == set(expected)
    assert not set(split["scored"]["decision_id"]) & set(expected)
    assert (
        personalized_split(dec, ["D03"], decision_order(dec[dec["driver_id"] == "D03"]))["scored_on"]
        == "in-sample: all 18 decisions given"
    )
    if importlib.util.find_spec("onnxruntime"):
        exp = CliRunner().invoke(app, ["export", "p5", "-w", str(study.root), "--json"])
        assert exp.exit_code == 0, exp.output
    again = CliRunner().invoke(app, ["train", "--resume", "p5", "-w", str(study.root)])
    assert again.exit_code == 1 and "was personalised" in again.stderr  # a resume would train on all its data


@pytest.mark.slow
def test_a_second_run_with_the_same_base_reuses_it(study: Workspace) -> None:
    a = _run(study, "--driver", "D04", "--decisions", "3", "--from", "fit", "--run-id", "b1", "--json", *TINY)
    b = _run(study, "--driver", "D04", "--decisions", "6", "--from", "fit", "--run-id", "b2", "--json", *TINY)
    assert a.exit_code == 0 and b.exit_code == 0, a.output + b.output
    assert json.loads(b.stdout)["base"]["reused_from"] == "b1"
    wa = torch.load(study.runs_dir / "b1" / "base_weights.pt", weights_only=True)
    wb = torch.load(study.runs_dir / "b2" / "base_weights.pt", weights_only=True)
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_the_population_base_is_every_other_driver(study: Workspace) -> None:
    res = _run(study, "--driver", "D06", "--decisions", "6", "--from", "population", "--run-id", "s6", "--json", *TINY)
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["base"]["from"] == "population" and out["base"]["drivers"] == ["D01", "D02", "D03", "D04", "D05"]


@pytest.mark.slow
def test_the_fitted_base_is_the_candidate_that_agrees_best_and_every_candidate_is_kept(study: Workspace) -> None:
    # choose by agreement however sure the style is, and take the chosen base as it is
    always = ["--from", "fit", "--min-confidence", "1.01", "--no-fine-tune"]
    res = _run(study, "--driver", "D02", "--decisions", "6", *always, "--run-id", "f6", "--json", *TINY)
    assert res.exit_code == 0, res.output
    base = json.loads(res.stdout)["base"]
    cands = base["candidates"]
    assert set(cands) == {"style Defensive", "style Normal", "style Aggressive", "population"}
    assert cands[base["chosen"]]["agreement"] == max(c["agreement"] for c in cands.values())
    assert base["drivers"] == cands[base["chosen"]]["drivers"] and "D02" not in base["drivers"]
    for name, c in cands.items():  # the others' weights kept, so the next personalisation reuses them
        assert name == base["chosen"] or (study.runs_dir / "f6" / "bases" / f"{c['key']}.pt").exists()
    folder = study.runs_dir / "f6"  # with --no-fine-tune the agent is the chosen base as it is
    wb, wa = (torch.load(folder / n, weights_only=True) for n in ("base_weights.pt", "weights.pt"))
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    assert json.loads((folder / "status.json").read_text())["state"] == "done"
    again = _run(study, "--driver", "D02", "--decisions", "4", *always, "--run-id", "f4", "--json", *TINY)
    assert again.exit_code == 0, again.output
    assert all(c.get("reused_from") == "f6" for c in json.loads(again.stdout)["base"]["candidates"].values())
    text = _run(study, "--driver", "D02", "--decisions", "5", *always, "--run-id", "f5", *TINY)
    assert text.exit_code == 0, text.output
    assert "chosen by agreement with the 5 decisions" in text.stdout and "as it is" in text.stdout
    sure = _run(
        study,
        "--driver",
        "D02",
        "--decisions",
        "6",
        "--from",
        "fit",
        "--no-fine-tune",
        "--run-id",
        "f6s",
        "--json",
        *TINY,
    )
    assert sure.exit_code == 0, sure.output
    out = json.loads(sure.stdout)
    if out["style"]["confidence"] >= 0.8:  # a confident style's agent is taken as assigned
        assert out["base"]["chosen"] == f"style {out['style']['style']}" and "candidates" not in out["base"]


def test_fine_tuning_when_unsure_follows_the_styles_confidence() -> None:
    from rl.personalize.agents import PersonalizeSettings, personalised_agent

    ps = PersonalizeSettings(method="unsure", min_confidence=0.8)
    assert ps.method_for(0.8) == "none" and ps.method_for(0.79) == "finetune"
    assert ps.resolved(0.5).method == "finetune" and ps.resolved(0.5).min_confidence == 0.8
    assert PersonalizeSettings(method="finetune").method_for(0.99) == "finetune"
    assert PersonalizeSettings(method="none").method_for(0.1) == "none"
    with pytest.raises(ValueError, match="resolve it first"):
        personalised_agent({}, [], [], None, None, ps)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    "flags, min_conf, requested, tuned",
    [
        ([], "1.01", "none", False),  # the default: the base as it is, however unsure the style
        pytest.param(["--no-fine-tune"], "1.01", "none", False, marks=pytest.mark.slow),  # the default, spelt out
        (["--fine-tune"], "0", "finetune", True),
        (["--fine-tune-unsure"], "1.01", "unsure", True),  # never sure above 1: it fine-tunes
        pytest.param(
            ["--fine-tune-unsure"], "0", "unsure", False, marks=pytest.mark.slow
        ),  # always sure at 0: the base as it is
    ],
)
def test_fine_tune_flags_and_the_unsure_rule(
    study: Workspace, flags: list[str], min_conf: str, requested: str, tuned: bool
) -> None:
    run_id = f"u-{requested}-{len(flags)}-{min_conf.replace('.', '')}"
    res = _run(
        study,
        "--driver",
        "D01",
        "--decisions",
        "4",
        "--min-confidence",
        min_conf,
        *flags,
        "--run-id",
        run_id,
        "--json",
        *TINY,
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["fine_tuned"] is tuned and out["method"] == ("finetune" if tuned else "none")
    folder = study.runs_dir / run_id
    config = json.loads((folder / "config.json").read_text())
    assert config["personalize"]["method"] == requested and config["method"] == out["method"]
    assert len((folder / "metrics.jsonl").read_text().splitlines()) == (40 if tuned else 0)
    if requested == "unsure":  # the run says why
        assert ("unsure: confidence" if tuned else "sure: confidence") in out["message"]


@pytest.mark.parametrize(
    "args, message",
    [
        (["--driver", "D99"], "no driver 'D99' in the analysis"),
        (["--driver", "D01", "--decisions", "19"], "--decisions 19: the driver has 18 decisions"),
        (["--driver", "D01", "--from", "fleet"], "unknown --from 'fleet'"),
        (["--driver", "D01", "--fine-tune-unsure", "--fine-tune"], "--fine-tune-unsure and --fine-tune: choose one"),
    ],
)
def test_errors_are_one_line(study: Workspace, args: list[str], message: str) -> None:
    res = _run(study, *args, *TINY)
    assert res.exit_code == 1
    err = res.stderr.strip()
    assert err.startswith("error: ") and message in err and "Traceback" not in res.output
    assert len(err.splitlines()) == 1


def test_no_analysis_is_one_line(tmp_path) -> None:
    res = _run(Workspace(tmp_path), "--driver", "D01")
    assert (
        res.exit_code == 1 and res.stderr.strip() == f"error: no analysis in {tmp_path}: run `laneprint analyze` first"
    )


def test_agreement_is_the_balanced_accuracy_on_the_recorded_states() -> None:
    from rl.personalize.agents import agreement, best_fit
    from rl.problem.env import approaches_from_decisions
    from rl.problem.rewards import CHANGE, KEEP

    approaches, _ = approaches_from_decisions(_decisions().query("driver_id == 'D01'"))
    always, never = (lambda s: np.full(len(s), CHANGE)), (lambda s: np.full(len(s), KEEP))
    assert agreement(always, approaches) == agreement(never, approaches) == 0.5
    assert best_fit({"style:A": 0.7, "style:B": 0.8, "population": 0.75}, {"style:A": 0.9, "style:B": 0.1}) == "style:B"
    # a tie goes to the style the bootstrap gives most, the population last
    assert best_fit({"style:A": 0.8, "style:B": 0.8, "population": 0.8}, {"style:A": 0.3, "style:B": 0.7}) == "style:B"


@pytest.mark.slow
def test_the_curve_scores_every_policy_and_the_fitted_base(study: Workspace, monkeypatch) -> None:
    from rl.personalize.agents import PersonalizeSettings

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from personalize_curve import ALL, CurveSettings, driver_curve  # the benchmark's harness
    from rl.problem.env import formulation_config
    from rl.settings import DQNSettings

    dec = study.read_table("analysis", "decisions")
    env = formulation_config(ReferenceLines.paper("Normal"), "decisions")
    dqn = DQNSettings(seed=0, episodes=60, episodes_per_approach=0.0, num_envs=8, batch_size=64, learning_starts=100)
    variants = {
        "personalised": PersonalizeSettings(base="fit", method="finetune", min_episodes=30, max_episodes=40),
        "as is": PersonalizeSettings(base="fit", method="none"),
        "unsure, never sure": PersonalizeSettings(
            base="fit", method="unsure", min_confidence=1.01, min_episodes=30, max_episodes=40
        ),
        "unsure, always sure": PersonalizeSettings(base="fit", method="unsure", min_confidence=0.0),
    }
    res = driver_curve(
        dec,
        "D05",
        ["D01", "D02", "D03", "D04", "D06"],
        env,
        dqn,
        CurveSettings(ks=(3, ALL), variants=variants),
        stored_settings(study),
    )
    cols = {c for c in res["states"].columns if c.startswith("action_")}
    assert {
        f"action_{p}"
        for p in ("personalised", "as is", "style", "population", "scratch", "imitation_k", "imitation_pop_k")
    } <= cols
    assert list(res["styles"]["k"]) == ["3", "all"]
    assert res["styles"]["fit_base"].str.match(r"style:|population").all()
    s = res["states"]  # 'unsure' is 'none' when the style is sure, 'finetune' (the same seed) when it is not
    assert s["action_unsure, always sure"].equals(s["action_as is"])
    assert s["action_unsure, never sure"].equals(s["action_personalised"])


def test_the_benchmark_reads_the_unsure_variant(monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from personalize import parse_variants

    v = parse_variants("none:fit,unsure:fit,unsure:fit:min_confidence=0.9")
    assert list(v) == ["personalised", "personalised[unsure/fit]", "personalised[unsure/fit min_confidence=0.9]"]
    assert v["personalised[unsure/fit]"].method == "unsure" and v["personalised[unsure/fit]"].base == "fit"
    assert v["personalised[unsure/fit min_confidence=0.9]"].min_confidence == 0.9


# --- the blend (--from blend): every candidate's advantage, weighted ------------------------------------------------


def test_the_blended_network_is_the_weighted_sum_of_its_parts() -> None:
    from rl.learners.dqn import q_network
    from rl.personalize.agents import blended_network

    torch.manual_seed(0)
    nets, coefs = [q_network((16, 8), 9) for _ in range(3)], [0.5, 0.2, 1.3]
    wide = q_network((48, 24), 9)
    wide.load_state_dict(blended_network([(n.state_dict(), c) for n, c in zip(nets, coefs)]))
    x = torch.rand(64, 9)
    with torch.no_grad():
        assert torch.allclose(wide(x), sum(c * n(x) for n, c in zip(nets, coefs)), atol=1e-5)


def test_blend_weights_are_the_shares_times_the_agreement() -> None:
    from rl.personalize.agents import PersonalizeSettings, blend_weights

    fits = {"style A": 0.8, "style B": 0.6, "population": 0.7}
    shares = {"style A": 0.75, "style B": 0.25}
    assert PersonalizeSettings().base == "blend" and PersonalizeSettings().blend_population == 0.4  # the default
    w = blend_weights(PersonalizeSettings(base="blend", blend_population=0.2), shares, fits)
    raw = {"style A": 0.8 * 0.75 * 0.8, "style B": 0.8 * 0.25 * 0.6, "population": 0.2 * 0.7}
    assert w == pytest.approx({n: v / sum(raw.values()) for n, v in raw.items()})
    prior = blend_weights(PersonalizeSettings(base="blend", blend_fit_power=0.0), shares, fits)
    assert prior == pytest.approx({"style A": 0.45, "style B": 0.15, "population": 0.4})
    equal = blend_weights(PersonalizeSettings(base="blend", blend_prior="equal", blend_fit_power=0.0), shares, fits)
    assert equal == pytest.approx(dict.fromkeys(fits, 1 / 3))
    sure = blend_weights(PersonalizeSettings(base="blend"), {"style A": 1.0, "style B": 0.0}, fits)
    assert sure["style B"] == 0.0 and sum(sure.values()) == pytest.approx(1.0)
    with pytest.raises(Exception, match="unknown blend prior"):
        PersonalizeSettings(base="blend", blend_prior="vote")


@pytest.mark.slow
def test_the_blend_is_a_run_that_acts_on_the_weighted_advantages(study: Workspace) -> None:
    from rl.learners.dqn import q_network
    from rl.personalize.agents import advantages
    from rl.problem.env import EnvConfig, approaches_from_decisions, observation, observation_names
    from rl.problem.scene import Scene
    from rl.settings import DQNSettings

    res = _run(study, "--driver", "D03", "--decisions", "6", "--run-id", "bl6", "--json", *TINY)  # the default
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    base = out["base"]
    assert base["from"] == "blend" and base["chosen"] == "blend" and out["method"] == "none"
    assert "D03" not in base["drivers"]
    cands = base["candidates"]
    assert set(cands) == {"style Defensive", "style Normal", "style Aggressive", "population"}
    assert sum(base["weights"].values()) == pytest.approx(1.0) and base["weights"]["population"] > 0
    folder = study.runs_dir / "bl6"
    config = json.loads((folder / "config.json").read_text())
    used = [n for n, w in base["weights"].items() if w > 0]
    assert config["dqn"]["hidden"] == [128 * len(used)] * 3 == base["hidden"]
    # the run's network acts on sum_i weight_i * advantage_i / spread_i of the candidates kept under bases/
    env, dqn = EnvConfig.from_dict(config["env"]), DQNSettings(seed=0)
    dec = study.read_table("analysis", "decisions")
    recorded, _ = approaches_from_decisions(dec[dec["driver_id"] == "D03"])
    mix = sum(
        base["weights"][n]
        / cands[n]["advantage_std"]
        * advantages(torch.load(folder / "bases" / f"{cands[n]['key']}.pt", weights_only=True), env, dqn, recorded)
        for n in used
    )
    net = q_network(tuple(config["dqn"]["hidden"]), len(observation_names(env)))
    net.load_state_dict(torch.load(folder / "weights.pt", weights_only=True))
    with torch.no_grad():
        q = net(torch.as_tensor(observation(Scene.concat([a.scene for a in recorded]), env))).numpy()
    assert np.allclose(q[:, 0] - q[:, 1], mix, atol=1e-4)
    ev = CliRunner().invoke(app, ["evaluate", "bl6", "-w", str(study.root), "--json"])
    assert ev.exit_code == 0, ev.output
    if importlib.util.find_spec("onnxruntime"):
        exp = CliRunner().invoke(app, ["export", "bl6", "-w", str(study.root), "--json"])
        assert exp.exit_code == 0, exp.output
    text = _run(study, "--driver", "D03", "--decisions", "5", "--from", "blend", "--run-id", "bl5", *TINY)
    assert text.exit_code == 0, text.output
    assert "blend weights" in text.stdout and "blend of" in text.stdout
    assert all(
        c.get("reused_from")
        for c in json.loads(  # every candidate kept (bl6's, or an earlier run's)
            (study.runs_dir / "bl5" / "config.json").read_text()
        )["base"]["candidates"].values()
    )


@pytest.mark.slow
def test_the_curve_scores_the_blend(study: Workspace, monkeypatch) -> None:
    from rl.personalize.agents import PersonalizeSettings

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from personalize import parse_variants
    from personalize_curve import ALL, CurveSettings, driver_curve
    from rl.problem.env import formulation_config
    from rl.settings import DQNSettings

    v = parse_variants("none:blend,none:blend:blend_prior=equal;blend_fit_power=0")
    assert (
        v["personalised"].base == "blend"
        and v["personalised[none/blend blend_prior=equal blend_fit_power=0]"].blend_prior == "equal"
    )
    dec = study.read_table("analysis", "decisions")
    env = formulation_config(ReferenceLines.paper("Normal"), "decisions")
    dqn = DQNSettings(seed=0, episodes=60, episodes_per_approach=0.0, num_envs=8, batch_size=64, learning_starts=100)
    res = driver_curve(
        dec,
        "D04",
        ["D01", "D02", "D03", "D05", "D06"],
        env,
        dqn,
        CurveSettings(
            ks=(3, ALL),
            variants={
                "personalised": PersonalizeSettings(base="blend"),
                "equal": PersonalizeSettings(base="blend", blend_prior="equal"),
            },
        ),
        stored_settings(study),
    )
    assert res["states"]["action_personalised"].notna().all() and res["states"]["action_equal"].notna().all()
    w = res["styles"][[c for c in res["styles"] if c.startswith("blend[personalised]")]]
    assert len(w.columns) == 4 and np.allclose(w.sum(axis=1), 1.0)


def test_a_new_drivers_style_from_the_headway_it_kept_by_its_kth_press() -> None:
    from tests.clustering.test_clustering_selection import acceptance_table
    from laneprint.errors import UserError

    dec, truth = acceptance_table()  # presses every 60 s in session r<d> of driver D<d>
    keep_s = {"Defensive": 3.0, "Normal": 1.8, "Aggressive": 1.0}
    rng = np.random.default_rng(0)
    eps = pd.DataFrame(
        [
            {
                "driver_id": d,
                "session_id": f"r{int(d[1:])}",
                "episode_id": f"{d}:f{i}",
                "t_start_s": 30.0 * i,
                "duration_s": 5.0,
                "ego_v_mps": 20.0,
                "thw_s": keep_s[s] * np.exp(rng.normal(0, 0.1)),
            }
            for d, s in truth.items()
            for i in range(40)
        ]
    )
    # D00 (Defensive) tailgates only after its 6th press (at 300 s): those episodes are not yet driven
    late = (eps["driver_id"] == "D00") & (eps["t_start_s"] > 300)
    eps.loc[late, "thw_s"] = 0.8
    settings = AnalysisSettings(features="following", feature_indicators=("thw_follow",))
    others = [d for d in truth if d != "D00"]
    pop = fit_population(dec, others, settings, eps)
    first6 = first_decisions(dec[dec["driver_id"] == "D00"], 6)
    est = estimate_style(pop, first6, n_bootstrap=50, seed=1, following=eps)
    assert est.style == "Defensive" and est.confidence == pytest.approx(1.0)
    # with every episode (its later tailgating too) it would read otherwise
    everything = estimate_style(pop, dec[dec["driver_id"] == "D00"], n_bootstrap=0, following=eps)
    assert everything.style != "Defensive"
    with pytest.raises(UserError, match="no defined value of thw_follow"):
        estimate_style(pop, first6, n_bootstrap=0)  # no episodes given


def test_personalisation_reports_its_phases_with_their_own_start(study: Workspace, monkeypatch) -> None:
    """Progress of a personalisation (issue 48, item 2): 'phase i/n' on the command line's bar; status.json
    carries the phase, the count and the phase's start (the dashboard's time estimate); done clears them."""
    from rl.learners.dqn import DQNSettings
    from rl.personalize.settings import PersonalizeSettings
    from rl.personalize.store import personalize
    from rl.runs import RunWriter

    written: list[dict] = []
    original = RunWriter.status

    def record(self, state, episode, message="", force=True):
        original(self, state, episode, message, force)
        written.append(json.loads((self.folder / "status.json").read_text()))

    monkeypatch.setattr(RunWriter, "status", record)
    messages: list[str] = []
    dqn = DQNSettings(num_envs=8, batch_size=64, learning_starts=100)
    personalize(
        study,
        "D01",
        4,
        PersonalizeSettings(base="population", method="finetune"),
        dqn,
        episodes=40,
        base_episodes=60,
        seed=7,
        run_id="phases",
        progress=lambda d, t, m="": messages.append(m),
    )  # seed 7: no base to reuse
    phases = [m.split(":")[0] for m in dict.fromkeys(messages)]
    assert phases[0] == "phase 1" and "phase 1/4" in phases and "phase 4/4" in phases
    assert any(m.startswith("phase 2/4: base (population): episode") for m in messages)
    assert any(m.startswith("phase 3/4: personalised: episode") for m in messages)
    running = [s for s in written if s["state"] == "running"]
    assert [s["phase"] for s in running] == sorted(s["phase"] for s in running)
    assert {s["phase_name"] for s in running} == {
        "training the base agent (population)",
        "personalising on 4 decisions",
        "evaluating",
    }
    assert all(s["phases"] == 4 and s["phase_started_at"] >= s["started_at"] for s in running)
    assert written[-1]["state"] == "done" and "phase" not in written[-1]
