"""`laneprint ingest PATH... [--driver ID] [--mapping FILE] [--backend local|ray]`: store logs in the workspace."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from laneprint.cliutil import DEFAULT_WS, BackendOpt, JsonOpt, RayAddressOpt, WorkspaceOpt, progress_bar, run_command
from ingest.limits import IngestLimits
from ingest.mapping import load_mapping
from laneprint.parallel import backend_session
from laneprint.workspace import Workspace
from laneprint.options import configurable

_STYLE = {"ingested": "green", "warning": "yellow", "duplicate": "cyan", "rejected": "red", "skipped": "dim"}


def ingest_result(
    paths: list[Path],
    driver: str | None,
    mapping: Path | None,
    workspace: Path,
    show_progress: bool,
    backend: str = "local",
    ray_address: str | None = None,
) -> dict[str, Any]:
    """Run the ingest and return the JSON-ready report (exit_code 1 when nothing could be processed)."""
    from ingest.pipeline import check_paths, ingest_paths

    load_mapping(mapping)  # a bad mapping file is one error line, before any bar is drawn
    limits = IngestLimits.from_env()  # so is a bad LANEPRINT_MAX_* value
    check_paths(paths)
    Workspace(workspace).check_writable()  # so is a workspace that cannot be written
    with backend_session(backend, ray_address), progress_bar(show_progress) as progress:
        report = ingest_paths(
            paths,
            Workspace(workspace),
            driver_id=driver,
            mapping=mapping,
            progress=progress,
            backend=backend,
            ray_address=ray_address,
            limits=limits,
        )
    out = report.to_dict()
    counts = out["counts"]
    processed = counts["ingested"] + counts["warning"] + counts["duplicate"] + counts["rejected"]
    if processed == 0:
        out["exit_code"] = 1
        out["error"] = "no log files found (.csv, .csv.gz or .mcap) under the given paths"
    return out


def render_ingest(result: dict[str, Any], console: Console) -> None:
    """The human summary: one row per file, then the counts."""
    table = Table(title=f"ingest into {result['workspace']}", show_lines=False)
    for col in ("file", "status", "driver", "session", "samples", "reason / warnings"):
        table.add_column(col, overflow="fold")
    shown = [f for f in result["files"] if f["status"] != "skipped"]
    for f in shown:
        note = f["reason"] or "; ".join(f["warnings"])
        if f["reason"] and f["warnings"]:
            note += " (" + "; ".join(f["warnings"]) + ")"
        style = _STYLE.get(f["status"], "")
        table.add_row(
            escape(Path(f["source"]).name),
            f"[{style}]{f['status']}[/]",
            escape(f["driver_id"] or ""),
            escape(f["session_id"] or ""),
            str(f["n_samples"] or ""),
            escape(note),
        )
    if shown:
        console.print(table)
    c = result["counts"]
    console.print(
        f"{c['ingested']} ingested, {c['warning']} ingested with warnings, {c['duplicate']} duplicate, "
        f"{c['rejected']} rejected, {c['skipped']} skipped (not logs)",
        highlight=False,
    )
    for note in result.get("notes", []):
        console.print(
            f"note: {note}; `laneprint check --repair` moves it to quarantine/",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    if result.get("error"):
        console.print(f"error: {result['error']}", markup=False, highlight=False)


@configurable("ingest")
def ingest_command(
    paths: Annotated[
        list[Path],
        typer.Argument(metavar="PATH", help="Log files (.csv, .csv.gz, .mcap) or folders to walk.", show_default=False),
    ],
    driver: Annotated[
        Optional[str],
        typer.Option(
            "--driver",
            metavar="ID",
            help="Driver id for files that carry none (a file's own id wins; a conflict warns).",
        ),
    ] = None,
    mapping: Annotated[
        Optional[Path],
        typer.Option(
            "--mapping",
            metavar="FILE",
            help="TOML/YAML file mapping your column/topic/field names and units onto the log format "
            "(for ROS 2 / protobuf MCAP: a topic and field path per signal, under mcap.signals).",
        ),
    ] = None,
    backend: BackendOpt = "local",
    ray_address: RayAddressOpt = None,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Read, validate and store simulator logs in the workspace."""
    run_command(
        lambda: ingest_result(
            paths, driver, mapping, workspace, show_progress=not as_json, backend=backend, ray_address=ray_address
        ),
        as_json,
        render_ingest,
    )
