"""Training: launch DQN runs in the background, watch them live, cancel, list past runs;
train a fleet (an agent for every driver or every style) and follow it agent by agent;
cross-validate a finished run (held-out figures, shown on the Results page)."""

import pandas as pd
import streamlit as st

from dashboard import docs_site, jobs, loaders, training, views, widgets
from dashboard.context import poll_seconds, workspace
from rl.fleet import store as fleet_store
from rl.plots import training_curves
from rl.runs import read_metrics


def launch_form(ws) -> None:
    """Target, reward, lines, episodes, seed and the trainer's settings; 'Start training' launches
    `laneprint train` in the background. Plain widgets, not an `st.form`: Enter in a field commits
    its value and starts nothing (in a form it submitted the form: a second, identical run followed
    the click). A request that cannot learn, or one identical to a run under way, is not started."""
    tables = loaders.training_inputs(str(ws.root), loaders.analysis_stamp(ws.root))
    recs = loaders.recordings(str(ws.root), loaders.recordings_stamp(ws.root))
    lines_table = tables.get("reference_lines")
    kind = st.radio("Imitate", ["style", "driver"], horizontal=True, key="target_kind")
    names = training.style_targets(lines_table) if kind == "style" else training.driver_targets(lines_table, recs)
    c1, c2, c3 = st.columns(3)
    name = c1.selectbox(kind.capitalize(), names, key="target_name")
    reward = c2.selectbox("Reward", training.rewards(), key="reward")
    line_opts = [
        o
        for o in ("analysis", "paper")
        if (o == "analysis" and lines_table is not None) or (o == "paper" and kind == "style")
    ]
    lines = c3.selectbox(
        "Reference lines",
        line_opts,
        key="lines",
        help=docs_site.with_more(
            "'analysis': lines fitted on this workspace; 'paper': Table 1 of the study", "formulations"
        ),
    )
    c4, c5, c6 = st.columns(3)
    learner = c4.selectbox(
        "Learner",
        training.learners(reward, lines),
        key="learner",
        help="'auto': the one of the DQN and the trees that agrees better across inner folds "
        "of the target's sessions (a few minutes); 'dqn': the study's DQN; 'trees': "
        "fitted Q iteration with boosted trees on the recorded approaches (no episodes, "
        "fitted in a minute). The trees fit the decisions reward only\n\n" + docs_site.more("learners"),
    )
    episodes = c5.number_input(
        "Episodes",
        min_value=1,
        max_value=100_000,
        step=100,
        value=training.default_episodes(),
        key="episodes",
        disabled=learner == "trees",
    )
    seed = c6.number_input("Seed", min_value=0, value=0, step=1, key="seed")
    values = {}
    with st.expander("Hyperparameters (the trainer's defaults, from Table 2 of the study)"):
        st.caption(training.defaults_note())
        cols = st.columns(3)
        for i, (field, default) in enumerate(training.hyperparameters().items()):
            label = training.FORM_SETTINGS[field][0]
            values[field] = cols[i % 3].number_input(
                label,
                value=default,
                key=f"hp_{field}",
                format="%g" if isinstance(default, float) else "%d",
                step=None if isinstance(default, float) else 1,
            )
    options = {"--learner": learner} | (training.changed_options(values) if learner != "trees" else {})
    req = jobs.TrainRequest(kind, str(name), int(episodes), int(seed), reward, lines, options) if name else None
    verdict, why = training.learning_check(ws, req, values, tables) if req and learner != "trees" else ("", "")
    if verdict:
        (st.warning if verdict == "refuse" else st.info)(why)
    submitted = st.button(
        "Start training",
        type="primary",
        key="start_training",
        disabled=not (names and line_opts) or verdict == "refuse",
    )
    if not (names and line_opts):
        st.info("Nothing to train for yet: ingest logs (Data page) and run the analysis (Styles page).")
    if submitted and req:
        problem = training.check_target(ws, req) or jobs.identical_active_run(ws, req)
        if problem:
            st.warning(f"Not started: {problem}")
            return
        run_id = jobs.launch(ws, req)
        st.session_state.setdefault("launched", []).append(run_id)
        st.toast(f"Started run {run_id}")


def run_panel(ws, run_id: str, status: dict, smoothing: float = 0.95, live: bool = True) -> None:
    """Progress, curves and a Cancel button for one run; a finished run's curves (`live=False`) are
    drawn once their expander is opened (a 2,000-point chart was half of this page's drawing time)."""
    done, total = int(status.get("episode") or 0), int(status.get("episodes") or 0)
    frac = min(1.0, done / total) if total else 0.0
    st.progress(frac, text=f"{run_id}: {status.get('state')} — episode {done}/{total or '?'}" + views.run_doing(status))
    box = st.container() if live else widgets.lazy_expander("Training curves (Fig. 9)", key="finished_curves_open")
    metrics = read_metrics(ws.runs_dir / run_id / "metrics.jsonl") if box is not None else ()
    if len(metrics):
        config = jobs.read_json(ws.runs_dir / run_id / "config.json") or {}
        box.plotly_chart(
            training_curves(metrics, smoothing, learning_starts=(config.get("dqn") or {}).get("learning_starts")),
            key=f"curves_{run_id}",
        )
    if status.get("state") in jobs.ACTIVE_STATES:
        if st.button("Cancel", key=f"cancel_{run_id}"):
            jobs.cancel(ws, run_id)
        return
    if status.get("state") == "interrupted":
        st.warning(status.get("message") or "interrupted")
    if status.get("log"):
        st.code(status["log"], language=None)


def crossval_section(ws, run_id: str, status: dict, running: list[str]) -> None:
    """Held-out figures for a finished run: its last cross-validation job, and a button for a new one."""
    st.markdown(f"**Cross-validate {run_id}** (held-out figures of agent, greedy and imitation)")
    config = jobs.read_json(ws.runs_dir / run_id / "config.json")
    if status.get("state") in jobs.ACTIVE_STATES or not config:
        st.caption(
            "A run can be cross-validated once its training has ended (it takes the run's target and "
            "settings from its config.json)."
        )
        return
    launched = jobs.crossval_job_ids(ws, run_id)
    if launched and launched[0] in running:
        st.caption("Under way: its progress is shown under Cross-validations above.")
        return
    if launched:
        widgets.crossval_panel(ws, launched[0], jobs.crossval_status(ws, launched[0]))
    widgets.crossval_launcher(ws, run_id, (config.get("dqn") or {}).get("episodes"))


def fleet_form(ws) -> None:
    """Train every driver (or every style) as one fleet: `laneprint train --drivers all | --styles all`."""
    lines_table = loaders.training_inputs(str(ws.root), loaders.analysis_stamp(ws.root)).get("reference_lines")
    recs = loaders.recordings(str(ws.root), loaders.recordings_stamp(ws.root))
    with st.form("fleet_form"):
        c1, c2, c3, c4 = st.columns(4)
        kind = c1.radio("An agent for every", ["drivers", "styles"], horizontal=True, key="fleet_kind")
        seeds = c2.number_input("Seeds per target", min_value=1, max_value=20, value=1, step=1, key="fleet_seeds")
        episodes = c3.number_input(
            "Episodes per agent",
            min_value=1,
            max_value=100_000,
            step=100,
            value=training.default_episodes(),
            key="fleet_episodes",
        )
        backend = c4.selectbox(
            "Backend",
            ["local", "ray"],
            key="fleet_backend",
            help=docs_site.with_more(
                "'local': all agents batched in one process; 'ray': "
                "shards of agents on Ray workers (a local Ray instance "
                "with this machine's cores)",
                "ray",
            ),
        )
        submitted = st.form_submit_button("Train fleet", type="primary")
    req = jobs.FleetRequest(kind, int(episodes), int(seeds), backend=backend)
    targets = training.driver_targets(lines_table, recs) if kind == "drivers" else training.style_targets(lines_table)
    st.caption(
        f"{len(targets)} {kind} x {int(seeds)} seed(s) = {len(targets) * int(seeds)} agents, trained together "
        f"and each evaluated as it finishes: `{views.command_text(jobs.fleet_command(req, ws.root))}`"
    )
    if not submitted:
        return
    if kind == "drivers" and (lines_table is None or not (lines_table.get("scope") == "driver").any()):
        st.warning(
            "Not started: a fleet of drivers needs each driver's reference lines: run the analysis (Styles page) first."
        )
        return
    job_id = jobs.launch_fleet(ws, req)
    st.session_state.setdefault("fleets_launched", []).append(job_id)
    st.toast(f"Started fleet job {job_id}")
    st.rerun()  # redraw with the fleet under way (and polling on)


def fleet_panel(ws, job_id: str, status: dict) -> None:
    """A fleet's progress (agents done, episodes summed over its runs), Cancel, and its agents as they finish."""
    state, fleet_id = status.get("state"), status.get("fleet_id")
    if not fleet_id:
        st.progress(0.0, text=f"fleet job {job_id}: {state} — {status.get('message', '')}")
    else:
        table = loaders.fleet_table(str(ws.root), fleet_id, loaders.fleets_stamp(ws.root))
        p = fleet_store.fleet_progress(table)
        frac = min(1.0, p["episode"] / p["episodes"]) if p["episodes"] else 0.0
        st.progress(
            frac,
            text=f"fleet {fleet_id}: {state} — {p['n_done']}/{p['n_runs']} agents done, "
            f"{p['episode']}/{p['episodes'] or '?'} episodes; {p['n_meeting_target']} of "
            f"{p['n_evaluated']} evaluated meet their target",
        )
        # a fleet under way shows its agents as they finish; a finished one once asked (Results has it in full)
        box = (
            st.container()
            if state in jobs.ACTIVE_STATES
            else widgets.lazy_expander(f"Agents of fleet {fleet_id} ({len(table)})", key=f"fleet_agents_open_{job_id}")
        )
        if box is not None:
            box.dataframe(
                views.fleet_view(table),
                hide_index=True,
                width="stretch",
                height=min(420, 38 + 35 * len(table)),
                key=f"fleet_table_{job_id}",
            )
    if state in jobs.ACTIVE_STATES:
        if st.button("Cancel fleet", key=f"fleet_cancel_{job_id}"):
            jobs.cancel_fleet(ws, job_id)
    elif status.get("log"):
        st.code(status["log"], language=None)


def fleets_section(ws) -> None:
    """Fleets under way, refreshed until they end; else the newest launched one as it ended."""
    st.subheader("Fleets")
    launched = jobs.fleet_job_ids(ws)
    active = [j for j in launched if jobs.fleet_job_status(ws, j)["state"] in jobs.ACTIVE_STATES]
    widgets.live_panels(active, lambda j: jobs.fleet_job_status(ws, j), lambda j, status: fleet_panel(ws, j, status))
    if not active and launched:
        fleet_panel(ws, launched[0], jobs.fleet_job_status(ws, launched[0]))
        st.caption("Every fleet, agent by agent, against greedy and imitation: Results page, Fleets.")
    elif not launched:
        st.caption("No fleet launched from here yet.")
    fleet_form(ws)


def main() -> None:
    st.title("Training")
    widgets.page_help("agents")
    ws = workspace()
    launch_form(ws)
    smoothing = widgets.smoothing_slider()

    # a fleet's agents are followed in its own panel (below), not one by one
    active = [
        rid
        for rid in jobs.run_ids(ws)
        if jobs.run_status(ws, rid).get("state") in jobs.ACTIVE_STATES and not jobs.in_fleet(ws, rid)
    ]

    listed: dict[str, pd.DataFrame] = {}  # the runs table the live view drew, reused below in the same run

    @st.fragment(run_every=poll_seconds() if active else None)
    def live_runs() -> None:
        st.subheader("Running")
        st.markdown(widgets.NO_FADE_CSS, unsafe_allow_html=True)  # a live view is not drawn greyed out
        still = []
        for rid in active:
            status = jobs.run_status(ws, rid)
            run_panel(ws, rid, status, smoothing)
            if status.get("state") in jobs.ACTIVE_STATES:
                still.append(rid)
        if not active:
            st.caption("No training running.")
        elif len(still) < len(active):
            st.rerun()  # redraw the whole page: past runs (the one that ended shown), polling off when none is left
        # the runs table follows the live panel: a running run is not shown 'starting', episode 0
        st.subheader("Runs")
        table = listed["table"] = jobs.runs_table(ws)
        if table.empty:
            st.caption("No runs yet.")
        else:
            st.dataframe(table, hide_index=True, width="stretch", key="runs_table")

    live_runs()
    fleets_section(ws)

    st.subheader("Cross-validations")
    cv_running = widgets.live_crossvals(ws)
    if not cv_running:
        st.caption("No cross-validation running: pick a finished run below to cross-validate it.")

    st.subheader("A finished run")
    table = listed.get("table")
    table = jobs.runs_table(ws) if table is None else table
    if table.empty:
        st.caption("No runs yet.")
        return
    finished = table.loc[~table["state"].isin(jobs.ACTIVE_STATES), "run_id"].tolist()
    if finished:
        # a run that ended since this session last drew the list is shown, however the page learnt of it
        # (the live panel's rerun, or a rerun that came first); the list is newest first
        seen = st.session_state.get("finished_seen")
        ended = [r for r in finished if seen is not None and r not in seen]
        if ended:
            st.session_state["show_run"] = ended[0]
        st.session_state["finished_seen"] = finished
        rid = st.selectbox("Show run", finished, key="show_run")
        status = jobs.run_status(ws, rid)
        run_panel(ws, rid, status, smoothing, live=status.get("state") in jobs.ACTIVE_STATES)
        crossval_section(ws, rid, status, cv_running)
    else:
        st.caption("No run has finished yet.")
    widgets.next_step(ws, "training")


main()
