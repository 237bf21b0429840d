"""Personalise: upload one session of a new driver, see its style with the confidence, and
train its agent from the other drivers' (`laneprint personalize`), followed live."""

import json
import sys
from datetime import datetime, timezone

import pandas as pd
import plotly.graph_objects as go
import streamlit as st

from dashboard import docs_site, jobs, loaders, uploads, views, widgets
from dashboard.context import EPISODES_ENV, env_int, max_upload_bytes, workspace
from dashboard.widgets import progress_to
from laneprint.errors import UserError


def upload_session(ws) -> None:
    """One session of a new driver: saved, ingested under the driver id given, then the analysis rerun."""
    st.subheader("A new driver's session")
    gen = st.session_state.get("p_uploader_gen", 0)
    c1, c2 = st.columns([3, 1])
    file = c1.file_uploader("One MCAP or CSV log", key=f"p_upload_{gen}")
    driver_id = c2.text_input("Driver id", key="p_driver_id", placeholder="e.g. D11")
    if not st.button("Ingest and analyse", key="p_ingest", disabled=not (file and driver_id.strip()), type="primary"):
        return
    if file is None:  # the button is disabled without a file
        return
    from clustering.pipeline import analyze
    from ingest.pipeline import ingest_paths
    from clustering.pipeline import stored_settings

    saved = uploads.save_upload(file.name, file.size, file, ws.root / "uploads", max_upload_bytes())
    if saved.path is None:
        st.warning(f"Not ingested: {saved.reason}")
        return
    bar = st.progress(0.0, text="Ingesting...")
    try:
        report = ingest_paths([saved.path], ws, driver_id=driver_id.strip(), progress=progress_to(bar, "Ingesting..."))
        refused = [f for f in report.to_dict()["files"] if f.get("status") == "rejected"]
        if refused:
            uploads.discard(saved.path, ws.root / "uploads")
            raise UserError(refused[0].get("reason", "refused"))
        analyze(ws, stored_settings(ws), progress_to(bar, "Analysing..."))
    except UserError as exc:
        bar.empty()
        st.warning(f"Not done: {exc}")
        return
    bar.empty()
    st.session_state["p_driver"] = driver_id.strip()
    st.session_state["p_uploader_gen"] = gen + 1
    st.rerun()


def style_figure(est) -> go.Figure:
    """The bootstrap share and the posterior of every style."""
    names = list(est.bootstrap)
    fig = go.Figure(
        [
            go.Bar(name="bootstrap over the decisions", x=names, y=[100 * est.bootstrap[n] for n in names]),
            go.Bar(name="clusterer's posterior", x=names, y=[100 * est.posterior[n] for n in names]),
        ]
    )
    fig.update_layout(
        barmode="group",
        yaxis_title="%",
        yaxis_range=[0, 100],
        height=300,
        margin={"t": 30, "b": 30},
        template="plotly_white",
    )
    return fig


@st.cache_data(show_spinner="Placing the driver among the styles...", max_entries=32)
def style_estimate(root: str, stamp: tuple[int, ...], driver: str, k: int):
    """The style of `driver`'s first `k` decisions among the other drivers (cached on the analysis's
    stamp: the population is clustered again and 200 resamples drawn, too slow for every rerun)."""
    from clustering.pipeline import stored_settings
    from laneprint.workspace import Workspace
    from rl.personalize.split import driver_rows, first_decisions
    from rl.personalize.style import estimate_style, fit_population

    tables = loaders.analysis(root, stamp)
    decisions, following = tables["decisions"], tables.get("following")
    others = [d for d in sorted(decisions["driver_id"].astype(str).unique()) if d != driver]
    pop = fit_population(decisions, others, stored_settings(Workspace(root)), following)
    return estimate_style(
        pop, first_decisions(driver_rows(decisions, driver), k), n_bootstrap=200, seed=0, following=following
    )


def style_section(ws, decisions: pd.DataFrame) -> tuple[str, int] | None:
    """Pick a driver and K; show the style its first K decisions give, with the confidence."""
    from rl.personalize.split import decision_order, driver_rows

    st.subheader("Style from its decisions")
    drivers = sorted(decisions["driver_id"].astype(str).unique())
    if len(drivers) < 2:
        st.info("Personalising needs other drivers to start from: ingest a study first (Data page).")
        return None
    chosen = st.session_state.get("p_driver")
    c1, c2 = st.columns(2)
    driver = c1.selectbox("Driver", drivers, index=drivers.index(chosen) if chosen in drivers else 0, key="p_sel")
    rows = driver_rows(decisions, driver)
    n = len(decision_order(rows))
    k = int(c2.number_input(f"First K decisions (of {n})", min_value=1, max_value=max(n, 1), value=n, key="p_k"))
    try:
        est = style_estimate(str(ws.root), loaders.analysis_stamp(ws.root), driver, k)
    except UserError as exc:
        st.warning(str(exc))
        return None
    st.metric(
        f"Style of {driver} from {k} decisions",
        est.style,
        f"confidence {100 * est.confidence:.0f} %",
        delta_color="off",
        delta_arrow="off",
    )
    st.plotly_chart(style_figure(est), key="p_style_fig")
    st.caption(
        f"Clustered on the other {len(drivers) - 1} drivers with the analysis's features; compared on "
        f"{', '.join(est.compared)} (the speeds its presses cover). Confidence: the share of {est.n_bootstrap} "
        "resamples of its decisions that give this style."
    )
    return driver, k


def launch(ws, driver: str, k: int, base: str, seed: int, fine_tune: bool = False) -> str:
    """Start `laneprint personalize` in the background (a run like the Training page's); returns the run id."""
    slug = "".join(c if c.isalnum() else "-" for c in driver.lower())
    run_id = f"{datetime.now(timezone.utc):%Y%m%d-%H%M%S}-{slug}-personalized-k{k}-s{seed}"
    cmd = [
        sys.executable,
        "-m",
        "laneprint.app.cli",
        "personalize",
        "--driver",
        driver,
        "--decisions",
        str(k),
        "--from",
        base,
        "--seed",
        str(seed),
        "--run-id",
        run_id,
        "--workspace",
        str(ws.root),
    ] + (["--fine-tune"] if fine_tune else [])
    if episodes := env_int(EPISODES_ENV, None):  # the demo's (and tests') small count: the base agents' episodes
        cmd += ["--base-episodes", str(episodes)]
    jobs._spawn(
        jobs.jobs_dir(ws),
        run_id,
        cmd,
        ws.root,  # the Training page's launcher: runs table, status, log
        {
            "run_id": run_id,
            "request": {
                "kind": "personalized",
                "driver": driver,
                "decisions": k,
                "from": base,
                "fine_tune": fine_tune,
                "seed": seed,
                "episodes": None,
            },
        },
    )
    return run_id


def run_panel(ws, run_id: str, status: dict) -> None:
    """Progress of one personalisation (base agent, then fine-tuning) with Cancel while it works; once it
    has finished, what it made and a link to its figures on the Results page."""
    state = status.get("state")
    if state in jobs.ACTIVE_STATES:
        st.progress(*views.personalize_progress(run_id, status))
        if st.button("Cancel", key=f"p_cancel_{run_id}"):
            jobs.cancel(ws, run_id)
        return
    if state == "done":
        p = loaders.personalized(str(ws.root), run_id, loaders.run_stamp(ws.root, run_id))
        st.success(views.personalize_done(run_id, status, p))
        st.markdown(f"[Open {run_id} on the Results page](results?run={run_id})")
        return
    st.warning(f"{run_id}: {state} — {status.get('message', '')}")
    if status.get("log"):
        st.code(status["log"], language=None)


def personalised_runs(ws) -> pd.DataFrame:
    """Every personalised run: driver, K, base, style and its figures on the decisions after the first K."""
    from laneprint.provenance import analysis_mark

    rows = []
    current = loaders.current_analysis(ws.root)
    for folder in sorted(ws.runs_dir.glob("*")) if ws.runs_dir.exists() else []:
        try:
            p = json.loads((folder / "personalize.json").read_text())
            p["base"]["from"], p["style"]["style"], p["style"]["confidence"]  # noqa: B018 (a complete record)
        except (OSError, ValueError, KeyError, TypeError):
            continue
        later = p.get("later_decisions") or {}
        lo, hi = later.get("balanced_accuracy_ci") or [None, None]
        rows.append(
            {
                "run": p["run_id"],
                "driver": p["driver"],
                "K": p["decisions"],
                "of": p["decisions_available"],
                "from": p["base"]["from"],
                "base": p["base"].get("chosen", p["base"]["from"]),
                "style": p["style"]["style"],
                "confidence": round(100 * p["style"]["confidence"]),
                "held out: decisions not given": later.get("n_decisions"),
                "balanced acc. [%]": None if not later else round(100 * later["balanced_accuracy"], 1),
                "95 % CI": None if lo is None else f"[{100 * lo:.1f}, {100 * hi:.1f}]",
                "timing MAE [s]": later.get("timing_mae_s"),
                "analysis": analysis_mark(p.get("analysis_fingerprint"), current)["analysis_label"],
            }
        )
    return pd.DataFrame(rows)


def launched_runs(ws) -> None:
    """The personalisations started from this page: live while under way, then the last one's result."""
    launched = st.session_state.get("p_launched", [])
    active = [r for r in launched if jobs.run_status(ws, r).get("state") in jobs.ACTIVE_STATES]
    if launched:
        st.subheader("Under way" if active else "Last personalisation")
        if active:  # polled until one ends, then the page reruns once
            widgets.live_panels(active, lambda r: jobs.run_status(ws, r), lambda r, status: run_panel(ws, r, status))
        else:  # drawn once: a finished run in the live panels made the page rerun without end
            run_panel(ws, launched[-1], jobs.run_status(ws, launched[-1]))


def main() -> None:
    st.title("Personalise")
    widgets.page_help("personal")
    ws = workspace()
    upload_session(ws)
    launched_runs(ws)
    tables = loaders.analysis(str(ws.root), loaders.analysis_stamp(ws.root))
    decisions = tables.get("decisions")
    if decisions is None or decisions.empty:
        st.info(f"No analysis yet: upload a study (Data page) and run `{views.cli_hint('analyze', ws.root)}`.")
        runs_table(ws)
        return
    picked = style_section(ws, decisions)
    if picked:
        driver, k = picked
        c1, c2 = st.columns(2)
        base = c1.radio(
            "Start from",
            ["blend", "fit", "style", "population", "auto"],
            horizontal=True,
            key="p_base",
            help="'blend' (the default): every style's agent and the population's at once, weighted by "
            "the style's bootstrap shares and their agreement with the K decisions (measured best "
            "held out, rl/README.md); 'fit': the agent of the style assigned above when its "
            "confidence is at least 80 %, else the candidate that agrees best with the K "
            "decisions; 'style': the agent of the style assigned above; 'population': of all "
            "other drivers; 'auto': the style's when its confidence is at least 80 %, else the "
            "population's\n\n" + docs_site.more("personal"),
        )
        seed = int(c2.number_input("Seed", min_value=0, value=0, step=1, key="p_seed"))
        fine_tune = st.checkbox(
            "Fine-tune on the K decisions",
            value=False,
            key="p_finetune",
            help="Off: the base agent as it is (measured better on SUMO studies).",
        )
        st.caption(
            f"`laneprint personalize --driver {driver} --decisions {k} --from {base}"
            f"{' --fine-tune' if fine_tune else ''} --seed {seed} -w {ws.root}`"
        )
        if st.button("Personalise", type="primary", key="p_start"):
            st.session_state.setdefault("p_launched", []).append(launch(ws, driver, k, base, seed, fine_tune))
            st.rerun()
    runs_table(ws)


def runs_table(ws) -> None:
    """Every personalised run, with the analysis it was made from."""
    table = personalised_runs(ws)
    if len(table):
        st.subheader("Personalised runs (learning-curve points)")
        st.dataframe(table, hide_index=True, width="stretch", key="p_runs")
        st.caption(
            "Held out: figures on each driver's decisions after its first K (not given, never seen by the "
            "agent); the runs are ordinary runs on the Results page. The benchmark of the whole curve: "
            "`python benchmarks/personalize.py -w WORKSPACE`."
        )


main()
