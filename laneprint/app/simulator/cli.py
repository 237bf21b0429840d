"""`laneprint simulate`: generate a driver-in-the-loop study and write its logs.

`--engine synthetic` (default) is laneprint's own generator (`laneprint/simulator/`);
`--engine sumo` runs every driver and section in Eclipse SUMO, whose models make
the decisions (`laneprint/simulator/sumo/`, needs `pip install -e '.[sumo]'`);
`--engine highway` in highway-env, whose IDM + MOBIL vehicles are the drivers
(`laneprint/simulator/highway/`, needs `pip install -e '.[highway]'`).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console

from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt, progress_bar, run_command
from laneprint.errors import UserError
from laneprint.options import configurable

OutOpt = Annotated[Path, typer.Option("--out", "-o", help="Folder to write the study into.")]
DriversOpt = Annotated[
    Optional[int],
    typer.Option("--drivers", help="Number of drivers (default 10 synthetic, 9 sumo and highway: 3 per style)."),
]
DecisionsOpt = Annotated[
    Optional[int],
    typer.Option("--decisions", help="Button presses per driver, over all sections (synthetic; default 50)."),
]
EngineOpt = Annotated[
    str,
    typer.Option(
        "--engine",
        help="synthetic (laneprint's generator), sumo (Eclipse SUMO's models decide) or highway "
        "(highway-env's IDM + MOBIL vehicles are the drivers).",
    ),
]
MinutesOpt = Annotated[
    Optional[float],
    typer.Option(
        "--minutes",
        help="Minutes of driving per section (sumo: default 5, 15 for --family acceptance, 6 for "
        "--family sublane; highway: default 6).",
    ),
]
FamilyOpt = Annotated[
    Optional[str],
    typer.Option(
        "--family",
        help="sumo study family: ttc (default; styles differ in the times to collision they accept), "
        "acceptance (IDM drivers whose styles differ in the gaps and headways they accept; most presses "
        "have no closing leader) or sublane (SUMO's sublane model SL2015 for every vehicle: lane changes "
        "are lateral moves at the driver's own lateral speed). See the documentation, Simulated studies.",
    ),
]
LanesOpt = Annotated[
    Optional[int],
    typer.Option(
        "--lanes",
        help="sumo and highway: lanes of the highway, 2 (default) or 3 (lane 0 rightmost; the ego changes "
        "from every lane, both ways from the middle one).",
    ),
]
JobsOpt = Annotated[int, typer.Option("--jobs", help="Recordings simulated in parallel (sumo, highway).")]
SharesOpt = Annotated[
    Optional[str],
    typer.Option(
        "--shares",
        help="Shares of the styles Defensive,Normal,Aggressive among the drivers, e.g. 2,4,3 "
        "(default 1,1,1 for sumo and highway: equal groups; 3,4,3 synthetic).",
    ),
]
SeedOpt = Annotated[int, typer.Option("--seed", help="Random seed (same seed, same study).")]
FormatOpt = Annotated[
    Optional[str],
    typer.Option(
        "--format",
        help="mixed (odd drivers MCAP, even drivers .csv.gz; the default, csv for highway), csv (all "
        ".csv.gz), mcap, or both (csv/ and mcap/).",
    ),
]
ForceOpt = Annotated[bool, typer.Option("--force", help="Write into a folder that holds other files.")]


ENGINES: tuple[str, ...] = ("synthetic", "sumo", "highway")


@configurable("simulate")
def simulate_command(
    out: OutOpt,
    drivers: DriversOpt = None,
    decisions: DecisionsOpt = None,
    seed: SeedOpt = 0,
    fmt: FormatOpt = None,
    force: ForceOpt = False,
    engine: EngineOpt = "synthetic",
    minutes: MinutesOpt = None,
    jobs: JobsOpt = 1,
    family: FamilyOpt = None,
    lanes: LanesOpt = None,
    shares: SharesOpt = None,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Generate a DIL study (CSV and MCAP logs, ground_truth.json, README.md) into --out."""

    def work() -> dict[str, Any]:
        from laneprint.app.simulator.output import FORMATS

        if engine not in ENGINES:
            raise UserError(f"unknown --engine {engine!r}; choose one of {', '.join(ENGINES)}")
        form = fmt if fmt is not None else ("csv" if engine == "highway" else "mixed")
        if form not in FORMATS:
            raise UserError(f"unknown --format {form!r}; choose one of {', '.join(FORMATS)}")
        if drivers is not None and drivers < 1:
            raise UserError("--drivers must be at least 1")
        if engine in ("sumo", "highway") and decisions is not None:
            raise UserError(f"--decisions is for --engine synthetic; with {engine} the drivers decide (use --minutes)")
        if engine == "sumo":
            return _simulate_sumo(out, drivers, seed, form, force, minutes, jobs, family, lanes, shares, as_json)
        if engine == "highway":
            if family is not None:
                raise UserError("--family is for --engine sumo")
            return _simulate_highway(out, drivers, seed, form, force, minutes, jobs, lanes, shares, as_json)
        if minutes is not None or jobs != 1 or family is not None or lanes is not None:
            raise UserError(
                "--minutes, --jobs, --family and --lanes are for --engine sumo "
                "(all but --family also for --engine highway)"
            )
        return _simulate_synthetic(out, drivers, decisions, seed, form, force, shares, as_json)

    render = {"sumo": _render_sumo, "highway": _render_highway}.get(engine, _render)
    run_command(work, as_json, render)


def _simulate_synthetic(
    out: Path,
    drivers: Optional[int],
    decisions: Optional[int],
    seed: int,
    fmt: str,
    force: bool,
    shares: Optional[str],
    as_json: bool,
) -> dict[str, Any]:
    from laneprint.simulator.config import StudySettings
    from laneprint.app.simulator.output import check_destination, write_study
    from laneprint.simulator.study import simulate_study

    base = StudySettings()
    decisions = base.decisions_per_driver if decisions is None else decisions
    if decisions < len(base.speed_limits_kph):
        raise UserError(f"--decisions must be at least {len(base.speed_limits_kph)} (one per section)")
    settings = replace(
        base,
        n_drivers=base.n_drivers if drivers is None else drivers,
        decisions_per_driver=decisions,
        style_shares=base.style_shares if shares is None else parse_shares(shares),
    )
    check_destination(out, force)  # before minutes of work, not after
    with progress_bar(not as_json) as bar:
        study = simulate_study(settings, seed, progress=bar)
        return write_study(study, out, fmt, force=force, progress=bar)


def _simulate_sumo(
    out: Path,
    drivers: Optional[int],
    seed: int,
    fmt: str,
    force: bool,
    minutes: Optional[float],
    jobs: int,
    family: Optional[str],
    lanes: Optional[int],
    shares: Optional[str],
    as_json: bool,
) -> dict[str, Any]:
    from laneprint.app.simulator.output import check_destination
    from laneprint.simulator.sumo.backend import check_available
    from laneprint.app.simulator.sumo_output import write_sumo_study
    from laneprint.simulator.sumo.settings import DEFAULT_FAMILY, DEFAULT_LANES, FAMILIES, LANES, family_settings
    from laneprint.simulator.sumo.study import simulate_sumo_study

    family = DEFAULT_FAMILY if family is None else family
    if family not in FAMILIES:
        raise UserError(f"unknown --family {family!r}; choose one of {', '.join(FAMILIES)}")
    lanes = DEFAULT_LANES if lanes is None else lanes
    if lanes not in LANES:
        raise UserError(f"--lanes {lanes}: a SUMO highway has {' or '.join(map(str, LANES))} lanes")
    if minutes is not None and not 0 < minutes <= 120:
        raise UserError("--minutes must be more than 0 and at most 120")
    if jobs < 1:
        raise UserError("--jobs must be at least 1")
    base = family_settings(family, lanes)
    settings = replace(
        base,
        n_drivers=base.n_drivers if drivers is None else drivers,
        minutes=base.minutes if minutes is None else minutes,
        style_shares=base.style_shares if shares is None else parse_shares(shares),
    )
    check_available()  # one line telling how to install SUMO, before anything else
    check_destination(out, force)
    with progress_bar(not as_json) as bar:
        study = simulate_sumo_study(settings, seed, progress=bar, jobs=jobs)
        return write_sumo_study(study, out, fmt, force=force, progress=bar)


def parse_shares(text: str) -> tuple[float, float, float]:
    """`--shares 2,4,3` -> (2.0, 4.0, 3.0): Defensive, Normal, Aggressive."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or min(values) < 0 or sum(values) <= 0:
        raise UserError(f"--shares {text!r}: give three non-negative numbers Defensive,Normal,Aggressive, e.g. 2,4,3")
    return values  # type: ignore[return-value]


def _simulate_highway(
    out: Path,
    drivers: Optional[int],
    seed: int,
    fmt: str,
    force: bool,
    minutes: Optional[float],
    jobs: int,
    lanes: Optional[int],
    shares: Optional[str],
    as_json: bool,
) -> dict[str, Any]:
    from laneprint.app.simulator.highway_output import write_highway_study
    from laneprint.simulator.highway.settings import DEFAULT_LANES, LANES, HighwaySettings
    from laneprint.simulator.highway.study import check_available, simulate_highway_study
    from laneprint.app.simulator.output import check_destination

    lanes = DEFAULT_LANES if lanes is None else lanes
    if lanes not in LANES:
        raise UserError(f"--lanes {lanes}: a highway-env road here has {' or '.join(map(str, LANES))} lanes")
    if minutes is not None and not 0 < minutes <= 120:
        raise UserError("--minutes must be more than 0 and at most 120")
    if jobs < 1:
        raise UserError("--jobs must be at least 1")
    base = HighwaySettings()
    settings = replace(
        base,
        n_lanes=lanes,
        n_drivers=base.n_drivers if drivers is None else drivers,
        minutes=base.minutes if minutes is None else minutes,
        style_shares=base.style_shares if shares is None else parse_shares(shares),
    )
    check_available()  # one line telling how to install highway-env, before anything else
    check_destination(out, force)
    with progress_bar(not as_json) as bar:
        study = simulate_highway_study(settings, seed, progress=bar, jobs=jobs)
        return write_highway_study(study, out, fmt, force=force, progress=bar)


def _render(result: dict[str, Any], console: Console) -> None:
    cases = ", ".join(f"{k} {v}" for k, v in sorted(result["cases"].items()))
    console.print(
        f"Wrote a synthetic study to {result['out']} (seed {result['seed']}, format {result['format']})",
        highlight=False,
        soft_wrap=True,
    )
    console.print(f"  drivers     {result['drivers']}", highlight=False, soft_wrap=True)
    console.print(f"  recordings  {result['recordings']}", highlight=False, soft_wrap=True)
    console.print(f"  decisions   {result['decisions']} ({cases})", highlight=False, soft_wrap=True)
    console.print(f"  files       {result['files']}, {result['bytes'] / 1e6:.1f} MB", highlight=False, soft_wrap=True)


def _render_sumo(result: dict[str, Any], console: Console) -> None:
    per = result["decisions_per_driver"]
    styles = result["styles"]
    counts = ", ".join(f"{d} {styles[d][0]} {n}" for d, n in per.items())
    lines = [
        f"Wrote a SUMO study to {result['out']} (Eclipse SUMO {result['sumo_version']}, family {result['family']}, "
        f"{result['lanes']} lanes, seed {result['seed']}, format {result['format']}, {result['minutes']:g} min per section)",
        f"  drivers     {result['drivers']}",
        f"  recordings  {result['recordings']}",
        f"  decisions   {result['decisions']} ({result['directions']['left']} left, "
        f"{result['directions']['right']} right; {counts})",
        "  by lane     " + ", ".join(f"{k} {v}" for k, v in result["changes_by_lane"].items()),
        f"  collisions  {result['collisions']}",
        f"  files       {result['files']}, {result['bytes'] / 1e6:.1f} MB",
    ]
    for line in lines:
        console.print(line, highlight=False, soft_wrap=True)


def _render_highway(result: dict[str, Any], console: Console) -> None:
    per = result["presses_per_driver"]
    styles = result["styles"]
    counts = ", ".join(f"{d} {styles[d][0]} {n}" for d, n in per.items())
    lines = [
        f"Wrote a highway-env study to {result['out']} (highway-env {result['highway_env_version']}, "
        f"{result['lanes']} lanes, seed {result['seed']}, format {result['format']}, {result['minutes']:g} min per "
        "section)",
        f"  drivers     {result['drivers']}",
        f"  recordings  {result['recordings']}",
        f"  presses     {result['presses']} ({result['directions']['left']} left, {result['directions']['right']} "
        f"right, {result['aborted']} aborted; {counts})",
        f"  missed      {result['missed']} lane changes without a press",
        "  by lane     " + ", ".join(f"{k} {v}" for k, v in result["presses_by_lane"].items()),
        f"  collisions  {result['collisions']} (traffic among itself {result['traffic_collisions']})",
        f"  files       {result['files']}, {result['bytes'] / 1e6:.1f} MB",
    ]
    for line in lines:
        console.print(line, highlight=False, soft_wrap=True)
