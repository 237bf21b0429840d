"""`laneprint report [--out FILE.html]`: the study in one self-contained HTML file.

What a researcher attaches to a paper's supplement or shows at a lab meeting: the
study (recordings, drivers, decisions, refused files and why), the correlations
and per-driver fits with their flags, the styles and their reference lines against
Table 1, every evaluated run's in-sample and held-out figures (agent, greedy,
imitation, with intervals), and provenance (code version, settings, data
fingerprints). Figures are interactive Plotly figures whose JavaScript is inlined
once, so the file opens offline and requests nothing from any host. Beside it,
`<FILE>_files/` holds every table as CSV and every figure as Plotly JSON, and as SVG
when `kaleido` is installed (`pip install -e '.[report]'`; it draws with a local
Chrome or Chromium, offline).

Pure assembly over the workspace: `build_report(ws)` returns the sections; `render_html`
writes them out. The command line (`report_command`) is `laneprint.app.report_cli`.
"""

from __future__ import annotations

import html
import json
import re
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pandas as pd
import plotly.graph_objects as go

from laneprint.errors import SettingError, UserError
from laneprint.workspace import Workspace

#: Per-driver figures are drawn for at most this many drivers (the typical drivers first); every
#: driver's fits are in the tables either way.
MAX_DRIVER_FIGURES = 6


@dataclass
class Section:
    """One part of the report: a heading, paragraphs (HTML-escaped text), tables and figures, in order."""

    title: str
    items: list[tuple[str, Any]] = field(default_factory=list)
    """('p', text) | ('warn', text) | ('table', (name, frame)) | ('figure', (name, go.Figure))."""

    def p(self, text: str) -> "Section":
        self.items.append(("p", text))
        return self

    def warn(self, text: str) -> "Section":
        self.items.append(("warn", text))
        return self

    def table(self, name: str, frame: pd.DataFrame) -> "Section":
        self.items.append(("table", (name, frame)))
        return self

    def figure(self, name: str, fig: go.Figure) -> "Section":
        self.items.append(("figure", (name, fig)))
        return self


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_")[:80] or "item"


def _study(ws: Workspace) -> Section:
    from dashboard import views

    sec = Section("The study")
    recs = ws.recordings()
    if recs.empty:
        raise UserError(
            f"no recordings in workspace {ws.root}: run `laneprint ingest PATH --workspace {ws.root}` first"
        )
    n_drivers = recs["driver_id"].nunique()
    presses = int(pd.to_numeric(recs.get("n_presses"), errors="coerce").sum()) if "n_presses" in recs else 0
    sec.p(
        f"{views.plural(len(recs), 'recording')} of {views.plural(n_drivers, 'driver')}, "
        f"{views.plural(presses, 'button press', 'button presses')}."
    )
    cols = [
        c
        for c in (
            "driver_id",
            "session_id",
            "speed_limit_kph",
            "format",
            "n_samples",
            "duration_s",
            "n_presses",
            "n_vehicles",
            "status",
            "warnings",
            "source_name",
            "recording_id",
        )
        if c in recs
    ]
    sec.table(
        "recordings", recs[cols].rename(columns={"speed_limit_kph": "speed limit [km/h]", "duration_s": "duration [s]"})
    )
    rej = ws.rejected()
    if len(rej):
        sec.p(f"{views.plural(len(rej), 'file')} refused by the ingest, with the reason:")
        sec.table("refused", rej[[c for c in ("source_name", "format", "reason", "rejected_at") if c in rej]])
    else:
        sec.p("No file was refused by the ingest.")
    return sec


def _analysis(ws: Workspace) -> list[Section]:
    from clustering.plots import cluster_scatter, following_headways, reference_lines
    from dashboard import views
    from indicators.plots import indicator_vs_speed
    from laneprint.reference import PAPER_TABLE1

    if not ws.has_table("analysis", "decisions"):
        return [Section("Analysis").p(f"No analysis yet: `laneprint analyze --workspace {ws.root}`.")]
    meta = ws.read_meta("analysis")
    t = {
        n: ws.read_table("analysis", n)
        for n in (
            "decisions",
            "correlations",
            "fits",
            "fits_by_direction",
            "styles",
            "reference_lines",
            "skipped",
            "following",
        )
        if ws.has_table("analysis", n)
    }
    summary = meta.get("summary") or {}
    dec = t["decisions"]
    ind = Section("Indicators, correlations and per-driver fits")
    ind.p(
        f"{views.plural(int((dec['label'] == 'change').sum()), 'press', 'presses')} and "
        f"{views.plural(int((dec['label'] == 'keep').sum()), 'not-yet state')} in the decisions table."
        + (f" By direction: {by_side}." if (by_side := views.presses_by_direction_text(meta)) else "")
    )
    share = summary.get("share_significant") or {}
    if share:
        ind.p(
            "Drivers with a significant linear correlation with ego speed: "
            + ", ".join(f"{k} {v:.0%}" for k, v in share.items() if v is not None)
            + " (the study reports 80 %)."
        )
    if "correlations" in t:
        ind.table("correlations", t["correlations"])
    fits = t.get("fits")
    if fits is not None:
        flagged = views.flagged_fits(fits)
        if len(flagged):
            ind.warn(
                f"{views.plural(len(flagged), 'per-driver line')} flagged (they mean little): "
                + "; ".join(f"{r.driver_id} {r.indicator}: {r.flag}" for r in flagged.itertuples())
            )
        summary = views.fit_summary(fits)
        ind.table("fits", summary.assign(driver_id=fits["driver_id"].to_numpy())[["driver_id", *summary.columns]])
    side_fits = t.get("fits_by_direction")
    if side_fits is not None and len(side_fits):
        ind.p(
            "The same fits on the presses to each side (left: overtaking, right: returning); a side with too "
            "few presses has no line, and the pooled line stands for it:"
        )
        ind.table("fits_by_direction", views.direction_fit_summary(side_fits, keep=("driver_id",)))
    styles = t.get("styles")
    sty = Section("Styles and reference lines")
    for w in views.analysis_warnings(meta):
        sty.warn(w)
    chosen = views.chosen_indicators(meta)
    feats = summary.get("features") or {}
    sty.p(
        f"Styles read by {', '.join(chosen)}"
        + (f" (feature set {feats.get('chosen')}, requested {feats.get('requested')})" if feats else "")
        + f", each driver's line read at {views.speeds_text(meta)}."
    )
    cands = views.feature_candidates(meta)
    if len(cands):
        sty.table("feature_sets", cands)
    if styles is not None and len(styles):
        sty.table("style_summary", views.style_summary(styles, meta))
        unsure = views.unsure_drivers(styles)
        if len(unsure):
            sty.p(
                "Drivers whose style is not sure, and why (confidence: the share of draws of the driver's own "
                "estimates that keep its style, times the share of plausible readings that agree, at most "
                "(n + 1) / (n + 2) for n presses):"
            )
            sty.table("unsure_drivers", unsure)
        try:
            sty.figure("drivers_in_feature_space", cluster_scatter(styles, indicators=chosen))
        except ValueError as exc:
            sty.p(f"No feature-space figure: {exc}.")
        following = t.get("following")
        if following is not None and len(following):
            sty.figure("headway_kept_in_steady_following", following_headways(following, styles))
        sty.table("styles", styles)
    lines = t.get("reference_lines")
    if lines is not None and len(lines):
        sty.figure("reference_lines", reference_lines(lines, indicators=views.reference_indicators(lines, chosen)))
        typical = lines[(lines["scope"] == "style") & (lines["kind"] == "typical") & (lines["direction"] == "both")]
        rows = []
        for r in typical.itertuples():
            paper = PAPER_TABLE1.get(str(r.name), {}).get(str(r.indicator))
            rows.append(
                {
                    "style": r.name,
                    "indicator": r.indicator,
                    "A": r.A,
                    "b": r.b,
                    "A (Table 1)": paper[0] if paper else None,
                    "b (Table 1)": paper[1] if paper else None,
                    "fit": getattr(r, "fit", ""),
                    "source": getattr(r, "source", ""),
                }
            )
        sty.p("The typical drivers' lines against Table 1 of the study (I = A v_e + b, v_e in m/s):")
        sty.table("reference_lines_vs_table1", pd.DataFrame(rows))
        sty.table("reference_lines", lines)
    if styles is not None and fits is not None and len(styles):
        order = styles.sort_values("is_typical", ascending=False)["driver_id"].astype(str).tolist()
        drv = Section("Typical drivers' indicators against speed")
        deciding = set(dec["driver_id"].astype(str).unique())
        shown = [d for d in order if d in deciding][:MAX_DRIVER_FIGURES]
        drv.p(
            f"{views.plural(len(shown), 'driver')} drawn (typical drivers first); every driver's fits are "
            "in the fits table above. Axes follow the bulk of the points; values beyond are drawn at the edge."
        )
        groups = views.indicator_groups_of(dec, fits)
        inds = [i for g in groups.values() for i in g if i in dict.fromkeys(["t_f", "t_nf", "dv_nb", *chosen])]
        for d in shown:
            for i in inds:
                drv.figure(f"driver_{d}_{i}", indicator_vs_speed(dec, fits, d, i, fits_by_direction=side_fits))
        return [ind, sty, drv]
    return [ind, sty]


def _runs(ws: Workspace) -> list[Section]:
    from dashboard import figures, views
    from rl.evaluation.crossval_store import list_crossvals, load_crossval
    from rl.plots import decision_agreement, indicators_at_decisions, training_curves
    from laneprint.provenance import analysis_mark
    from rl.runs import list_runs, load_run

    runs = list_runs(ws)
    evaluated = [r for r in runs["run_id"] if (ws.runs_dir / r / "evaluation.json").exists()] if len(runs) else []
    cvs = list_crossvals(ws)
    out = []
    overview = Section("Agents: every evaluated run")
    if not evaluated:
        overview.p(f"No evaluated run yet: `laneprint train --style NAME --workspace {ws.root}`.")
        return [overview]
    shown = runs[runs["run_id"].isin(evaluated)]
    stale = shown[shown["analysis"] == "earlier"]["run_id"].tolist()
    if stale:
        overview.warn(
            f"{len(stale)} of {len(shown)} runs were made with an earlier analysis (its styles or reference "
            f"lines have changed since): re-run them ({', '.join(stale)}). Column `analysis` says which."
        )
    overview.table("runs", shown)
    if len(cvs):
        overview.p("Every stored cross-validation (held out by session), balanced accuracy per policy:")
        overview.table("crossvals", views.crossvals_view(cvs))
    out.append(overview)
    fleet_of = {rid: (_read_config(ws, rid).get("fleet_id") or "") for rid in evaluated}
    for fid in dict.fromkeys(f for f in fleet_of.values() if f):
        out.append(_fleet(ws, fid))
    for rid in [r for r in evaluated if not fleet_of[r]]:
        run = load_run(ws, rid)
        cfg, ev = run["config"], run["evaluation"] or {}
        sec = Section(f"Run {rid}")
        tgt = cfg.get("target", {})
        sec.p(
            f"{tgt.get('kind')} {tgt.get('name')}, reward {cfg.get('reward')}, lines {cfg.get('lines_source')}, "
            f"seed {cfg.get('seed')}, {(run['status'] or {}).get('episode', '?')} episodes."
        )
        sec.p(views.learner_text(cfg))
        mark = run["analysis_mark"]
        if mark["analysis"] == "earlier":
            sec.warn(
                f"{mark['analysis_label']}: this run was made with analysis {mark['analysis_fingerprint']}, the "
                f"current one is {mark['current_analysis_fingerprint']} (styles or reference lines changed). "
                f"`laneprint train --{tgt.get('kind')} {tgt.get('name')} --workspace {ws.root}`."
            )
        else:
            sec.p(f"Analysis: {mark['analysis_label']}.")
        in_sample = ev.get("summary_members") or ev.get("summary")
        sec.p("In-sample: agent vs greedy benchmark vs imitation vs driver (on the decisions it was trained on).")
        sec.table(f"{rid}_in_sample", views.evaluation_table(in_sample))
        sec.p(views.EVAL_DEFINITION)
        metrics = run["metrics"]
        if metrics is not None and len(metrics) and ("loss" not in metrics or metrics["loss"].isna().all()):
            sec.warn(
                "This agent never updated its network (no loss in any episode): its figures are those of "
                "an untrained network."
            )
        cv = None
        own = ws.runs_dir / rid / "crossval.json"
        if own.exists():
            cv = json.loads(own.read_text())
        elif len(cvs):
            mine = views.default_crossval(cvs, rid, tgt)
            cv = load_crossval(ws, mine) if mine else None
        if cv:
            cv_mark = analysis_mark(cv.get("analysis_fingerprint"), ws.analysis_fingerprint())
            sec.p("Held out (cross-validation): " + views.scored_line(cv) + f"; {cv_mark['analysis_label']}.")
            sec.table(f"{rid}_held_out", views.crossval_table(cv.get("summary"), in_sample))
            sec.figure(f"{rid}_held_out_vs_in_sample", figures.heldout_vs_insample(cv.get("summary"), in_sample))
        else:
            sec.p(f"No cross-validation of this run: `laneprint crossval --run {rid} --workspace {ws.root}`.")
        if cfg.get("lines"):
            sec.figure(f"{rid}_fig10", indicators_at_decisions(run["eval_changes"], cfg["lines"]))
        sec.figure(f"{rid}_fig11_agent", decision_agreement(run["eval_states"], who="agent"))
        sec.figure(f"{rid}_fig11_greedy", decision_agreement(run["eval_states"], who="greedy"))
        sec.figure(
            f"{rid}_fig9", training_curves(metrics, learning_starts=(cfg.get("dqn") or {}).get("learning_starts"))
        )
        out.append(sec)
    return out


def _drives(ws: Workspace) -> list[Section]:
    """The closed-loop drives (`laneprint drive`, WORKSPACE/drives/*/drive.json): who made each lane change,
    per section and in total, and the drive beside its drivers."""
    from dashboard import views

    found = []
    for path in sorted((ws.root / "drives").glob("*/drive.json")):
        try:
            found.append((path.parent.name, json.loads(path.read_text())))
        except (OSError, ValueError):
            continue
    if not found:
        return []
    sec = Section("Closed-loop drives in SUMO")
    sec.p(views.DRIVE_RULE_NOTE)
    for name, d in found:
        sec.p(f"{views.drive_label(name, d)}. {views.drive_made_by_text(d)}")
        sec.table(f"drive_{name}_made_by", views.drive_made_by_table(d))
        fid = d.get("fidelity") or {}
        if "rate" in fid:
            from rl.plots import drive_fidelity

            sec.figure(f"drive_{name}_fidelity", drive_fidelity(fid))
    return [sec]


def _read_config(ws: Workspace, run_id: str) -> dict[str, Any]:
    try:
        return json.loads((ws.runs_dir / run_id / "config.json").read_text())
    except (OSError, ValueError):
        return {}


def _fleet(ws: Workspace, fleet_id: str) -> Section:
    """A fleet's agents side by side, as the dashboard's Results page shows them: one table row per agent
    (its figures against greedy and imitation) and one figure, not four figures per agent (a 100-agent
    fleet made the report 400 figures and minutes long)."""
    from dashboard import figures, views
    from rl.fleet.store import fleet_table

    table = fleet_table(ws, fleet_id)
    sec = Section(f"Fleet {fleet_id}")
    sec.p(
        f"{views.plural(len(table), 'agent')} trained together, each on its own target. " + views.fleet_headline(table)
    )
    sec.table(f"fleet_{fleet_id}", views.fleet_view(table))
    sec.figure(f"fleet_{fleet_id}_agreement", figures.fleet_agreement(table))
    sec.p(
        "Each agent's training curves and Figs. 10-11 are on the dashboard's Results page (Runs); runs trained "
        "alone have them here."
    )
    return sec


def provenance(ws: Workspace) -> dict[str, Any]:
    """Code version, the analysis settings, the data fingerprints: what the report was made from."""
    from clustering.pipeline import code_version

    meta = ws.read_meta("analysis") if ws.has_table("analysis", "decisions") else {}
    recs = ws.recordings()
    return {
        "generated_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "workspace": str(ws.root),
        "code": code_version(),
        "data_fingerprint": ws.fingerprint(),
        "analysis_fingerprint": ws.analysis_fingerprint() if meta else None,
        "analysis_data_fingerprint": meta.get("data_fingerprint"),
        "analysis_is_current": (meta.get("data_fingerprint") == ws.fingerprint()) if meta else None,
        "analysis_code": meta.get("code"),
        "analysis_settings": meta.get("settings"),
        "recordings": {str(r["recording_id"]): str(r.get("source_name", "")) for _, r in recs.iterrows()},
    }


def build_report(ws: Workspace) -> tuple[list[Section], dict[str, Any]]:
    """The report's sections and its provenance; a `UserError` when the workspace has no recordings."""
    if not ws.root.is_dir():
        raise UserError(f"no workspace at {ws.root}")
    sections = [_study(ws), *_analysis(ws), *_runs(ws), *_drives(ws)]
    return sections, provenance(ws)


_CSS = """body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;
color:#222}h1{font-size:1.8em}h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;font-size:12px;margin:.5em 0 1em}td,th{border:1px solid #ddd;padding:2px 6px;
text-align:left}th{background:#f3f3f3;position:sticky;top:0}.scroll{max-height:420px;overflow:auto}.warn{background:#fff4e5;
border-left:4px solid #f59e0b;padding:.5em 1em}.fig{margin:1em 0}nav a{margin-right:1em}code{background:#f3f3f3}
"""


def _cell(x: Any) -> str:
    if x is None or x is pd.NA or (isinstance(x, float) and x != x) or x is pd.NaT:
        return ""
    if isinstance(x, float):
        return f"{x:.4g}"
    return html.escape(str(x))


def _table_html(frame: pd.DataFrame) -> str:
    """The frame as an HTML table (what `DataFrame.to_html(index=False, na_rep='', float_format='{:.4g}')`
    writes, a tenth of its time: it formatted each cell through several layers)."""
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in frame.columns)
    cols = [frame[c].astype(object).tolist() for c in frame.columns]
    body = "".join("<tr>" + "".join(f"<td>{_cell(x)}</td>" for x in row) + "</tr>" for row in zip(*cols))
    return f'<div class="scroll"><table class="dataframe"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table></div>'


def render_html(sections: list[Section], prov: dict[str, Any], title: str = "laneprint report") -> str:
    """The report as one HTML document: plotly.js inlined once, no reference to any other host."""
    from plotly.offline import get_plotlyjs

    from dashboard.figures import fit_title

    parts = [
        f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
        f"<style>{_CSS}</style><script type='text/javascript'>{get_plotlyjs()}</script></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f"<p>Workspace <code>{html.escape(prov['workspace'])}</code>, generated {prov['generated_at']} by "
        f"laneprint {html.escape(str((prov.get('code') or {}).get('version')))} (commit "
        f"{html.escape(str((prov.get('code') or {}).get('git_commit')))}); data fingerprint "
        f"<code>{prov['data_fingerprint']}</code>.</p>",
    ]
    if prov.get("analysis_is_current") is False:
        parts.append(
            "<p class='warn'>Recordings were added or removed since the analysis ran: its tables describe "
            "an older set of recordings.</p>"
        )
    parts.append(
        "<nav>"
        + "".join(f"<a href='#s{i}'>{html.escape(s.title)}</a>" for i, s in enumerate(sections))
        + "<a href='#provenance'>Provenance</a></nav>"
    )
    for i, sec in enumerate(sections):
        parts.append(f"<h2 id='s{i}'>{html.escape(sec.title)}</h2>")
        for kind, item in sec.items:
            if kind == "p":
                parts.append(f"<p>{html.escape(item)}</p>")
            elif kind == "warn":
                parts.append(f"<p class='warn'>{html.escape(item)}</p>")
            elif kind == "table":
                parts.append(_table_html(item[1]))
            else:
                parts.append(
                    "<div class='fig'>"
                    + fit_title(item[1]).to_html(
                        full_html=False,
                        include_plotlyjs=False,
                        div_id=f"fig-{_safe(item[0])}",
                        config={"displaylogo": False, "toImageButtonOptions": {"format": "svg"}},
                    )
                    + "</div>"
                )
    parts.append(
        "<h2 id='provenance'>Provenance</h2><pre>"
        + html.escape(json.dumps(prov, indent=2, default=str))
        + "</pre></body></html>"
    )
    return "".join(parts)


def write_assets(
    sections: list[Section], folder: Path, svg: bool = True, drawer: "SvgDrawer | None" = None
) -> dict[str, Any]:
    """Every table as CSV and every figure as Plotly JSON under `folder`; with `svg` and `kaleido`
    installed (the `report` extra), every figure as SVG too, all drawn in one headless Chrome session
    (kaleido starts the browser once per call: 10-15 s). `svg_note` says why there is no SVG, if so."""
    folder.mkdir(parents=True, exist_ok=True)
    written: dict[str, Any] = {"tables": [], "figures": [], "svg": [], "svg_note": ""}
    figures: list[tuple[go.Figure, Path]] = []
    for sec in sections:
        for kind, item in sec.items:
            if kind == "table":
                path = folder / f"{_safe(item[0])}.csv"
                item[1].to_csv(path, index=False)
                written["tables"].append(path.name)
            elif kind == "figure":
                path = folder / f"{_safe(item[0])}.json"
                path.write_text(item[1].to_json())
                written["figures"].append(path.name)
                figures.append((item[1], folder / f"{_safe(item[0])}.svg"))
    if svg and figures:
        written["svg"], written["svg_note"] = write_svgs(figures, drawer)
    return written


def write_svgs(figures: list[tuple[go.Figure, Path]], drawer: "SvgDrawer | None" = None) -> tuple[list[str], str]:
    """The figures as SVG files with kaleido (one browser session for all: `drawer`'s, started earlier, or
    a new one); (names written, '' or why none)."""
    try:
        import kaleido  # noqa: F401
    except ImportError:
        return [], "no SVG: kaleido is not installed (pip install -e '.[report]')"
    import plotly.io as pio

    try:
        if drawer is not None:
            drawer.draw(figures)
        else:
            pio.write_images([f for f, _ in figures], [p for _, p in figures], format="svg")
    except Exception as exc:  # kaleido finds no Chrome/Chromium (or it fails to start): the JSON stays
        for _, p in figures:
            p.unlink(missing_ok=True)
        return [], f"no SVG: kaleido could not draw ({type(exc).__name__}: {str(exc).splitlines()[0][:200]})"
    return [p.name for _, p in figures], ""


class SvgDrawer:
    """kaleido's headless Chromium started in a thread of its own before the report's figures are built
    (its start, 10-15 s on the 2-core machine, then overlaps them), drawing them all once they are.
    MathJax is off (no request to its CDN). A Chromium that fails to start is reported by `draw`."""

    def __init__(self) -> None:
        import concurrent.futures
        import queue
        import threading

        self._jobs: "queue.Queue[list[dict] | None]" = queue.Queue(maxsize=1)
        self._done: concurrent.futures.Future = concurrent.futures.Future()
        threading.Thread(target=self._run, name="laneprint-svg", daemon=True).start()

    @classmethod
    def start(cls) -> "SvgDrawer | None":
        """A started drawer, or None when kaleido is not installed."""
        try:
            import kaleido  # noqa: F401
        except ImportError:
            return None
        return cls()

    def _run(self) -> None:
        import asyncio

        try:
            asyncio.run(self._serve())
        except BaseException as exc:  # noqa: BLE001 - handed to `draw`
            if not self._done.done():
                self._done.set_exception(exc)

    async def _serve(self) -> None:
        import asyncio

        import kaleido

        async with kaleido.Kaleido(n=2, mathjax=False) as k:
            specs = await asyncio.to_thread(self._jobs.get)
            if specs:
                await k.write_fig_from_object(specs, cancel_on_error=True)
        if not self._done.done():
            self._done.set_result(None)

    def draw(self, figures: list[tuple[go.Figure, Path]], timeout_s: float = 900) -> None:
        """Write each figure as SVG to its path (plotly's default size, 700 x 500)."""
        import plotly.io as pio

        size = {
            "format": "svg",
            "width": pio.defaults.default_width,
            "height": pio.defaults.default_height,
            "scale": pio.defaults.default_scale,
        }
        self._jobs.put([{"fig": f.to_plotly_json(), "path": p, "opts": dict(size)} for f, p in figures])
        self._done.result(timeout=timeout_s)

    def close(self) -> None:
        """Stop the browser if nothing was drawn (the thread ends once its session is closed)."""
        try:
            self._jobs.put_nowait(None)
        except Exception:  # noqa: BLE001 - the figures are queued already
            pass


def report_html(ws: Workspace) -> str:
    """The report of a workspace as an HTML string (the dashboard's download)."""
    sections, prov = build_report(ws)
    return render_html(sections, prov)


def write_report(ws: Workspace, out: Path | None = None, assets: bool = True, svg: bool = True) -> dict[str, Any]:
    """Write the report to `out` (default `<workspace>/report.html`) and, with `assets`, its tables and
    figures into `<out stem>_files/` (with `svg`, the figures as SVG too where kaleido is installed);
    returns what was written."""
    from laneprint.workspace import atomic_write_bytes

    start = time.perf_counter()
    out = Path(out) if out is not None else ws.root / "report.html"
    if out.exists() and out.is_dir():
        raise SettingError(f"{{0}} {out} is a folder: give a file name such as report.html", "out")
    if not out.parent.exists():
        raise SettingError(f"{{0}} {out}: folder {out.parent} does not exist", "out")
    drawer = SvgDrawer.start() if assets and svg else None  # Chromium starts while the figures are built
    try:
        sections, prov = build_report(ws)
        text = render_html(sections, prov)
        atomic_write_bytes(out, text.encode())
        written = write_assets(sections, out.with_name(out.stem + "_files"), svg=svg, drawer=drawer) if assets else {}
    finally:
        if drawer is not None:
            drawer.close()
    n_fig = sum(1 for s in sections for k, _ in s.items if k == "figure")
    n_tab = sum(1 for s in sections for k, _ in s.items if k == "table")
    return {
        "report": str(out),
        "bytes": len(text.encode()),
        "figures": n_fig,
        "tables": n_tab,
        "assets": str(out.with_name(out.stem + "_files")) if assets else None,
        "written": written,
        "sections": [s.title for s in sections],
        "seconds": round(time.perf_counter() - start, 2),
    }
