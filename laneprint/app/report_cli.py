"""`laneprint report [--out FILE.html]`: the command line of `dashboard.report` (the study in one HTML file)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from dashboard.report import write_report
from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt, console, err_console, visible
from laneprint.errors import UserError
from laneprint.options import configurable
from laneprint.workspace import Workspace


@configurable("report")
def report_command(
    workspace: WorkspaceOpt = DEFAULT_WS,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            help="The HTML file to write (default <workspace>/report.html); tables (CSV) and figures "
            "(Plotly JSON; SVG with the report extra, kaleido) go to <name>_files/ beside it.",
        ),
    ] = None,
    no_assets: Annotated[bool, typer.Option("--no-assets", help="Only the HTML file.")] = False,
    no_svg: Annotated[
        bool,
        typer.Option(
            "--no-svg",
            help="No SVG of the figures (kaleido takes 10-15 s to start "
            "its browser, and more for hundreds of figures).",
        ),
    ] = False,
    as_json: JsonOpt = False,
) -> None:
    """The study in one self-contained HTML file: data, fits and flags, styles, every run's figures."""
    try:
        ws = Workspace(workspace)
        if not ws.root.is_dir():
            raise UserError(f"no workspace at {ws.root}")
        result = write_report(ws, out, assets=not no_assets, svg=not no_svg)
    except UserError as exc:
        err_console.print(f"error: {visible(str(exc))}", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(1) from None
    if as_json:
        sys.stdout.write(json.dumps(result) + "\n")
        return
    written = result.get("written") or {}
    console.print(
        f"report written to [bold]{result['report']}[/bold] ({result['bytes'] / 1e6:.1f} MB, "
        f"{result['figures']} figures, {result['tables']} tables, {result['seconds']} s)"
        + (f"; tables and figures in {result['assets']}" if result["assets"] else "")
        + (f" ({len(written['svg'])} figures as SVG)" if written.get("svg") else "")
        + (f"; {written['svg_note']}" if written.get("svg_note") else ""),
        highlight=False,
    )
