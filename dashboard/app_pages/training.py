"""Training: launch DQN runs in the background, watch them live, cancel, list past runs;
cross-validate a finished run (held-out figures, shown on the Results page)."""

import streamlit as st

from dashboard import jobs, loaders, training, widgets
from dashboard.context import poll_seconds, workspace
from rl.plots import training_curves
from rl.runs import read_metrics


def launch_form(ws) -> None:
    tables = loaders.analysis(str(ws.root), loaders.analysis_stamp(ws.root))
    recs = loaders.recordings(str(ws.root), loaders.recordings_stamp(ws.root))
    lines_table = tables.get("reference_lines")
    kind = st.radio("Imitate", ["style", "driver"], horizontal=True, key="target_kind")
    names = (training.style_targets(lines_table) if kind == "style"
             else training.driver_targets(lines_table, recs))
    with st.form("train_form"):
        c1, c2, c3 = st.columns(3)
        name = c1.selectbox(kind.capitalize(), names, key="target_name")
        reward = c2.selectbox("Reward", training.rewards(), key="reward")
        line_opts = [o for o in ("analysis", "paper")
                     if (o == "analysis" and lines_table is not None) or (o == "paper" and kind == "style")]
        lines = c3.selectbox("Reference lines", line_opts, key="lines",
                             help="'analysis': lines fitted on this workspace; 'paper': Table 1 of the study")
        c4, c5 = st.columns(2)
        episodes = c4.number_input("Episodes", min_value=1, max_value=100_000, step=100,
                                   value=training.default_episodes(), key="episodes")
        seed = c5.number_input("Seed", min_value=0, value=0, step=1, key="seed")
        values = {}
        with st.expander("Hyperparameters (the trainer's defaults, from Table 2 of the study)"):
            st.caption(training.defaults_note())
            cols = st.columns(3)
            for i, (field, default) in enumerate(training.hyperparameters().items()):
                label = training.FORM_SETTINGS[field][0]
                values[field] = cols[i % 3].number_input(
                    label, value=default, key=f"hp_{field}",
                    format="%g" if isinstance(default, float) else "%d",
                    step=None if isinstance(default, float) else 1)
        submitted = st.form_submit_button("Start training", type="primary", disabled=not (names and line_opts))
    if not (names and line_opts):
        st.info("Nothing to train for yet: ingest logs (Data page) and run the analysis (Styles page).")
    if submitted and name:
        req = jobs.TrainRequest(kind, str(name), int(episodes), int(seed), reward, lines,
                                training.changed_options(values))
        problem = training.check_target(ws, req)
        if problem:
            st.warning(f"Not started: {problem}")
            return
        run_id = jobs.launch(ws, req)
        st.session_state.setdefault("launched", []).append(run_id)
        st.toast(f"Started run {run_id}")


def run_panel(ws, run_id: str, status: dict) -> None:
    """Progress, curves and a Cancel button for one run."""
    done, total = int(status.get("episode") or 0), int(status.get("episodes") or 0)
    frac = min(1.0, done / total) if total else 0.0
    st.progress(frac, text=f"{run_id}: {status.get('state')} — episode {done}/{total or '?'}")
    metrics = read_metrics(ws.runs_dir / run_id / "metrics.jsonl")
    if len(metrics):
        st.plotly_chart(training_curves(metrics), key=f"curves_{run_id}")
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
        st.caption("A run can be cross-validated once its training has ended (it takes the run's target and "
                   "settings from its config.json).")
        return
    launched = jobs.crossval_job_ids(ws, run_id)
    if launched and launched[0] in running:
        st.caption("Under way: its progress is shown under Cross-validations above.")
        return
    if launched:
        widgets.crossval_panel(ws, launched[0], jobs.crossval_status(ws, launched[0]))
    widgets.crossval_launcher(ws, run_id, (config.get("dqn") or {}).get("episodes"))


def main() -> None:
    st.title("Training")
    ws = workspace()
    launch_form(ws)

    active = [rid for rid in jobs.run_ids(ws) if jobs.run_status(ws, rid).get("state") in jobs.ACTIVE_STATES]

    @st.fragment(run_every=poll_seconds() if active else None)
    def live_runs() -> None:
        st.subheader("Running")
        still = []
        for rid in active:
            status = jobs.run_status(ws, rid)
            run_panel(ws, rid, status)
            if status.get("state") in jobs.ACTIVE_STATES:
                still.append(rid)
        if not active:
            st.caption("No training running.")
        elif len(still) < len(active):
            st.session_state["show_run"] = next(r for r in active if r not in still)  # show the one that ended
            st.rerun()  # redraw the whole page: past runs, polling off when none is left

    live_runs()

    st.subheader("Cross-validations")
    cv_running = widgets.live_crossvals(ws)
    if not cv_running:
        st.caption("No cross-validation running: pick a finished run below to cross-validate it.")

    st.subheader("Runs")
    table = jobs.runs_table(ws)
    if table.empty:
        st.caption("No runs yet.")
        return
    st.dataframe(table, hide_index=True, width="stretch")
    finished = [r for r in table["run_id"] if r not in active]
    if finished:
        rid = st.selectbox("Show run", finished, key="show_run")
        status = jobs.run_status(ws, rid)
        run_panel(ws, rid, status)
        crossval_section(ws, rid, status, cv_running)


main()
