"""`laneprint analyze`: decisions, per-driver statistics and styles of a workspace."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console
from rich import box
from rich.table import Table

from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt, progress_bar, run_command
from laneprint.errors import UserError
from laneprint.plotting import line_formula
from laneprint.workspace import Workspace
from indicators.settings import CHOSEN_BY_DATA

PAPER_INDICATORS = ("t_f", "t_nf", "dv_nb")
TRAIT_UNITS = ("thw_follow",)  # indicators.stats.TRAIT_UNITS, without importing it at start-up


def _fmt(x: Any, spec: str = ".3g") -> str:
    return "-" if x is None else format(x, spec)


def _line(f: dict[str, Any]) -> str:
    """A fit as 'A/b', with '!' when flagged."""
    if not f or f["status"] != "ok":
        return "-"
    return f"{f['A']:.3g}/{f['b']:.3g}" + ("!" if f.get("flag") else "")


def _kept(f: dict[str, Any] | None) -> str:
    """A driver's thw_follow level and its number of steady-following episodes."""
    if not f or f.get("thw_follow_s") is None:
        return "-"
    return f"{f['thw_follow_s']:.2f} s ({f['episodes']})"


def render(result: dict[str, Any], console: Console) -> None:
    """Human summary of an analysis report."""
    s = result["summary"]
    console.print(f"[bold]analysis[/bold] of {s['n_drivers']} driver(s): {s['n_presses']} presses, "
                  f"{s['n_keep_states']} keep states, {s['n_skipped']} skipped item(s)")
    share = s["share_significant"]
    console.print("drivers with a significant linear correlation with speed: "
                  + ", ".join(f"{k} {_fmt(None if share.get(k) is None else 100 * share[k], '.0f')} %"
                              for k in PAPER_INDICATORS)
                  + f"; all three {_fmt(None if s['share_drivers_all_significant'] is None else 100 * s['share_drivers_all_significant'], '.0f')} %")
    feats = s.get("features")
    if feats:
        render_features(feats, console, int((result.get("settings") or {}).get("min_fit_points", 5)))
    shown = list(PAPER_INDICATORS) + [i for i in (feats or {}).get("indicators", []) if i not in PAPER_INDICATORS]
    table = Table(title="drivers: lines I = A v_e + b shown as A/b; ! flagged (see warnings); * typical"
                        + ("; thw_follow: headway kept (episodes)" if any(i in TRAIT_UNITS for i in shown) else ""),
                  box=box.SIMPLE_HEAD, pad_edge=False)
    widths = {"n": 3, "style": 10, "driver": 6}
    for col in ("driver", "n", "style", "conf", "", *shown):
        table.add_column(col, no_wrap=True, min_width=10 if col in shown else widths.get(col, len(col)))
    for d, info in result["drivers"].items():
        fits = {f["indicator"]: f for f in info["fits"]}
        table.add_row(d, str(info["n_decisions"]), info["style"], f"{info['confidence']:.2f}",
                      "*" if info["is_typical"] else "",
                      *(_kept(info.get("following")) if ind in TRAIT_UNITS else _line(fits.get(ind)) for ind in shown))
    console.print(table)
    for name, st in result["styles"].items():
        lines = [ln for ln in st["reference_lines"] if ln["kind"] == "typical" and ln["indicator"] in PAPER_INDICATORS
                 and ln.get("direction", "both") == "both"]
        txt = ", ".join(format_line(ln["indicator"], ln["A"], ln["b"]) + (" (level)" if ln.get("fit") == "level" else "")
                        for ln in lines)
        console.print(f"[bold]{name}[/bold] ({len(st['members'])}): typical {', '.join(st['typical'])}: {txt}",
                      highlight=False)
        if st.get("description"):
            console.print(f"  {name}: {st['description']}", markup=False, highlight=False)
    for d, why in (s.get("unsure_drivers") or {}).items():
        console.print(f"unsure: {d}: {why}", markup=False, highlight=False)
    for w in s.get("warnings", []):
        console.print(f"[yellow]warning:[/yellow] {w}", highlight=False)
    if result["skipped"]:
        console.print(f"skipped ({len(result['skipped'])}), first ones:")
        for row in result["skipped"][:8]:
            console.print(f"  {row['what']} {row['id']}: {row['reason']}", markup=False, highlight=False)
    console.print(f"stored in {result['workspace']}/analysis", markup=False, highlight=False)


def _read_text(c: dict[str, Any], min_points: int) -> str:
    """'  read at N presses per driver' of a candidate, and whether 'auto' leaves it out for that."""
    read = c.get("presses_read")
    if read is None:  # every indicator read over the drive, or an analysis made before it was measured
        return ""
    out = f"  read at {read:g} presses per driver"
    return out + (f" (under {min_points}: auto leaves it out)" if read < min_points else "")


def render_features(feats: dict[str, Any], console: Console, min_points: int = 5) -> None:
    """Which reading the styles were read by, and the figures of the readings measured."""
    how = "chosen by the data" if feats["requested"] in CHOSEN_BY_DATA else "as requested"
    console.print(f"styles read by [bold]{feats['chosen']}[/bold] ({', '.join(feats['indicators'])}), {how}:",
                  highlight=False)
    cands = feats["candidates"]
    heldout = any(c.get("heldout_ll") is not None for c in cands)
    for c in cands[:8] if heldout else cands:
        mark = "*" if c["chosen"] else ("~" if c.get("plausible") else " ")
        if heldout:
            console.print(f"  {mark} {c['name']:<28} held-out log-likelihood {_fmt(c['heldout_ll'], '.1f')}"
                          f"  (± {_fmt(c.get('heldout_se'), '.1f')} against the best)", markup=False, highlight=False)
            continue
        console.print(f"  {mark} {c['name']:<11} silhouette {_fmt(c['silhouette'], '.2f')}  stability "
                      f"{_fmt(c['stability'], '.2f')}  score {_fmt(c['score'], '.3f')}  "
                      f"imputed {_fmt(None if c['imputed'] is None else 100 * c['imputed'], '.0f')} %"
                      + _read_text(c, min_points),
                      markup=False, highlight=False)
    if heldout and len(cands) > 8:
        console.print(f"  ... {len(cands) - 8} more readings; ~ marks readings as plausible as the chosen one",
                      markup=False, highlight=False)


def format_line(indicator: str, A: float, b: float) -> str:
    """'t_f = 0.45 v − 3.26' with the signs printed properly."""
    return line_formula(indicator, A, b, x="v", digits_a=2)


def with_config(path: Path, flags: "AnalysisSettings") -> "AnalysisSettings":
    """The settings of `path`, with every option given on the command line (differing from its
    default) on top; the result checked as the options are."""
    from dataclasses import fields, replace

    from indicators.settings import DRIVER_LINES, AnalysisSettings
    from laneprint.config import read_config

    settings = read_config(path, AnalysisSettings)
    default = AnalysisSettings()
    given = {f.name: getattr(flags, f.name) for f in fields(AnalysisSettings)
             if getattr(flags, f.name) != getattr(default, f.name)}
    settings = replace(settings, **given)
    if settings.driver_lines not in DRIVER_LINES:
        raise UserError(f"--config {path}: driver_lines must be one of {', '.join(DRIVER_LINES)}, "
                        f"not {settings.driver_lines!r}")
    return settings


def analyze_command(
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
    k: Annotated[int, typer.Option("--k", help="Number of styles.", min=1)] = 3,
    choose_k: Annotated[Optional[str], typer.Option("--choose-k", help="Choose k by 'silhouette' or 'bic'.")] = None,
    far_follower_m: Annotated[float, typer.Option("--far-follower-m", help="Target-lane follower beyond this gap has no influence [m].")] = 100.0,
    step_s: Annotated[float, typer.Option("--step-s", help="Spacing of the 'not yet' states before a press [s].")] = 0.5,
    feature_fit: Annotated[str, typer.Option("--feature-fit", help="Line fit for the clustering features: huber, theilsen, ols, or a flat level: median or trimmed (mean after cutting a fifth at each end).")] = "huber",
    acceptance_fit: Annotated[str, typer.Option(
        "--acceptance-fit", help="How gap, headway and relative-speed features are read: trimmed (the driver's "
                                 "level, a trimmed mean), median (the level as a median), or a line: huber, "
                                 "theilsen, ols.")] = "trimmed",
    extrapolate_features: Annotated[bool, typer.Option(
        "--extrapolate-features", help="Read each driver's feature line at every section speed, even beyond "
                                       "the speeds of its presses (default: within them).")] = False,
    features: Annotated[str, typer.Option(
        "--features", help="What the styles are read by: auto (the indicator set whose styles are best separated "
                           "and most stable, the study's TTCs unless another is clearly better), separated (the "
                           "best separated and most stable of the indicator sets and the behaviour readings, no "
                           "margin for any), reliable (the two behaviour parameters in which the drivers differ "
                           "most reliably), heldout (the reading whose styles best predict the drivers' held-out "
                           "decisions and following headways: indicator sets and the drivers' critical gaps), "
                           "behaviour (only the critical gaps and following headway), behaviour:PARAMS (e.g. "
                           "behaviour:thw_nb+thw_follow), an indicator set: ttc (the study's t_f, t_nf), paper "
                           "(t_f, t_nf, dv_nb), headway, acceptance, all, following, or a comma-separated list of "
                           "indicators.")] = "auto",
    flagged_lines: Annotated[str, typer.Option(
        "--flagged-lines", help="A flagged per-driver line (low R², slope interval spanning 0, few points) in the "
                                "reference lines: level (the driver's median, A = 0) or ols (as fitted, the "
                                "study's way).")] = "level",
    keep_receding: Annotated[bool, typer.Option(
        "--keep-receding", help="Fit front gaps and headways to leaders pulling away too (default: left out when "
                                "the leader pulls away faster than 1 m/s: the driver is not held by it).")] = False,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the clustering.")] = 0,
    config: Annotated[Optional[Path], typer.Option(
        "--config", help="A TOML file of analysis settings (the fields of AnalysisSettings, e.g. "
                         "driver_lines = \"mixed\"); options given on the command line take precedence.")] = None,
) -> None:
    """Indicators at every decision, per-driver correlations and fits, styles and reference lines."""
    from clustering.pipeline import analyze
    from clustering.selection import resolve_features
    from indicators.settings import FEATURE_FITS, FLAGGED_LINES, AnalysisSettings

    def work() -> dict[str, Any]:
        if choose_k not in (None, "silhouette", "bic"):
            raise UserError(f"--choose-k must be 'silhouette' or 'bic', not {choose_k!r}")
        if feature_fit not in FEATURE_FITS:
            raise UserError(f"--feature-fit must be one of {', '.join(FEATURE_FITS)}, not {feature_fit!r}")
        if acceptance_fit not in FEATURE_FITS:
            raise UserError(f"--acceptance-fit must be one of {', '.join(FEATURE_FITS)}, not {acceptance_fit!r}")
        if step_s <= 0:
            raise UserError("--step-s must be positive")
        if features not in CHOSEN_BY_DATA:
            resolve_features(features)  # a one-line error before any work
        if flagged_lines not in FLAGGED_LINES:
            raise UserError(f"--flagged-lines must be one of {', '.join(FLAGGED_LINES)}, not {flagged_lines!r}")
        flags = AnalysisSettings(k=k, choose_k=choose_k, far_follower_m=far_follower_m, step_s=step_s,
                                 feature_fit=feature_fit, acceptance_fit=acceptance_fit, feature_extrapolate=extrapolate_features,
                                 features=features, flagged_lines=flagged_lines, random_state=seed,
                                 max_receding_mps=None if keep_receding else AnalysisSettings.max_receding_mps)
        settings = flags if config is None else with_config(config, flags)
        if settings.features not in CHOSEN_BY_DATA:
            resolve_features(settings.features)
        ws = Workspace(Path(workspace))
        if not ws.root.is_dir() or ws.recordings().empty:  # before the progress bar draws anything
            raise UserError(f"no recordings in workspace {ws.root}: run `laneprint ingest PATH` first")
        with progress_bar(enabled=not as_json) as progress:
            return analyze(ws, settings, progress)

    run_command(work, as_json, render)
