"""`laneprint simulate`: generate the synthetic driver-in-the-loop study and write its logs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt, progress_bar, run_command
from laneprint.errors import UserError

OutOpt = Annotated[Path, typer.Option("--out", "-o", help="Folder to write the study into.")]
DriversOpt = Annotated[int, typer.Option("--drivers", help="Number of drivers.")]
DecisionsOpt = Annotated[int, typer.Option("--decisions", help="Button presses per driver, over all sections.")]
SeedOpt = Annotated[int, typer.Option("--seed", help="Random seed (same seed, same study).")]
FormatOpt = Annotated[str, typer.Option(
    "--format", help="mixed (odd drivers MCAP, even drivers .csv.gz), csv (all .csv.gz), mcap, or both (csv/ and mcap/).")]
ForceOpt = Annotated[bool, typer.Option("--force", help="Write into a folder that holds other files.")]


def simulate_command(out: OutOpt, drivers: DriversOpt = 10, decisions: DecisionsOpt = 50, seed: SeedOpt = 0,
                     fmt: FormatOpt = "mixed", force: ForceOpt = False, workspace: WorkspaceOpt = DEFAULT_WS,
                     as_json: JsonOpt = False) -> None:
    """Generate a synthetic DIL study (CSV and MCAP logs, ground_truth.json) into --out."""

    def work() -> dict[str, Any]:
        from laneprint.simulator.config import StudySettings
        from laneprint.simulator.output import FORMATS, check_destination, write_study
        from laneprint.simulator.study import simulate_study

        if fmt not in FORMATS:
            raise UserError(f"unknown --format {fmt!r}; choose one of {', '.join(FORMATS)}")
        if drivers < 1:
            raise UserError("--drivers must be at least 1")
        base = StudySettings()
        if decisions < len(base.speed_limits_kph):
            raise UserError(f"--decisions must be at least {len(base.speed_limits_kph)} (one per section)")
        settings = replace(base, n_drivers=drivers, decisions_per_driver=decisions)
        check_destination(out, force)  # before minutes of work, not after
        with progress_bar(not as_json) as bar:
            study = simulate_study(settings, seed, progress=bar)
            return write_study(study, out, fmt, force=force, progress=bar)

    run_command(work, as_json, _render)


def _render(result: dict[str, Any], console: Console) -> None:
    cases = ", ".join(f"{k} {v}" for k, v in sorted(result["cases"].items()))
    console.print(f"Wrote a synthetic study to {result['out']} (seed {result['seed']}, format {result['format']})",
                  highlight=False, soft_wrap=True)
    console.print(f"  drivers     {result['drivers']}", highlight=False, soft_wrap=True)
    console.print(f"  recordings  {result['recordings']}", highlight=False, soft_wrap=True)
    console.print(f"  decisions   {result['decisions']} ({cases})", highlight=False, soft_wrap=True)
    console.print(f"  files       {result['files']}, {result['bytes'] / 1e6:.1f} MB", highlight=False, soft_wrap=True)
