"""The `laneprint` command line: wires the stages together.

Each stage owns its command in its own package (`<stage>/cli.py`); this module
only registers them, plus `run`, which chains ingest and analysis (and training
when asked).
"""

from __future__ import annotations

import typer

from clustering.cli import analyze_command
from laneprint.app.check_cli import check_command
from dashboard.cli import dashboard_command
from ingest.cli import ingest_command
from laneprint.app.simulator.cli import simulate_command
from laneprint.app.pipeline_cli import run_command_cli
from laneprint.app.report_cli import report_command
from rl.cli import (
    annotate_command,
    crossval_command,
    evaluate_command,
    export_command,
    personalize_command,
    runs_command,
    train_command,
)
from rl.drive.cli import drive_command

app = typer.Typer(
    name="laneprint",
    help="Driver-in-the-loop pipeline for personalised automated lane changes.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,  # help texts are plain: "[ray]" and "[dqn]" are words, not markup
)

app.command(
    "simulate",
    help="Generate a driver-in-the-loop study (CSV and MCAP logs): synthetic, Eclipse SUMO with --engine sumo, or highway-env with --engine highway.",
)(simulate_command)
app.command("ingest", help="Read, validate and store simulator logs in the workspace.")(ingest_command)
app.command("analyze", help="Indicators at decisions, per-driver fits and driving styles.")(analyze_command)
app.command(
    "train",
    help="Train an agent for a style or a driver (learner: --learner), or a fleet of them (--drivers/--styles).",
)(train_command)
app.command(
    "personalize", help="An agent for one driver from its first K decisions, starting from the other drivers' agent."
)(personalize_command)
app.command("evaluate", help="Evaluate a trained run against the drivers' decisions.")(evaluate_command)
app.command("crossval", help="Held-out figures: agent vs greedy vs imitation, by session folds.")(crossval_command)
app.command("export", help="Export a trained run's policy as ONNX, documented and checked with onnxruntime.")(
    export_command
)
app.command("annotate", help="Write a recording again as MCAP with the agent's, greedy's and driver's decisions.")(
    annotate_command
)
app.command("drive", help="Let a trained agent make the ego's lane changes in SUMO traffic; MCAP logs of the drive.")(
    drive_command
)
app.command("runs", help="List the training runs and their state (interrupted: killed, resumable).")(runs_command)
app.command("check", help="Verify the workspace; --repair removes leftovers of interrupted writes.")(check_command)
app.command("report", help="The study in one self-contained HTML file (figures, tables as CSV beside it).")(
    report_command
)
app.command("dashboard", help="Serve the Streamlit dashboard.")(dashboard_command)
app.command("run", help="Everything end to end: ingest PATHs, analyze, and train/evaluate the styles.")(run_command_cli)


def main() -> None:
    """Entry point: the app, with a last guard so a user's mistake never shows a traceback."""
    import sys

    from laneprint.errors import SettingError, UserError

    try:
        app()
    except UserError as exc:
        print(f"error: {exc.as_flags() if isinstance(exc, SettingError) else exc}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
