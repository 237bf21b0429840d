"""`laneprint run PATH...`: the whole pipeline end to end.

Ingest the logs, analyse the workspace (indicators, fits, styles), then train and
evaluate one agent per style found (as one fleet, `rl/fleet/batch.py`), and say how to open the dashboard. Each stage
is the same function its own command calls, so `run` adds no behaviour of its own.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console

from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt, progress_bar, run_command
from laneprint.errors import UserError
from laneprint.workspace import Workspace
from indicators.settings import AnalysisSettings
from laneprint.options import Section, Settings, configurable
from rl.settings import DQNSettings


def run_pipeline(
    paths: list[Path],
    workspace: Path,
    driver: str | None,
    mapping: Path | None,
    train: bool,
    episodes: int | None,
    seed: int,
    show_progress: bool,
    analysis_settings: Any = None,
    dqn_settings: Any = None,
) -> dict[str, Any]:
    """Ingest -> analyze -> train and evaluate one agent per style; a JSON-ready report (settings: the
    `[analysis]` and `[dqn]` tables of a config file, seeded by `seed`)."""
    from dataclasses import replace

    from clustering.pipeline import analyze
    from ingest.cli import ingest_result
    from indicators.settings import AnalysisSettings

    ingest = ingest_result(paths, driver, mapping, workspace, show_progress)
    ws = Workspace(workspace)
    if ws.recordings().empty:
        raise UserError(
            f"no recordings could be stored from {', '.join(map(str, paths))}; see the reasons above "
            "(`laneprint ingest --json` lists them)"
        )
    with progress_bar(show_progress) as progress:
        analysis = analyze(ws, replace(analysis_settings or AnalysisSettings(), random_state=seed), progress)
    runs = []
    if train:
        from rl.fleet.runs import create_fleet, train_fleet
        from rl.runs import Target

        overrides = {"seed": seed} | ({"episodes": episodes, "episodes_per_approach": 0.0} if episodes else {})
        targets = [Target("style", style) for style in analysis["styles"]]
        fleet = create_fleet(
            ws, targets, [seed], replace(dqn_settings or DQNSettings(), **overrides)
        )  # the styles' agents, batched
        with progress_bar(show_progress) as progress:
            runs = train_fleet(ws, fleet["fleet_id"], progress=progress)["summaries"]
    return {
        "workspace": str(ws.root),
        "ingest": ingest,
        "analysis": analysis,
        "runs": runs,
        "dashboard": f"{_laneprint_exe()} dashboard --workspace {ws.root}",
    }


def _laneprint_exe() -> str:
    """`laneprint` when the shell finds this one, else its full path (a virtual environment not activated)."""
    import shutil
    import sys

    mine = Path(sys.executable).with_name("laneprint")
    found = shutil.which("laneprint")
    return "laneprint" if found and Path(found).resolve() == mine.resolve() else str(mine)


def render_run(result: dict[str, Any], console: Console) -> None:
    """Each stage's own summary, then where to look next."""
    from clustering.cli import render as render_analysis
    from ingest.cli import render_ingest

    render_ingest(result["ingest"], console)
    render_analysis(result["analysis"], console)
    if result["runs"]:
        from rl.cli import summary_table

        for run in result["runs"]:
            console.print(
                f"run {run['run_id']}: {run['state']}, {run.get('target', '')}, reward "
                f"{run.get('reward', '')}, {run.get('episodes', '?')} episodes",
                highlight=False,
            )
            if run.get("evaluation"):
                console.print(summary_table(run["evaluation"], f"{run['target']} against its typical driver"))
    console.print(f"open the dashboard: {result['dashboard']}", markup=False, highlight=False)


@configurable("run", Section("analysis", AnalysisSettings, options=False), Section("dqn", DQNSettings, options=False))
def run_command_cli(
    settings: Settings,
    paths: Annotated[list[Path], typer.Argument(help="Log files or folders (e.g. sample_logs).")],
    driver: Annotated[Optional[str], typer.Option("--driver", help="Driver id for files that carry none.")] = None,
    mapping: Annotated[
        Optional[Path], typer.Option("--mapping", help="Name/unit mapping file (docs: your own study).")
    ] = None,
    train: Annotated[bool, typer.Option("--train/--no-train", help="Train and evaluate one agent per style.")] = True,
    episodes: Annotated[
        Optional[int], typer.Option("--episodes", help="Training episodes per agent (default: the trainer's).")
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the clustering and the training.")] = 0,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Ingest PATHs, analyze, and train/evaluate one agent per style."""
    run_command(
        lambda: run_pipeline(
            paths, workspace, driver, mapping, train, episodes, seed, not as_json, settings.analysis, settings.dqn
        ),
        as_json,
        render_run,
    )
