"""Styles: the drivers' clusters, members and typical drivers, reference lines; rerun with other k."""

import streamlit as st

from clustering.plots import cluster_scatter, reference_lines
from dashboard import figures, loaders, views, widgets
from dashboard.context import workspace
from dashboard.widgets import progress_to
from indicators.settings import FEATURE_FITS
from laneprint.errors import UserError

CHOOSE_K = {"fixed k": None, "silhouette": "silhouette", "BIC": "bic"}


def rerun_form(ws, current: dict) -> None:
    """k and the way it is chosen; 'Run analysis' calls the analysis stage."""
    now = views.analysis_settings(current)  # the last run's settings, defaults where missing
    with st.form("analysis_form"):
        c1, c2, c3 = st.columns(3)
        k = c1.number_input("Number of styles k", min_value=2, max_value=8, step=1, value=int(now.k), key="k")
        labels = list(CHOOSE_K)
        chosen = next((lab for lab, v in CHOOSE_K.items() if v == now.choose_k), "fixed k")
        how = c2.selectbox("k chosen by", labels, index=labels.index(chosen), key="choose_k")
        fits = list(dict.fromkeys([now.feature_fit, *FEATURE_FITS]))
        fit = c3.selectbox("Feature line fit", fits, key="feature_fit",
                           help="How each driver's line is fitted to make the clustering features")
        go = st.form_submit_button("Run analysis", type="primary")
    if go:
        from clustering.pipeline import analyze

        settings = views.analysis_settings(current, k=int(k), choose_k=CHOOSE_K[how], feature_fit=fit)
        bar = st.progress(0.0, text="Analysing...")
        try:
            analyze(ws, settings, progress_to(bar, "Analysing..."))
        except UserError as exc:  # the stage's one-line reason; keep the app alive
            bar.empty()
            st.warning(f"Analysis did not run: {exc}")
            return
        bar.empty()
        st.rerun()


def main() -> None:
    st.title("Styles")
    ws = workspace()
    key = loaders.analysis_stamp(ws.root)
    tables = loaders.analysis(str(ws.root), key)
    meta = loaders.analysis_meta(str(ws.root), key)
    if loaders.recordings(str(ws.root), loaders.recordings_stamp(ws.root)).empty:
        st.info("No recordings yet: upload logs on the Data page first.")
        return
    if loaders.analysis_is_stale(ws.root):
        st.info("Recordings were added or removed since this analysis ran: press 'Run analysis' to update it.")
    rerun_form(ws, meta.get("settings", {}))

    styles = tables.get("styles")
    if styles is None:
        st.info("No analysis yet: press 'Run analysis'.")
        return
    scores = tables.get("k_scores")
    if scores is not None and len(scores):
        how = meta.get("settings", {}).get("choose_k") or "k"
        st.caption(f"k chosen by {how}: {styles['style'].nunique()} styles")
        st.plotly_chart(figures.k_scores(scores, how), key="k_scores")
    st.subheader("Drivers in feature space")
    st.plotly_chart(cluster_scatter(styles), key="clusters")
    st.subheader("Members and typical drivers")
    st.dataframe(views.style_summary(styles), hide_index=True, width="stretch")
    st.subheader("Reference lines per style")
    lines = tables.get("reference_lines")
    if lines is not None:
        st.plotly_chart(reference_lines(lines), key="ref_lines")
        if table := widgets.lazy_expander("Reference lines table", key="ref_lines_open"):
            table.dataframe(lines, hide_index=True, width="stretch")
    if assignment := widgets.lazy_expander("Per-driver style assignment", key="assignment_open"):
        assignment.dataframe(styles, hide_index=True, width="stretch")


main()
