"""Results: the trained agent against the greedy benchmark and the driver; two runs compared."""

import streamlit as st

from dashboard import figures, jobs, loaders, views
from dashboard.context import workspace
from rl.plots import decision_agreement, indicators_at_decisions, training_curves


def evaluated_runs(ws) -> list[str]:
    return [rid for rid in jobs.run_ids(ws) if (ws.runs_dir / rid / "evaluation.json").exists()
            and (ws.runs_dir / rid / "config.json").exists()]


def one_run(ws, run_id: str) -> None:
    run = loaders.run(str(ws.root), run_id, loaders.run_stamp(ws.root, run_id))
    ev = run["evaluation"]
    cfg = run["config"]
    st.markdown(f"**{run_id}**: {cfg['target']['kind']} **{cfg['target']['name']}**, reward `{cfg.get('reward')}`, "
                f"lines `{cfg.get('lines_source')}`, seed {cfg.get('seed')}, "
                f"{(run['status'] or {}).get('episode', '?')} episodes")
    st.subheader("Agent vs greedy benchmark vs driver")
    if ev.get("summary_typical"):
        st.caption(f"On the typical driver's decisions ({ev.get('typical_driver')}, "
                   f"{ev.get('n_decisions_typical')} decisions):")
        st.dataframe(views.evaluation_table(ev["summary_typical"]), hide_index=True, width="stretch")
    st.caption(f"On all {len(ev.get('drivers', []))} drivers' decisions ({ev.get('n_decisions_members')} decisions, "
               f"{ev.get('n_states_members')} states):")
    st.dataframe(views.evaluation_table(ev.get("summary_members") or ev.get("summary")), hide_index=True,
                 width="stretch")
    st.subheader("Indicators at the decisions against the reference lines (Fig. 10)")
    st.plotly_chart(indicators_at_decisions(run["eval_changes"], cfg["lines"]), key=f"fig10_{run_id}")
    st.subheader("Same and opposite decisions as the drivers (Fig. 11)")
    left, right = st.columns(2)
    left.plotly_chart(figures.compact(decision_agreement(run["eval_states"], who="agent")), key=f"fig11a_{run_id}")
    right.plotly_chart(figures.compact(decision_agreement(run["eval_states"], who="greedy")),
                       key=f"fig11g_{run_id}")
    with st.expander("Training curves (Fig. 9)"):
        st.plotly_chart(training_curves(run["metrics"]), key=f"fig9_{run_id}")


def compare(ws, runs: list[str]) -> None:
    st.subheader("Compare two runs")
    if len(runs) < 2:
        st.caption("Train a second run to compare.")
        return
    c1, c2 = st.columns(2)
    a = c1.selectbox("Run A", runs, index=0, key="cmp_a")
    b = c2.selectbox("Run B", runs, index=1, key="cmp_b")
    picked = list(dict.fromkeys([a, b]))
    loaded = {rid: loaders.run(str(ws.root), rid, loaders.run_stamp(ws.root, rid)) for rid in picked}
    st.dataframe(views.compare_runs({rid: views.evaluation_table((r["evaluation"] or {}).get("summary"))
                                     for rid, r in loaded.items()}), hide_index=True, width="stretch")
    metrics = {rid: r["metrics"] for rid, r in loaded.items()}
    c1, c2 = st.columns(2)
    c1.plotly_chart(figures.runs_curves(metrics, "loss", "training loss [-]"), key="cmp_loss")
    c2.plotly_chart(figures.runs_curves(metrics, "mean_step_reward", "mean step reward [-]"), key="cmp_reward")


def main() -> None:
    st.title("Results")
    ws = workspace()
    runs = evaluated_runs(ws)
    if not runs:
        st.info("No evaluated runs yet: start one on the Training page (runs are evaluated when they "
                "finish), or run `laneprint evaluate RUN_ID`.")
        return
    one_run(ws, st.selectbox("Run", runs, key="result_run"))
    compare(ws, runs)


main()
