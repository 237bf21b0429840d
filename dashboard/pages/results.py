"""Results: the trained agent against the greedy benchmark and the driver; two runs compared."""

import streamlit as st

from dashboard import figures, jobs, views
from dashboard.context import workspace


def evaluated_runs(ws) -> list[str]:
    return [rid for rid in jobs.run_ids(ws) if (ws.runs_dir / rid / "evaluation.json").exists()]


def main() -> None:
    st.title("Results")
    ws = workspace()
    runs = evaluated_runs(ws)
    if not runs:
        st.info("No evaluated runs yet: start one on the Training page (runs are evaluated when they "
                "finish), or run `laneprint evaluate RUN_ID`.")
        return
    run_id = st.selectbox("Run", runs, key="result_run")
    evaluation = jobs.read_json(ws.runs_dir / run_id / "evaluation.json") or {}
    st.subheader("Agent vs greedy benchmark vs driver")
    st.dataframe(views.evaluation_table(evaluation), hide_index=True, width="stretch")
    for title, name in (("Indicators at the decisions (Fig. 10)", "indicators_at_decisions"),
                        ("Same and opposite decisions (Fig. 11)", "decision_agreement")):
        plot = figures.stage_plot("rl.plots", name)
        if plot is not None:
            st.subheader(title)
            st.plotly_chart(plot(evaluation), key=f"{name}_{run_id}")

    st.subheader("Compare two runs")
    if len(runs) < 2:
        st.caption("Train a second run to compare.")
        return
    c1, c2 = st.columns(2)
    a = c1.selectbox("Run A", runs, index=0, key="cmp_a")
    b = c2.selectbox("Run B", runs, index=1, key="cmp_b")
    evals = {rid: views.evaluation_table(jobs.read_json(ws.runs_dir / rid / "evaluation.json") or {})
             for rid in dict.fromkeys([a, b])}
    st.dataframe(views.compare_runs(evals), hide_index=True, width="stretch")
    metrics = {rid: jobs.read_metrics(ws.runs_dir / rid / "metrics.jsonl") for rid in dict.fromkeys([a, b])}
    c1, c2 = st.columns(2)
    c1.plotly_chart(figures.runs_curves(metrics, "loss", "loss [-]"), key="cmp_loss")
    c2.plotly_chart(figures.runs_curves(metrics, "mean_step_reward", "mean step reward [-]"), key="cmp_reward")


main()
