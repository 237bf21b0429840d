"""Styles: the drivers' clusters, members and typical drivers, reference lines; rerun with other k."""

import streamlit as st

from clustering.plots import DIRECTION_NAMES, cluster_scatter, following_headways, line_directions, reference_lines
from dashboard import docs_site, figures, loaders, views, widgets
from dashboard.context import workspace
from dashboard.widgets import progress_to
from indicators.settings import FEATURE_FITS, INDICATOR_SETS, AnalysisSettings
from laneprint.errors import UserError

CHOOSE_K = {"fixed k": None, "silhouette": "silhouette", "BIC": "bic"}
#: The receding-leader threshold the form's tick box switches on [m/s].
RECEDING_MPS = AnalysisSettings.max_receding_mps
#: Feature sets the form offers ('auto': chosen by the data).
FEATURE_SETS = ("consensus", "auto", "separated", "reliable", "heldout", "behaviour", *INDICATOR_SETS)


def rerun_form(ws, current: dict) -> None:
    """k and the way it is chosen; 'Run analysis' calls the analysis stage."""
    now = views.analysis_settings(current)  # the last run's settings, defaults where missing
    with st.form("analysis_form"):
        c1, c2, c3, c4 = st.columns(4)
        k = c1.number_input("Number of styles k", min_value=2, max_value=8, step=1, value=int(now.k), key="k")
        labels = list(CHOOSE_K)
        chosen = next((lab for lab, v in CHOOSE_K.items() if v == now.choose_k), "fixed k")
        how = c2.selectbox("k chosen by", labels, index=labels.index(chosen), key="choose_k")
        fits = list(dict.fromkeys([now.feature_fit, *FEATURE_FITS]))
        fit = c3.selectbox(
            "Feature line fit",
            fits,
            key="feature_fit",
            help=docs_site.with_more("How each driver's line is fitted to make the clustering features", "readings"),
        )
        sets = list(dict.fromkeys([now.features, *FEATURE_SETS]))
        features = c4.selectbox(
            "Features",
            sets,
            key="features",
            help="What the styles are read by; 'consensus' (the default): the styles the readings with the "
            "most say agree on (well separated, stable, and agreed with by the other parameters); 'auto': the indicator set best separated and "
            "most stable; 'separated': the best separated and most stable of the indicator "
            "sets and the behaviour readings; 'reliable': the two behaviour parameters in "
            "which the drivers differ most reliably; 'heldout': the reading whose styles best predict the drivers' "
            "held-out decisions and following headways; 'behaviour': the same among the "
            "drivers' critical gaps, following headway and free speed only" + "\n\n" + docs_site.more("readings"),
        )
        d1, d2, _ = st.columns([1, 2, 1])
        levels = list(dict.fromkeys([now.acceptance_fit, *FEATURE_FITS]))
        level = d1.selectbox(
            "Gap / headway features",
            levels,
            key="acceptance_fit",
            help="How a driver's gaps, headways and relative speeds are read: 'trimmed' (its "
            "level, a trimmed mean), 'median', or a line\n\n" + docs_site.more("indicators"),
        )
        receding = d2.checkbox(
            "Leave out front gaps to leaders pulling away (> 1 m/s)",
            value=now.max_receding_mps is not None,
            key="receding",
            help=docs_site.with_more(
                "The driver is not held by a leader running away (as at "
                "most returns to the right); unticked, every front gap "
                "and headway is used",
                "used_values",
            ),
        )
        go = st.form_submit_button("Run analysis", type="primary")
    if go:
        from clustering.pipeline import analyze

        changes = {
            "k": int(k),
            "choose_k": CHOOSE_K[how],
            "feature_fit": fit,
            "features": features,
            "acceptance_fit": level,
            "max_receding_mps": RECEDING_MPS if receding else None,
        }
        settings = views.analysis_settings(current, **changes)
        bar = st.progress(0.0, text="Analysing...")
        names = views.recording_names(loaders.recordings(str(ws.root), loaders.recordings_stamp(ws.root)))
        try:
            analyze(ws, settings, progress_to(bar, "Analysing...", views.progress_text(names)))
        except UserError as exc:  # the stage's one-line reason; keep the app alive
            bar.empty()
            st.warning(f"Analysis did not run: {exc}")
            return
        bar.empty()
        st.rerun()


def main() -> None:
    st.title("Styles")
    widgets.page_help("styles")
    ws = workspace()
    key = loaders.analysis_stamp(ws.root)
    tables = loaders.analysis(str(ws.root), key)
    meta = loaders.analysis_meta(str(ws.root), key)
    if loaders.recordings(str(ws.root), loaders.recordings_stamp(ws.root)).empty:
        st.info(
            f"No recordings yet: upload logs on the Data page first (or `{views.cli_hint('ingest', ws.root, 'LOGS/')}`)."
        )
        return
    if loaders.analysis_is_stale(ws.root):
        st.info("Recordings were added or removed since this analysis ran: press 'Run analysis' to update it.")
    rerun_form(ws, meta.get("settings", {}))

    styles = tables.get("styles")
    if styles is None:
        st.info("No analysis yet: press 'Run analysis'.")
        return
    for warning in views.analysis_warnings(meta):
        st.warning(warning)
    if by_side := views.presses_by_direction_text(meta):
        st.markdown(f"{views.plural(len(styles), 'driver')}; {by_side}.")
    chosen = views.chosen_indicators(meta)
    feats = (meta.get("summary") or {}).get("features") or {}
    st.subheader("Features the styles were read by")
    if feats:
        st.markdown(
            f"Feature set **{feats.get('chosen')}** ({', '.join(chosen)}), requested "
            f"`{feats.get('requested')}`; each driver's line of each indicator read at "
            f"{views.speeds_text(meta)}."
        )
        candidates = views.feature_candidates(meta)
        if len(candidates):
            st.caption(
                "Every feature set measured: silhouette (how well the styles are separated, -1 to 1), "
                "stability (share of bootstrap resamples of each driver's presses that keep its style), "
                "the score the choice is made on, and at how many presses the median driver has a value "
                "of the set's sparsest indicator ('auto' leaves out a set read at fewer presses than a "
                "fit takes)."
            )
            st.dataframe(candidates, hide_index=True, width="stretch")
    else:
        st.markdown(
            f"Indicators **{', '.join(chosen)}**, each driver's line read at {views.speeds_text(meta)} "
            "(an analysis made before the feature sets were chosen by the data: run it again to compare them)."
        )
    scores = tables.get("k_scores")
    if scores is not None and len(scores):
        how = meta.get("settings", {}).get("choose_k") or "k"
        st.caption(f"k chosen by {how}: {styles['style'].nunique()} styles")
        st.plotly_chart(figures.k_scores(scores, how), key="k_scores")
    st.subheader("Drivers in feature space")
    st.plotly_chart(cluster_scatter(styles, indicators=chosen), key="clusters")
    following = tables.get("following")
    if following is not None and len(following):
        st.subheader("Headway kept in steady following")
        st.caption(
            "Over the whole drive, press or not: every stretch of at least 2 s at its leader's speed "
            "(within 1 m/s) while held below its free speed. The styles read each driver's short end "
            "(the bar), where the feature set holds thw_follow."
        )
        st.plotly_chart(following_headways(following, styles), key="following")
    st.subheader("Members and typical drivers")
    st.caption(
        "What sets each style apart: its members' median critical values (the smallest gap they accept, "
        "how close a leader comes before they want out; estimated from their presses and the states they "
        "let pass) and the headway they keep while following. " + docs_site.more("behaviour")
    )
    st.table(views.style_summary(styles, meta).set_index("style"))
    unsure = views.unsure_drivers(styles)
    st.subheader("Unsure drivers")
    if unsure.empty:
        st.caption("Every driver's style is sure: its own presses and every plausible reading agree.")
    else:
        st.caption(
            "Confidence is the share of draws of the driver's own estimates that keep its style, times the "
            "share of plausible readings that agree, at most (n + 1) / (n + 2) for n presses. "
            + docs_site.more("confidence")
        )
        st.table(unsure.set_index("driver"))
    st.subheader("Reference lines per style")
    lines = tables.get("reference_lines")
    if lines is not None:
        sides = line_directions(lines)
        direction = (
            st.radio(
                "Lines fitted on",
                sides,
                format_func=DIRECTION_NAMES.get,
                horizontal=True,
                key="ref_direction",
                help=docs_site.with_more(
                    "Overtaking (target lane to the left) and returning (to the right) presses have "
                    "their own lines where the typical driver's side has enough presses",
                    "directions",
                ),
            )
            if len(sides) > 1
            else "both"
        )
        st.plotly_chart(
            reference_lines(lines, indicators=views.reference_indicators(lines, chosen), direction=direction),
            key="ref_lines",
        )
        if table := widgets.lazy_expander("Reference lines table", key="ref_lines_open"):
            table.dataframe(lines, hide_index=True, width="stretch")
    if assignment := widgets.lazy_expander("Per-driver style assignment", key="assignment_open"):
        assignment.dataframe(styles, hide_index=True, width="stretch")
    widgets.next_step(ws, "styles")


main()
