"""`laneprint train`, `evaluate`, `crossval`, `export` and `annotate`."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console
from rich.table import Table

from laneprint.cliutil import DEFAULT_WS, BackendOpt, JsonOpt, RayAddressOpt, WorkspaceOpt, progress_bar, run_command
from laneprint.errors import UserError
from laneprint.options import Section, Settings, configurable
from laneprint.workspace import Workspace
from rl.problem.rewards import REWARDS
from rl.evaluation.settings import CrossvalSettings
from rl.personalize.settings import PersonalizeSettings
from rl.settings import (
    DEFAULT_REWARD,
    LEARNERS,
    OBSERVATIONS,
    SCENES,
    AutoSettings,
    DQNSettings,
    TreeQSettings,
    default_learner,
    trees_fit,
)

#: older names of DQNSettings' options, still accepted
DQN_ALIASES = {
    "learning_rate": ("--lr",),
    "learning_rate_end": ("--lr-end",),
    "target_update_episodes": ("--target-update",),
}

RewardOpt = Annotated[
    Optional[str],
    typer.Option(
        "--reward",
        hidden=True,
        help=f"Reward: {', '.join(REWARDS)} (default {DEFAULT_REWARD}; timing with --lines paper).",
    ),
]
ScenesOpt = Annotated[
    Optional[str],
    typer.Option(
        "--scenes", hidden=True, help=f"Where episodes come from: {' or '.join(SCENES)} (default: the reward's own)."
    ),
]
ObservationOpt = Annotated[
    Optional[str],
    typer.Option(
        "--observation",
        hidden=True,
        help=f"What the agent sees: {' or '.join(OBSERVATIONS)} (default: the reward's own).",
    ),
]
OtherSideOpt = Annotated[
    Optional[bool],
    typer.Option(
        "--other-side/--driver-side-only",
        hidden=True,
        help="Recorded scenes: also replay the side a middle-lane driver did not take, as approaches without a "
        "press (default), or only the driver's side. No effect on two lanes.",
    ),
]

LearnerOpt = Annotated[
    Optional[str],
    typer.Option(
        "--learner",
        help=f"Who learns the Q function: {', '.join(LEARNERS)} ('auto': per target the one of the "
        "DQN and the trees that agrees better across inner folds of its own sessions; 'dqn': the "
        "study's DQN; 'trees': fitted Q iteration with boosted trees on the recorded approaches). "
        "Default: 'auto' for one style or driver on the decisions reward with recorded scenes, "
        "'dqn' for fleets and the other formulations (the paper's among them).",
    ),
]


def dqn_as_asked(settings: Settings) -> tuple[DQNSettings, int | None]:
    """The `[dqn]` settings, and the episodes asked for (None: not asked). Asked, they are the number to
    train, not the per-approach rule's ceiling."""
    dqn = settings.dqn
    if "episodes" not in settings.given("dqn"):
        return dqn, None
    return replace(dqn, episodes_per_approach=0.0), dqn.episodes


def learner_settings(
    learner: str, dqn: DQNSettings, trees: TreeQSettings | None = None, auto: AutoSettings | None = None
) -> DQNSettings | TreeQSettings | AutoSettings:
    """`dqn`, the tree learner's settings, or both to choose from (`auto`'s folds and margin), all with `dqn`'s
    seed (`learner`: a `resolve_learner` name)."""
    if learner == "dqn":
        return dqn
    trees = replace(trees or TreeQSettings(), seed=dqn.seed)
    return trees if learner == "trees" else replace(auto or AutoSettings(), dqn=dqn, trees=trees, seed=dqn.seed)


def resolve_learner(learner: str | None, env: Any, fleet: bool = False) -> str:
    """`--learner` as given, or the default for `env`'s formulation (`rl.settings.default_learner`); a named
    tree learner (alone or in 'auto') must fit the decisions reward on recorded scenes, one target at a time."""
    if learner is None:
        return default_learner(env.reward.name, env.scenes, fleet)
    if learner not in LEARNERS:
        raise UserError(f"unknown --learner {learner!r}: choose one of {', '.join(LEARNERS)}")
    if learner != "dqn" and fleet:
        raise UserError(
            f"--learner {learner} fits one style or driver (fleets train DQN agents): "
            "leave out --drivers/--styles, or use --learner dqn"
        )
    if learner != "dqn" and not trees_fit(env.reward.name, env.scenes):
        raise UserError(
            f"--learner {learner} needs the decisions reward on recorded scenes (the trees fit the "
            f"drivers' recorded presses), not reward {env.reward.name!r} on {env.scenes} scenes: "
            "leave out --reward/--scenes/--lines paper, or use --learner dqn"
        )
    return learner


def _fmt(x: Any, pct: bool = False) -> str:
    if x is None:
        return "-"
    return f"{100 * x:.1f} %" if pct else f"{x:.2f}"


def summary_table(rows: list[dict[str, Any]], title: str) -> Table:
    t = Table(title=title)
    for col in (
        "who",
        "recall",
        "balanced acc.",
        "timing MAE [s]",
        "never",
        "median |err| t_f [s]",
        "median |err| t_nf [s]",
        "median |err| dv_nb [m/s]",
    ):
        t.add_column(col)
    for r in rows:
        t.add_row(
            r["who"],
            _fmt(r["recall"], True),
            _fmt(r["balanced_accuracy"], True),
            _fmt(r["timing_mae_s"]),
            _fmt(r["never_rate"], True),
            *(_fmt(r.get(f"medae_{k}")) for k in ("t_f", "t_nf", "dv_nb")),
        )
    t.caption = (
        "median |err| <indicator>: median |indicator at the policy's change - the reference line at that "
        "speed| (robust to minutes-long TTCs; the means are mae_* in --json, every field defined in 'fields')"
    )
    return t


def _render_eval(ev: dict[str, Any], console: Console) -> None:
    for group in ("typical", "members"):
        rows = ev.get(f"summary_{group}")
        if rows:
            who = ev["typical_driver"] if group == "typical" else ", ".join(ev["drivers"])
            skipped = {k: v for k, v in ev.get(f"skipped_{group}", {}).items() if v}
            console.print(
                summary_table(
                    rows,
                    f"{group}: {who} — {ev[f'n_decisions_{group}']} decisions, "
                    f"{ev[f'n_states_{group}']} states, skipped {skipped or 'none'}",
                )
            )


def _render_fleet(res: dict[str, Any], console: Console) -> None:
    console.print(res["fleet_id"])
    agents = res.get("agents", [])
    t = Table(title=f"fleet {res['fleet_id']}: {res['message']}")
    for col in ("run", "state", "recall", "agent bal. acc.", "greedy", "imitation", "target met"):
        t.add_column(col)
    num = lambda x: None if x is None or x != x else x  # noqa: E731 - NaN (not evaluated) prints as '-'
    for r in agents:
        t.add_row(
            r["run_id"],
            r["state"],
            _fmt(num(r["agent_recall"]), True),
            _fmt(num(r["agent_balanced_accuracy"]), True),
            _fmt(num(r["greedy_balanced_accuracy"]), True),
            _fmt(num(r["imitation_balanced_accuracy"]), True),
            {True: "yes", False: "no"}.get(r["meets_target"], "-"),
        )
    console.print(t)
    met = sum(bool(r["meets_target"]) for r in agents)
    console.print(
        f"{met} of {len(agents)} agents meet the target (recall >= 95 %, balanced accuracy >= greedy + 5 points)",
        highlight=False,
    )


def learning_checks(
    ws: Workspace, targets: list[Any], env: Any, settings: DQNSettings, share: float = 1.0
) -> list[tuple[Any, Any]]:
    """(target, `rl.settings.LearningCheck`) of each target whose run could not learn, or only late, at
    `settings`, checked before training (`share`: the part of the target's approaches a fold's agent
    trains on, in cross-validation)."""
    from rl.settings import approach_steps, decision_counts, learning_check, target_counts

    counts = decision_counts(ws.read_table("analysis", "decisions")) if ws.has_table("analysis", "decisions") else None
    styles = ws.read_table("analysis", "styles") if ws.has_table("analysis", "styles") else None
    out = []
    for target in targets:
        states, presses = target_counts(counts, styles, target.kind, target.name)
        steps, source = approach_steps(env, states, presses)
        resolved = settings.resolved_episodes(
            max(1, round(presses * share)) if presses and env.scenes == "recorded" else None
        )
        check = learning_check(resolved, steps, source)
        if check.verdict:
            out.append((target, check))
    return out


def _warn_learning(checks: list[tuple[Any, Any]], n_targets: int) -> dict[str, Any] | None:
    """Print the learning checks' warning on stderr before the run starts; its JSON form (None: none)."""
    from laneprint.cliutil import err_console

    if not checks:
        return None
    target, check = next(((t, c) for t, c in checks if c.verdict == "never"), checks[0])
    never = sum(c.verdict == "never" for _, c in checks)
    head = (
        ""
        if n_targets == 1
        else f"{never or len(checks)} of {n_targets} agents {'would learn nothing' if never else 'would learn late'}"
        f"; e.g. {target.kind} {target.name}: "
    )
    err_console.print(f"warning: {head}{check.message}", markup=False, highlight=False, soft_wrap=True)
    return {
        "verdict": check.verdict,
        "targets": [f"{t.kind} {t.name}" for t, _ in checks],
        "expected_transitions": round(check.expected),
        "needed_episodes": check.needed_episodes,
        "message": head + check.message,
    }


@configurable(
    "train",
    Section("dqn", DQNSettings, visible=("episodes", "seed"), aliases=DQN_ALIASES),
    Section("trees", TreeQSettings, options=False),
    Section("auto", AutoSettings, options=False),
)
def train_command(
    settings: Settings,
    style: Annotated[
        Optional[str], typer.Option("--style", help="Imitate a style (its typical driver's lines).")
    ] = None,
    driver: Annotated[Optional[str], typer.Option("--driver", help="Imitate one driver (its own lines).")] = None,
    drivers: Annotated[
        Optional[str], typer.Option("--drivers", help="A fleet: one agent per driver, 'all' or ID,ID,...")
    ] = None,
    styles: Annotated[
        Optional[str], typer.Option("--styles", help="A fleet: one agent per style, 'all' or NAME,NAME,...")
    ] = None,
    learner: LearnerOpt = None,
    resume: Annotated[
        Optional[str], typer.Option("--resume", help="Continue an interrupted run from its checkpoint.")
    ] = None,
    reward: RewardOpt = None,
    scenes: ScenesOpt = None,
    observation: ObservationOpt = None,
    other_side: OtherSideOpt = None,
    lines: Annotated[
        str, typer.Option("--lines", hidden=True, help="Reference lines: 'analysis' or 'paper' (Table 1).")
    ] = "analysis",
    run_id: Annotated[
        Optional[str],
        typer.Option("--run-id", hidden=True, help="Id of the new run (default: time-target-reward-seed)."),
    ] = None,
    dt: Annotated[
        Optional[float], typer.Option("--dt", hidden=True, help="Seconds between decisions (default 0.5).")
    ] = None,
    evaluate: Annotated[
        bool, typer.Option("--evaluate/--no-evaluate", hidden=True, help="Evaluate against the drivers at the end.")
    ] = True,
    seeds: Annotated[
        int, typer.Option("--seeds", min=1, hidden=True, help="A fleet: agents per target, seeds --seed, --seed+1, ...")
    ] = 1,
    backend: BackendOpt = "local",
    ray_address: RayAddressOpt = None,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Train an agent for a style or a driver (see --learner), or a fleet of them; prints the run (or fleet) id."""

    def work() -> dict[str, Any]:
        from rl.problem.env import EnvConfig, formulation_config, learner_env  # torch only when the command runs
        from rl.fleet.runs import create_fleet, fleet_targets, is_fleet, train_fleet
        from rl.runs import Target, resolve_lines, train_run

        ws = Workspace(workspace)
        dqn, episodes = dqn_as_asked(settings)
        threads = dqn.threads if "threads" in settings.given("dqn") else None
        fleet_opts: dict[str, Any] = {
            "backend": backend,
            "ray_address": ray_address,
            "threads": threads,
            "evaluate": evaluate,
        }
        if resume:
            if style or driver or drivers or styles:
                raise UserError("--resume takes the run's own target: leave out --style/--driver/--drivers/--styles")
            with progress_bar(not as_json) as progress:
                if is_fleet(ws, resume):
                    return train_fleet(ws, resume, progress=progress, **fleet_opts)
                return train_run(
                    ws, None, None, None, resume=resume, episodes=episodes, evaluate=evaluate, progress=progress
                )
        fleet = drivers is not None or styles is not None
        if sum(x is not None for x in (style, driver, drivers, styles)) != 1:
            raise UserError(
                "give exactly one of --style NAME, --driver ID, --drivers all|ID,... or --styles all|NAME,..."
            )
        if fleet:
            fleet_env = formulation_config(EnvConfig().lines, reward, scenes, observation, lines)
            resolve_learner(learner, fleet_env, fleet=True)
            targets = fleet_targets(ws, drivers, styles)
            warned = _warn_learning(learning_checks(ws, targets, fleet_env, dqn), len(targets))
            record = create_fleet(
                ws,
                targets,
                list(range(dqn.seed, dqn.seed + seeds)),
                dqn,
                reward=reward,
                scenes=scenes,
                observation=observation,
                other_side=other_side,
                lines_source=lines,
                dt_s=dt,
                backend=backend,
                fleet_id=run_id,
            )
            with progress_bar(not as_json) as progress:
                res = train_fleet(ws, record["fleet_id"], progress=progress, **fleet_opts)
            return {**res, "learning_check": warned} if warned else res
        target = Target("style", style) if style else Target("driver", str(driver))
        env = formulation_config(resolve_lines(ws, target, lines), reward, scenes, observation, lines, other_side)
        who = resolve_learner(learner, env)
        env = learner_env(env if dt is None else replace(env, dt_s=dt), who)
        learner_set = learner_settings(who, dqn, settings.trees, settings.auto)
        warned = _warn_learning(learning_checks(ws, [target], env, dqn), 1) if who != "trees" else None
        with progress_bar(not as_json) as progress:
            res = train_run(
                ws, target, env, learner_set, run_id=run_id, lines_source=lines, evaluate=evaluate, progress=progress
            )
        return {**res, "learning_check": warned} if warned else res

    def render(res: dict[str, Any], console: Console) -> None:
        if "fleet_id" in res:
            _render_fleet(res, console)
            return
        console.print(res["run_id"])
        if res.get("learner") == "trees":
            console.print(
                f"{res['state']}: {res['target']}, reward {res['reward']}, tree Q functions fitted in "
                f"{res['wall_s']} s — {res['folder']}",
                highlight=False,
            )
        else:
            console.print(
                f"{res['state']}: {res['target']}, reward {res['reward']}, {res['episodes']} episodes, "
                f"{res['env_steps']} steps in {res['wall_s']} s — {res['folder']}",
                highlight=False,
            )
        if res.get("learner_choice"):
            c = res["learner_choice"]
            console.print(
                f"learner chosen: {c['learner']} (held-out agreement on {c['n_holdout']} of the target's "
                f"{c['n_train']} approaches over {c.get('folds') or 1} inner folds, mean over the sides: "
                + ", ".join(f"{k} {100 * v:.1f} %" for k, v in c["scores"].items())
                + ")",
                highlight=False,
            )
            if c.get("stopped"):
                console.print(f"stopped early: {c['stopped']}", highlight=False)
        if res.get("warning"):
            console.print(f"[yellow]warning:[/yellow] {res['warning']}", highlight=False)
        if res.get("evaluation"):
            console.print(summary_table(res["evaluation"], "against the drivers"))
        if res.get("evaluation_note"):
            console.print(res["evaluation_note"], highlight=False)

    run_command(work, as_json, render)


@configurable("evaluate")
def evaluate_command(
    run_id: Annotated[str, typer.Argument(help="Run to evaluate (see the workspace's runs/).")],
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Evaluate a run against the drivers' recorded decisions (agent, greedy, driver)."""

    def work() -> dict[str, Any]:
        from rl.runs import evaluate_run  # torch only when the command runs

        return evaluate_run(Workspace(workspace), run_id)

    run_command(work, as_json, _render_eval)


def _cv_table(res: dict[str, Any]) -> Table:
    t = Table(
        title=f"held out ({res['folds']} folds by {res['settings']['split']}): {res['target']['kind']} "
        f"{res['target']['name']} — {res['n_decisions_scored']} of {res['n_decisions_total']} decisions scored"
    )
    for col in ("who", "balanced acc. [95 % CI]", "recall", "specificity", "timing MAE [s]", "never"):
        t.add_column(col)
    for r in res["summary"]:
        lo, hi = r["balanced_accuracy_ci"]
        t.add_row(
            r["who"],
            f"{100 * r['balanced_accuracy']:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}]",
            _fmt(r["recall"], True),
            _fmt(r["specificity"], True),
            _fmt(r["timing_mae_s"]),
            _fmt(r["never_rate"], True),
        )
    return t


def _direction_table(res: dict[str, Any]) -> Table | None:
    rows = res.get("summary_by_direction") or []
    if not rows:
        return None
    t = Table(title="by direction of the lane change (target lane to the left / right)")
    for col in ("direction", "who", "decisions", "balanced acc. [95 % CI]", "recall", "timing MAE [s]"):
        t.add_column(col)
    for r in rows:
        lo, hi = r["balanced_accuracy_ci"]
        t.add_row(
            r["direction"],
            r["who"],
            str(r["n_decisions"]),
            f"{100 * r['balanced_accuracy']:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}]",
            _fmt(r["recall"], True),
            _fmt(r["timing_mae_s"]),
        )
    return t


def _render_cv(res: dict[str, Any], console: Console) -> None:
    for r in res.get("results", [res]):
        console.print(_cv_table(r))
        by_dir = _direction_table(r)
        if by_dir is not None:
            console.print(by_dir)
        if r.get("unscored"):
            console.print(f"not scored: {r['unscored']}", highlight=False)
        if r.get("learner") == "auto":
            chosen = [f.get("learner", "?") for f in r.get("per_fold", [])]
            console.print(f"learner chosen per fold (auto): {', '.join(chosen)}", highlight=False)
            stopped = sum(bool(f.get("learner_stopped")) for f in r.get("per_fold", []))
            if stopped:
                console.print(
                    f"chosen before both learners finished (out of reach) in {stopped} of {len(chosen)} "
                    "folds: per_fold[].learner_stopped",
                    highlight=False,
                )
        console.print(f"stored as crossval/{r['crossval_id']}", highlight=False)


@configurable(
    "crossval",
    Section("crossval", CrossvalSettings, visible=("folds", "seed"), aliases={"n_bootstrap": ("--bootstrap",)}),
    Section("dqn", DQNSettings, aliases=DQN_ALIASES),
    Section("trees", TreeQSettings, options=False),
    Section("auto", AutoSettings, options=False),
)
def crossval_command(
    settings: Settings,
    style: Annotated[Optional[str], typer.Option("--style", help="Hold out sessions of a style's drivers.")] = None,
    driver: Annotated[Optional[str], typer.Option("--driver", help="Hold out sessions of one driver.")] = None,
    all_styles: Annotated[bool, typer.Option("--all", help="Every style of the analysis, one result each.")] = False,
    run: Annotated[
        Optional[str], typer.Option("--run", hidden=True, help="Take target and settings from a trained run.")
    ] = None,
    reward: RewardOpt = None,
    scenes: ScenesOpt = None,
    observation: ObservationOpt = None,
    other_side: OtherSideOpt = None,
    learner: LearnerOpt = None,
    lines: Annotated[
        str, typer.Option("--lines", hidden=True, help="'analysis' (refitted per fold) or 'paper' (Table 1).")
    ] = "analysis",
    backend: BackendOpt = "local",
    ray_address: RayAddressOpt = None,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Held-out figures: agent, greedy and imitation scored on sessions none of them was fitted on."""

    def work() -> dict[str, Any]:
        from rl.evaluation.crossval_store import crossval_run, run_crossval, style_names, target_env
        from rl.problem.env import EnvConfig, formulation_config, learner_env
        from rl.runs import Target
        from laneprint.parallel import backend_session

        ws = Workspace(workspace)
        cv = settings.crossval
        dqn, episodes = dqn_as_asked(settings)
        if "seed" not in settings.given("dqn"):  # the folds' seed seeds the agents too
            dqn = replace(dqn, seed=cv.seed)
        where: dict[str, Any] = {"backend": backend, "ray_address": ray_address}
        with backend_session(**where), progress_bar(not as_json) as progress:  # one Ray instance for every target
            if run:
                if style or driver or all_styles:
                    raise UserError("--run takes the run's own target: leave out --style/--driver/--all")
                return crossval_run(ws, run, cv, episodes, progress, **where)
            if sum(x is not None and x is not False for x in (style, driver, all_styles or None)) != 1:
                raise UserError("give exactly one of --style NAME, --driver ID, --all or --run RUN_ID")
            targets = (
                [Target("style", s) for s in style_names(ws)]
                if all_styles
                else [Target("style", style)]
                if style
                else [Target("driver", str(driver))]
            )
            base = formulation_config(EnvConfig().lines, reward, scenes, observation, lines, other_side)
            who = resolve_learner(learner, base)
            base = learner_env(base, who)
            agent = learner_settings(who, dqn, settings.trees, settings.auto)
            if who != "trees":
                _warn_learning(learning_checks(ws, targets, base, dqn, share=(cv.folds - 1) / cv.folds), len(targets))
            results = [
                run_crossval(ws, t, target_env(ws, t, base, lines), agent, cv, lines, progress=progress, **where)
                for t in targets
            ]
        return {"results": results} if all_styles else results[0]

    run_command(work, as_json, _render_cv)


def _render_export(res: dict[str, Any], console: Console) -> None:
    c = res["check"]
    console.print(
        f"exported {res['run_id']} as {res['format']} to {res['folder']} ({', '.join(res['files'])})", highlight=False
    )
    console.print(f"inputs: {', '.join(res['inputs'])}", highlight=False)
    for name, s in c["sets"].items():
        console.print(
            f"check {name}: {s['n_states']} states, max |Q_onnxruntime - Q_torch| = "
            f"{s['max_abs_diff']:.2e} (tolerance {c['tolerance']:g}), actions agree on "
            f"{s['actions_agree']}",
            highlight=False,
        )


@configurable("export")
def export_command(
    run_id: Annotated[str, typer.Argument(help="Run whose policy to export (see the workspace's runs/).")],
    fmt: Annotated[str, typer.Option("--format", help="Model format: onnx.")] = "onnx",
    out: Annotated[
        Optional[Path], typer.Option("--out", help="Output folder (default WORKSPACE/exports/RUN_ID).")
    ] = None,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Export a run's policy as ONNX with its observation documented, checked with onnxruntime."""

    def work() -> dict[str, Any]:
        from rl.deploy.export import export_run  # torch and onnx only when the command runs

        with progress_bar(not as_json) as progress:
            return export_run(Workspace(workspace), run_id, fmt, out, progress)

    run_command(work, as_json, _render_export)


def _render_annotate(res: dict[str, Any], console: Console) -> None:
    console.print(
        f"wrote {res['out']}: recording {res['recording_id']} ({res['session_id']}) with {', '.join(res['topics'])}",
        highlight=False,
    )
    console.print(
        f"{res['steps']} steps of {res['dt_s']:g} s {res['steps_by_status']}; agent says change at "
        f"{res['agent_change_at_presses']} / greedy at {res['greedy_change_at_presses']} of the driver's "
        f"{res['presses']} presses",
        highlight=False,
    )


@configurable("annotate")
def annotate_command(
    run_id: Annotated[str, typer.Argument(help="Run whose decisions to write (see the workspace's runs/).")],
    recording: Annotated[str, typer.Argument(help="Recording id (or a unique prefix, or its session id).")],
    out: Annotated[Path, typer.Option("--out", help="The annotated MCAP file to write.")],
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Write a recording again as MCAP with the agent's, greedy's and driver's decisions at every step."""

    def work() -> dict[str, Any]:
        from rl.deploy.annotate import annotate_recording  # torch only when the command runs

        with progress_bar(not as_json) as progress:
            return annotate_recording(Workspace(workspace), run_id, recording, out, progress)

    run_command(work, as_json, _render_annotate)


@configurable("runs")
def runs_command(
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """List the runs: target, state ('interrupted' when its process died), progress, headline figures."""

    def work() -> dict[str, Any]:
        from rl.runs import list_runs

        ws = Workspace(workspace)
        table = list_runs(ws)
        return {
            "runs": table.astype(object).where(table.notna(), None).to_dict("records"),
            "current_analysis_fingerprint": ws.analysis_fingerprint(),
        }

    def render(res: dict[str, Any], console: Console) -> None:
        t = Table(title=f"{len(res['runs'])} runs")
        for col in ("run", "target", "reward", "state", "episode", "balanced acc.", "analysis", "message"):
            t.add_column(col)
        for r in res["runs"]:
            mark = str(r.get("analysis_label") or "")
            t.add_row(
                r["run_id"],
                f"{r['target_kind']} {r['target']}",
                str(r["reward"]),
                str(r["state"]),
                f"{r['episode'] or 0}/{r['episodes'] or '?'}",
                _fmt(r["balanced_accuracy"], True),
                f"[yellow]{mark}[/yellow]" if r.get("analysis") == "earlier" else mark,
                str(r["message"] or ""),
            )
        console.print(t)
        if any(r.get("analysis") == "earlier" for r in res["runs"]):
            console.print(
                "runs made with an earlier analysis: their styles or lines have changed since; re-run them "
                "(`laneprint train --style NAME` or `--driver ID`)",
                highlight=False,
            )
        if any(r["state"] == "interrupted" for r in res["runs"]):
            console.print("interrupted runs: continue one with `laneprint train --resume RUN_ID`", highlight=False)

    run_command(work, as_json, render)


def _render_personalize(res: dict[str, Any], console: Console) -> None:
    st = res["style"]
    console.print(res["run_id"])
    shares = ", ".join(f"{name} {100 * p:.0f} %" for name, p in st["bootstrap"].items())
    console.print(
        f"style from {res['decisions']} of {res['decisions_available']} decisions: {st['style']}, "
        f"confidence {100 * st['confidence']:.0f} % (bootstrap over the decisions: {shares}; "
        f"posterior {100 * st['posterior'][st['style']]:.0f} %)",
        highlight=False,
    )
    base = res["base"]
    src = f"reused from run {base['reused_from']}" if base.get("reused_from") else f"{base.get('episodes')} episodes"
    chosen = base.get("chosen") or ("population" if base["from"] == "population" else f"style {base['style']}")
    who = "all other drivers" if chosen == "population" else chosen
    if chosen == "blend":
        console.print(
            f"base agent: a blend of {len(base['candidates'])} agents ({len(base['drivers'])} other "
            "drivers: each style's and the population's)",
            highlight=False,
        )
    else:
        console.print(
            f"base agent: {who} ({len(base['drivers'])} drivers, {base['n_approaches']} approaches; {src})",
            highlight=False,
        )
    if base.get("candidates"):
        fits = ", ".join(f"{n} {100 * c['agreement']:.1f} %" for n, c in base["candidates"].items())
        how = "weighted" if chosen == "blend" else "chosen"
        console.print(
            f"{how} by agreement with the {res['decisions']} decisions (balanced accuracy): {fits}", highlight=False
        )
    if base.get("weights"):
        console.print(
            "blend weights (advantages scaled by their spread): "
            + ", ".join(f"{n} {100 * w:.0f} %" for n, w in base["weights"].items()),
            highlight=False,
        )
    console.print(
        f"{res['state']}: {res['message']}, {res['episodes']} episodes in {res['wall_s']} s — {res['folder']}",
        highlight=False,
    )
    later = res.get("later_decisions")
    if later:
        lo, hi = later["balanced_accuracy_ci"]
        console.print(
            f"on the driver's {later['n_decisions']} later decisions (not used): balanced accuracy "
            f"{100 * later['balanced_accuracy']:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}], recall "
            f"{100 * later['recall']:.1f} %, timing MAE {_fmt(later['timing_mae_s'])} s",
            highlight=False,
        )


@configurable(
    "personalize",
    Section("dqn", DQNSettings, aliases=DQN_ALIASES),
    Section("personalize", PersonalizeSettings, visible=("base",), aliases={"base": ("--from",)}),
)
def personalize_command(
    settings: Settings,
    driver: Annotated[str, typer.Option("--driver", help="The driver to personalise for.")],
    decisions: Annotated[
        Optional[int], typer.Option("--decisions", min=1, help="K: its first K decisions in time order (default: all).")
    ] = None,
    fine_tune: Annotated[
        Optional[bool],
        typer.Option(
            "--fine-tune/--no-fine-tune",
            hidden=True,
            help="Fine-tune the base on the K decisions, or not (the default: the base as it is).",
            show_default=False,
        ),
    ] = None,
    fine_tune_unsure: Annotated[
        bool,
        typer.Option(
            "--fine-tune-unsure",
            hidden=True,
            help="Fine-tune only when the style's confidence is below min_confidence (as personalize.method = 'unsure').",
        ),
    ] = False,
    episodes: Annotated[
        Optional[int],
        typer.Option(
            "--episodes",
            min=1,
            hidden=True,
            help="Fine-tuning episodes, when it fine-tunes (default: 60 per decision, 600-3000).",
        ),
    ] = None,
    base_episodes: Annotated[
        Optional[int],
        typer.Option(
            "--base-episodes", min=1, hidden=True, help="Episodes of the base agent (default: the trainer's rule)."
        ),
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of everything random.")] = 0,
    run_id: Annotated[Optional[str], typer.Option("--run-id", hidden=True, help="Id of the new run.")] = None,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """An agent for one driver from its first K decisions, starting from the other drivers' agent."""

    def work() -> dict[str, Any]:
        from rl.personalize.store import check_request, personalize  # torch only when the command runs

        ws = Workspace(workspace)
        check_request(ws, driver, decisions)
        dqn, ps = settings.dqn, settings.personalize
        if fine_tune_unsure and fine_tune is not None:
            raise UserError(f"--fine-tune-unsure and --{'' if fine_tune else 'no-'}fine-tune: choose one")
        if fine_tune_unsure or fine_tune is not None:
            ps = replace(ps, method="unsure" if fine_tune_unsure else "finetune" if fine_tune else "none")
        if "learning_starts" in settings.given("dqn") and "learning_starts" not in settings.given("personalize"):
            ps = replace(ps, learning_starts=min(dqn.learning_starts, 500))
        with progress_bar(not as_json) as progress:
            return personalize(
                ws,
                driver,
                decisions,
                ps,
                dqn,
                episodes=episodes,
                base_episodes=base_episodes,
                seed=seed,
                run_id=run_id,
                progress=progress,
            )

    run_command(work, as_json, _render_personalize)
