"""Drivers: one driver's indicators against speed with the OLS fits, correlations, fit summary."""

import streamlit as st

from dashboard import figures, loaders, views, widgets
from dashboard.context import workspace
from indicators.plots import correlation_table, indicator_vs_speed

INDICATORS = ("t_f", "t_nf", "dv_nb")


def main() -> None:
    st.title("Drivers")
    ws = workspace()
    tables = loaders.analysis(str(ws.root), loaders.analysis_stamp(ws.root))
    if "decisions" not in tables:
        st.info("No analysis yet: ingest logs on the Data page, then run the analysis on the Styles page "
                "(or `laneprint analyze`).")
        return
    if loaders.analysis_is_stale(ws.root):
        st.info("Recordings were added or removed since this analysis ran: run it again on the Styles page.")
    decisions, fits = tables["decisions"], tables.get("fits")
    drivers = views.drivers_of(tables)
    driver = st.selectbox("Driver", drivers, key="driver")
    styles = views.for_driver(tables.get("styles"), driver)
    n_press = int(((decisions["driver_id"] == driver) & (decisions["label"] == "change")).sum())
    style_txt = f", style **{styles.iloc[0]['style']}**" if len(styles) and "style" in styles else ""
    st.markdown(f"**{driver}**: {n_press} lane-change decisions{style_txt}")

    cols = st.columns(len(INDICATORS))
    for col, ind in zip(cols, INDICATORS):
        with col:
            fig = figures.compact(indicator_vs_speed(decisions, fits, driver, ind))
            st.plotly_chart(fig, key=f"ivs_{ind}")

    st.subheader("Correlation with ego speed")
    corr = views.for_driver(tables.get("correlations"), driver)
    if len(corr):
        st.plotly_chart(figures.bare_table(correlation_table(corr), len(corr)), key="correlations")
    else:
        st.caption("No correlations for this driver.")
    share = loaders.analysis_meta(str(ws.root), loaders.analysis_stamp(ws.root)).get("summary", {}).get(
        "share_significant")
    if share:
        st.caption("Drivers with a significant linear correlation (all drivers): " + ", ".join(
            f"{k} {v:.0%}" for k, v in share.items() if v is not None) + " (the study reports 80 %).")
    st.subheader("Fits  I = A·v_e + b")
    fit = views.for_driver(fits, driver)
    if len(fit):
        st.caption("A in s per m/s for the TTCs (t_f, t_nf) and in m/s per m/s for dv_nb; b in s or m/s; "
                   "[lo, hi] are 95 % confidence intervals.")
        st.dataframe(views.fit_summary(fit), hide_index=True, width="stretch")
    else:
        st.caption("No fits for this driver.")

    st.subheader("Decisions with undefined indicators")
    bad = views.undefined_decisions(decisions, driver)
    if len(bad):
        st.caption(f"{len(bad)} of {n_press} presses: 'absent' = no such vehicle, 'not_closing' = the gap "
                   "is not closing (TTC undefined), 'far' = follower beyond the no-influence distance.")
        st.dataframe(bad, hide_index=True, width="stretch")
    else:
        st.caption("All indicators defined at every press.")
    skipped = views.for_driver(tables.get("skipped"), driver)
    if len(skipped):
        if box := widgets.lazy_expander(f"Skipped by the analysis ({len(skipped)})", key="skipped_open"):
            box.dataframe(skipped, hide_index=True, width="stretch")


main()
