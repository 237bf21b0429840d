"""Results: the trained agent against the greedy benchmark, the imitation classifier and the driver,
in-sample and held out (cross-validation); two runs compared; a fleet's agents side by side;
every stored cross-validation."""

import plotly.graph_objects as go
import streamlit as st

from dashboard import docs_site, figures, jobs, loaders, views, widgets
from dashboard.context import workspace
from rl.plots import decision_agreement, drive_fidelity, indicators_at_decisions, training_curves


def evaluated_runs(ws) -> list[str]:
    return [
        rid
        for rid in jobs.run_ids(ws)
        if (ws.runs_dir / rid / "evaluation.json").exists() and (ws.runs_dir / rid / "config.json").exists()
    ]


def in_sample_tables(ev: dict) -> None:
    heading, caption = views.evaluation_heading(ev)
    st.subheader(heading)
    st.caption(caption)
    scored = str(ev.get("scored_on") or "in-sample")
    if ev.get("summary_typical"):
        st.caption(
            f"On the typical driver's decisions ({views.md_escape(ev.get('typical_driver'))}, "
            f"{ev.get('n_decisions_typical')} decisions), in-sample:"
        )
        st.dataframe(views.evaluation_table(ev["summary_typical"]), hide_index=True, width="stretch")
    n = len(ev.get("drivers", []))
    whose = "the driver's" if n == 1 else f"all {n} drivers'"
    st.caption(
        f"On {whose} decisions ({ev.get('n_decisions_members')} decisions, "
        f"{ev.get('n_states_members')} states), {scored}:"
    )
    st.dataframe(
        views.evaluation_table(ev.get("summary_members") or ev.get("summary")), hide_index=True, width="stretch"
    )
    st.caption(views.EVAL_DEFINITION)


def held_out_figures(result: dict, in_sample: list | None, key: str) -> None:
    """The cross-validation's three policies, next to the in-sample ones when given."""
    st.caption(views.scored_line(result))
    st.dataframe(views.crossval_table(result.get("summary"), in_sample), hide_index=True, width="stretch")
    if in_sample is not None and not any(r.get("who") == "imitation" for r in in_sample):
        st.caption(
            "This run's in-sample evaluation has no imitation row (evaluated before the imitation "
            "benchmark existed): `laneprint evaluate RUN_ID` adds it."
        )
    bars = figures.heldout_vs_insample(result.get("summary"), in_sample)
    st.plotly_chart(bars, key=f"cv_bars_{key}")
    widgets.figure_downloads(bars, f"held-out-vs-in-sample-{key}", key=f"cv_bars_{key}")
    unscored = views.unscored_table(result)
    if len(unscored):
        st.markdown(f"**Not scored** ({int(unscored['decisions'].sum())} decisions), by reason:")
        st.dataframe(unscored, hide_index=True, width="stretch")
    else:
        st.caption("Every decision of the target's drivers was scored.")
    if per_fold := widgets.lazy_expander("Per fold", key=f"cv_per_fold_open_{key}"):
        with per_fold:
            st.plotly_chart(figures.crossval_folds(result.get("per_fold")), key=f"cv_per_fold_{key}")
            for note in result.get("notes") or []:
                st.caption(note)


def held_out(ws, run_id: str, run: dict) -> None:
    """Held-out figures (the run's cross-validation, else the newest of its target) beside the in-sample ones."""
    st.subheader("In-sample vs held out (cross-validation)")
    cfg, ev = run["config"], run["evaluation"] or {}
    root = str(ws.root)
    running = widgets.live_crossvals(ws, run_id)
    table = loaders.crossvals(root, loaders.crossvals_stamp(ws.root))
    own = loaders.run_crossval(root, run_id, loaders.run_crossval_stamp(ws.root, run_id))
    view = views.crossvals_view(table)
    labels = {r["crossval_id"]: views.crossval_label(r) for r in view.to_dict("records")}
    if own and own.get("crossval_id") not in labels:  # its folder is gone; runs/<id>/crossval.json remains
        labels = {
            own["crossval_id"]: views.crossval_label(
                {
                    **own,
                    "target_kind": own["target"]["kind"],
                    "target": own["target"]["name"],
                    "reward": own["env"]["reward"]["name"],
                }
            ),
            **labels,
        }
    ids = list(labels)
    default = views.default_crossval(table, run_id, cfg.get("target", {}), (own or {}).get("crossval_id"))
    if own and default is None:
        default = own.get("crossval_id")
    if default is None:
        how = "one is under way (above); or run" if running else "start one below, or run"
        st.info(
            f"No cross-validation of this run (or of {cfg['target']['kind']} {cfg['target']['name']}) yet: "
            f"{how} `laneprint crossval --run {run_id} -w {ws.root}`."
        )
        if not running:
            widgets.crossval_launcher(ws, run_id, (cfg.get("dqn") or {}).get("episodes"))
        if not ids:
            return
        pick = st.selectbox(
            "Or show a stored cross-validation",
            ids,
            index=None,
            format_func=labels.__getitem__,
            key=f"cv_pick_{run_id}",
        )
        if pick is None:
            return
    else:
        pick = st.selectbox(
            "Held-out figures from",
            ids,
            index=ids.index(default),
            format_func=labels.__getitem__,
            key=f"cv_pick_{run_id}",
        )
    if own and pick == own.get("crossval_id"):
        result = own
    else:
        result = loaders.crossval(root, pick, loaders.crossvals_stamp(ws.root))
    cv_level, cv_text = views.analysis_notice(
        result.get("analysis_fingerprint"), loaders.current_analysis(ws.root), "cross-validation"
    )
    if cv_level == "warning":
        st.warning(cv_text)
    elif cv_level == "info":
        st.caption(cv_text)
    differences = views.crossval_differences(result, run_id, cfg)
    if differences:
        st.caption("Not exactly this run's settings: " + "; ".join(differences) + ".")
    held_out_figures(result, ev.get("summary_members") or ev.get("summary"), key=run_id)
    if default is not None and not running:
        if again := widgets.lazy_expander("Cross-validate this run again", key=f"cv_again_open_{run_id}"):
            with again:
                widgets.crossval_launcher(ws, run_id, (cfg.get("dqn") or {}).get("episodes"))


def downloads(ws, run_id: str, run: dict) -> None:
    """The run's results (JSON, CSV) and its trained policy (ONNX with policy.json), built when clicked."""
    own = loaders.run_crossval(str(ws.root), run_id, loaders.run_crossval_stamp(ws.root, run_id))
    c1, c2, c3 = st.columns(3)
    c1.download_button(
        "Results (JSON)",
        data=lambda: views.run_results_json(run, own),
        file_name=f"{run_id}.json",
        mime="application/json",
        key=f"dl_json_{run_id}",
        on_click="ignore",
        icon=None,
        help="config, status, in-sample evaluation and the run's cross-validation",
    )
    c2.download_button(
        "Results (CSV)",
        data=lambda: views.run_results_csv(run, own),
        file_name=f"{run_id}.csv",
        mime="text/csv",
        key=f"dl_csv_{run_id}",
        on_click="ignore",
        help="one row per policy: in-sample figures, held out with 95 % intervals when cross-validated",
    )
    policy_download(ws, run_id, run, c3)


def policy_download(ws, run_id: str, run: dict, box) -> None:
    """The ONNX policy: one click when its export is current; else a button that exports it first and says on
    the page why when that fails (or, without onnx/onnxruntime, what to install instead of a button)."""
    error_key = f"onnx_error_{run_id}"
    if not run.get("has_weights"):
        box.caption("No trained weights to export.")
    elif hint := jobs.onnx_missing():
        box.info(f"Policy (ONNX): {hint}.")
    elif jobs.policy_is_current(ws, run_id):
        box.download_button(
            "Policy (ONNX + policy.json, zip)",
            data=lambda: jobs.policy_zip(ws, run_id),
            file_name=f"{run_id}-policy.zip",
            mime="application/zip",
            key=f"dl_onnx_{run_id}",
            on_click="ignore",
            help=docs_site.with_more(
                "`laneprint export RUN_ID --format onnx`: checked against torch with onnxruntime", "onnx"
            ),
        )
    elif box.button(
        "Export the policy (ONNX)",
        key=f"export_onnx_{run_id}",
        help=docs_site.with_more(
            "`laneprint export RUN_ID --format onnx`: writes policy.onnx, policy.json and README.md, "
            "checked against torch with onnxruntime (a few seconds); then the zip downloads",
            "onnx",
        ),
    ):
        with box, st.spinner("exporting and checking with onnxruntime..."):
            st.session_state[error_key] = jobs.export_policy(ws, run_id)
        if st.session_state[error_key] is None:
            st.rerun()
    if err := st.session_state.get(error_key):
        box.error(f"The policy could not be exported: {err}")


def report_download(ws) -> None:
    """The study as one self-contained HTML file (`laneprint report`), built when clicked."""
    st.download_button(
        "Report of the study (HTML)",
        data=lambda: jobs.report_bytes(ws),
        file_name="report.html",
        mime="text/html",
        key="dl_report",
        on_click="ignore",
        type="primary",
        help=docs_site.with_more(
            "`laneprint report`: data, fits and flags, styles, every run's figures; opens offline", "report"
        ),
    )


def one_run(ws, run_id: str) -> None:
    run = loaders.run(str(ws.root), run_id, loaders.run_stamp(ws.root, run_id))
    ev = run["evaluation"]
    cfg = run["config"]
    st.markdown(views.run_header(run_id, cfg, run["status"]))
    st.caption(views.learner_text(cfg))
    analysis_banner(ws, cfg)
    never = views.never_learnt(run["metrics"], cfg)
    if never:
        st.warning(never)
    downloads(ws, run_id, run)
    in_sample_tables(ev)
    held_out(ws, run_id, run)
    where = str((ev or {}).get("scored_on") or "in-sample")
    st.subheader(f"Indicators at the decisions against the reference lines (Fig. 10, {where})")
    fig10 = indicators_at_decisions(run["eval_changes"], cfg["lines"])
    st.plotly_chart(fig10, key=f"fig10_{run_id}")
    widgets.figure_downloads(fig10, f"{run_id}-fig10-indicators", key=f"fig10_{run_id}")
    st.subheader(f"Same and opposite decisions as the drivers (Fig. 11, {where})")
    left, right = st.columns(2)
    fig11 = decision_agreement(run["eval_states"], who="agent")
    left.plotly_chart(figures.compact(go.Figure(fig11)), key=f"fig11a_{run_id}")
    right.plotly_chart(figures.compact(decision_agreement(run["eval_states"], who="greedy")), key=f"fig11g_{run_id}")
    widgets.figure_downloads(fig11, f"{run_id}-fig11-agent", key=f"fig11a_{run_id}")
    curves_of(run_id, run)


def analysis_banner(ws, cfg: dict) -> None:
    """Whether the run was made with the current analysis; a re-run offered when it was not."""
    level, text = views.analysis_notice(cfg.get("analysis_fingerprint"), loaders.current_analysis(ws.root))
    if level == "ok":
        st.caption(text)
        return
    (st.warning if level == "warning" else st.info)(text, icon=":material/history:")
    kind, name = cfg.get("target", {}).get("kind"), str(cfg.get("target", {}).get("name"))
    st.caption(
        f"Re-run it on the Training page ({kind} {name}), or `{views.cli_hint('train', ws.root, f'--{kind}', name)}`."
    )


@st.fragment
def curves_of(run_id: str, run: dict) -> None:
    """Fig. 9 in an expander that draws when opened. A fragment: opening it (or moving its smoothing
    slider) reruns and redraws this part only, not Figs. 10 and 11 above it."""
    if curves := widgets.lazy_expander("Training curves (Fig. 9)", key=f"fig9_open_{run_id}"):
        with curves:
            smoothing = widgets.smoothing_slider(key=f"smoothing_{run_id}")
            st.plotly_chart(
                training_curves(
                    run["metrics"], smoothing, learning_starts=(run["config"].get("dqn") or {}).get("learning_starts")
                ),
                key=f"fig9_{run_id}",
            )


def compare(ws, runs: list[str]) -> None:
    st.subheader("Compare two runs (in-sample)")
    if len(runs) < 2:
        st.caption("Train a second run to compare.")
        return
    c1, c2 = st.columns(2)
    a = c1.selectbox("Run A", runs, index=0, key="cmp_a")
    b = c2.selectbox("Run B", runs, index=1, key="cmp_b")
    picked = list(dict.fromkeys([a, b]))
    loaded = {rid: loaders.run(str(ws.root), rid, loaders.run_stamp(ws.root, rid)) for rid in picked}
    st.dataframe(
        views.compare_runs(
            {rid: views.evaluation_table((r["evaluation"] or {}).get("summary")) for rid, r in loaded.items()}
        ),
        hide_index=True,
        width="stretch",
    )
    compare_curves({rid: r["metrics"] for rid, r in loaded.items()})


@st.fragment
def compare_curves(metrics: dict) -> None:
    """The two runs' loss and reward curves, drawn once their expander is opened (a fragment: opening it
    redraws this part only)."""
    if box := widgets.lazy_expander("Loss and reward curves of the two runs", key="cmp_curves_open"):
        with box:
            smoothing = widgets.smoothing_slider(key="cmp_smoothing")
            c1, c2 = st.columns(2)
            c1.plotly_chart(figures.runs_curves(metrics, "loss", smoothing=smoothing), key="cmp_loss")
            c2.plotly_chart(figures.runs_curves(metrics, "mean_step_reward", smoothing=smoothing), key="cmp_reward")


def fleets(ws) -> None:
    """A fleet's agents side by side: one row per agent (sortable), and each target's agreement with its drivers."""
    root = str(ws.root)
    key = loaders.fleets_stamp(ws.root)
    listed = loaders.fleets(root, key)
    if listed.empty:
        return
    st.subheader(f"Fleets ({len(listed)})")
    labels = {r["fleet_id"]: views.fleet_label(r) for r in listed.to_dict("records")}
    fleet_id = st.selectbox("Fleet", list(labels), format_func=labels.__getitem__, key="fleet_pick")
    table = loaders.fleet_table(root, fleet_id, key)
    st.caption(views.fleet_headline(table) + " Click a column header to sort.")
    st.dataframe(views.fleet_view(table), hide_index=True, width="stretch", key="fleet_agents")
    st.plotly_chart(figures.fleet_agreement(table), key="fleet_agreement")


def drives(ws) -> None:
    """Closed-loop drives (`laneprint drive`) beside their target drivers."""
    found = loaders.drives(str(ws.root), loaders.drives_stamp(ws.root))
    if not found:
        return
    st.subheader(f"Closed-loop drives in SUMO ({len(found)})")
    st.caption(
        "`laneprint drive RUN_ID --engine sumo` writes here (WORKSPACE/drives/); each drive beside the "
        "target's drivers, read from the logs the same way: lane changes per km within +-20 % is the goal "
        "(shaded), and each indicator's median at the agent's presses inside the drivers' IQR."
    )
    pick = st.selectbox("Drive", list(found), key="drive_pick", format_func=lambda k: views.drive_label(k, found[k]))
    d = found[pick]
    st.markdown(f"**{views.drive_made_by_text(d)}**")
    st.dataframe(views.drive_made_by_table(d), hide_index=True, width="stretch", key="drive_made_by")
    st.caption(docs_site.with_more(views.DRIVE_RULE_NOTE, "closed_loop"))
    if "rate" not in d.get("fidelity", {}):
        st.info(
            d.get("fidelity", {}).get(
                "note", "This drive has no comparison with drivers (driven by an older laneprint): drive it again."
            )
        )
        return
    st.plotly_chart(drive_fidelity(d["fidelity"]), key="drive_fidelity")


def stored_crossvals(ws, show_one: bool) -> None:
    """Every stored cross-validation; with `show_one` (no run to show them beside), a picker for one."""
    table = views.crossvals_view(loaders.crossvals(str(ws.root), loaders.crossvals_stamp(ws.root)))
    if table.empty:
        return
    st.subheader(f"Stored cross-validations ({len(table)})")
    st.dataframe(table, hide_index=True, width="stretch")
    if show_one:
        labels = {r["crossval_id"]: views.crossval_label(r) for r in table.to_dict("records")}
        pick = st.selectbox("Show", list(labels), format_func=labels.__getitem__, key="cv_pick_any")
        held_out_figures(loaders.crossval(str(ws.root), pick, loaders.crossvals_stamp(ws.root)), None, key="any")


def main() -> None:
    st.title("Results")
    widgets.page_help("scoring")
    ws = workspace()
    report_download(ws)
    runs = evaluated_runs(ws)
    if not runs:
        st.info(
            "No evaluated runs yet: start one on the Training page (runs are evaluated when they "
            "finish), or run `laneprint evaluate RUN_ID`."
        )
        fleets(ws)
        drives(ws)
        stored_crossvals(ws, show_one=True)
        return
    wanted = st.query_params.get("run")  # the Personalise page links to its finished run
    one_run(ws, st.selectbox("Run", runs, key="result_run", index=runs.index(wanted) if wanted in runs else 0))
    compare(ws, runs)
    fleets(ws)
    drives(ws)
    stored_crossvals(ws, show_one=False)
    widgets.next_step(ws, "results")


main()
