"""`laneprint analyze`: decisions, per-driver statistics and styles of a workspace."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich import box
from rich.table import Table

from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt, progress_bar, run_command
from laneprint.errors import UserError
from laneprint.plotting import line_formula
from laneprint.workspace import Workspace
from indicators.settings import CHOSEN_BY_DATA, AnalysisSettings
from laneprint.options import Section, Settings, configurable

PAPER_INDICATORS = ("t_f", "t_nf", "dv_nb")
TRAIT_UNITS = ("thw_follow",)  # indicators.stats.TRAIT_UNITS, without importing it at start-up


def _fmt(x: Any, spec: str = ".3g") -> str:
    return "-" if x is None else format(x, spec)


def _line(f: dict[str, Any] | None) -> str:
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
    console.print(
        f"[bold]analysis[/bold] of {s['n_drivers']} driver(s): {s['n_presses']} presses, "
        f"{s['n_keep_states']} keep states, {s['n_skipped']} skipped item(s)"
    )
    share = s["share_significant"]
    console.print(
        "drivers with a significant linear correlation with speed: "
        + ", ".join(f"{k} {_fmt(None if share.get(k) is None else 100 * share[k], '.0f')} %" for k in PAPER_INDICATORS)
        + f"; all three {_fmt(None if s['share_drivers_all_significant'] is None else 100 * s['share_drivers_all_significant'], '.0f')} %"
    )
    feats = s.get("features")
    if feats:
        render_features(feats, console, int((result.get("settings") or {}).get("min_fit_points", 5)))
    shown = list(PAPER_INDICATORS) + [i for i in (feats or {}).get("indicators", []) if i not in PAPER_INDICATORS]
    table = Table(
        title="drivers: lines I = A v_e + b shown as A/b; ! flagged (see warnings); * typical"
        + ("; thw_follow: headway kept (episodes)" if any(i in TRAIT_UNITS for i in shown) else ""),
        box=box.SIMPLE_HEAD,
        pad_edge=False,
    )
    widths = {"n": 3, "style": 10, "driver": 6}
    for col in ("driver", "n", "style", "conf", "", *shown):
        table.add_column(col, no_wrap=True, min_width=10 if col in shown else widths.get(col, len(col)))
    for d, info in result["drivers"].items():
        fits = {f["indicator"]: f for f in info["fits"]}
        table.add_row(
            d,
            str(info["n_decisions"]),
            info["style"],
            f"{info['confidence']:.2f}",
            "*" if info["is_typical"] else "",
            *(_kept(info.get("following")) if ind in TRAIT_UNITS else _line(fits.get(ind)) for ind in shown),
        )
    console.print(table)
    for name, st in result["styles"].items():
        lines = [
            ln
            for ln in st["reference_lines"]
            if ln["kind"] == "typical" and ln["indicator"] in PAPER_INDICATORS and ln.get("direction", "both") == "both"
        ]
        txt = ", ".join(
            format_line(ln["indicator"], ln["A"], ln["b"]) + (" (level)" if ln.get("fit") == "level" else "")
            for ln in lines
        )
        console.print(
            f"[bold]{name}[/bold] ({len(st['members'])}): typical {', '.join(st['typical'])}: {txt}", highlight=False
        )
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
    console.print(
        f"styles read by [bold]{feats['chosen']}[/bold] ({', '.join(feats['indicators'])}), {how}:", highlight=False
    )
    cands = feats["candidates"]
    heldout = any(c.get("heldout_ll") is not None for c in cands)
    for c in cands[:8] if heldout else cands:
        mark = "*" if c["chosen"] else ("~" if c.get("plausible") else " ")
        if heldout:
            console.print(
                f"  {mark} {c['name']:<28} held-out log-likelihood {_fmt(c['heldout_ll'], '.1f')}"
                f"  (± {_fmt(c.get('heldout_se'), '.1f')} against the best)",
                markup=False,
                highlight=False,
            )
            continue
        console.print(
            f"  {mark} {c['name']:<11} silhouette {_fmt(c['silhouette'], '.2f')}  stability "
            f"{_fmt(c['stability'], '.2f')}  score {_fmt(c['score'], '.3f')}  "
            f"imputed {_fmt(None if c['imputed'] is None else 100 * c['imputed'], '.0f')} %"
            + _read_text(c, min_points),
            markup=False,
            highlight=False,
        )
    if heldout and len(cands) > 8:
        console.print(
            f"  ... {len(cands) - 8} more readings; ~ marks readings as plausible as the chosen one",
            markup=False,
            highlight=False,
        )


def format_line(indicator: str, A: float, b: float) -> str:
    """'t_f = 0.45 v − 3.26' with the signs printed properly."""
    return line_formula(indicator, A, b, x="v", digits_a=2)


@configurable(
    "analyze",
    Section(
        "analysis",
        AnalysisSettings,
        visible=("features", "k", "choose_k", "random_state"),
        aliases={"random_state": ("--seed",), "feature_extrapolate": ("--extrapolate-features",)},
    ),
)
def analyze_command(
    settings: Settings,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
    keep_receding: Annotated[
        bool,
        typer.Option(
            "--keep-receding",
            hidden=True,
            help="Fit front gaps and headways to leaders pulling away too (sets max_receding_mps to none).",
        ),
    ] = False,
) -> None:
    """Indicators at every decision, per-driver correlations and fits, styles and reference lines."""
    from clustering.pipeline import analyze
    from clustering.selection import resolve_features
    from indicators.settings import DRIVER_LINES, FEATURE_FITS, FLAGGED_LINES

    def work() -> dict[str, Any]:
        st = settings.analysis if not keep_receding else replace(settings.analysis, max_receding_mps=None)
        if st.choose_k not in (None, "silhouette", "bic"):
            raise UserError(f"--choose-k must be 'silhouette' or 'bic', not {st.choose_k!r}")
        for name, value, allowed in (
            ("feature-fit", st.feature_fit, FEATURE_FITS),
            ("acceptance-fit", st.acceptance_fit, FEATURE_FITS),
            ("flagged-lines", st.flagged_lines, FLAGGED_LINES),
            ("driver-lines", st.driver_lines, DRIVER_LINES),
        ):
            if value not in allowed:
                raise UserError(f"--{name} must be one of {', '.join(allowed)}, not {value!r}")
        if st.step_s <= 0:
            raise UserError("--step-s must be positive")
        if st.features not in CHOSEN_BY_DATA:
            resolve_features(st.features)  # a one-line error before any work
        ws = Workspace(Path(workspace))
        if not ws.root.is_dir() or ws.recordings().empty:  # before the progress bar draws anything
            raise UserError(f"no recordings in workspace {ws.root}: run `laneprint ingest PATH` first")
        with progress_bar(enabled=not as_json) as progress:
            return analyze(ws, st, progress)

    run_command(work, as_json, render)
