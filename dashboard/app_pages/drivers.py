"""Drivers: one driver's indicators against speed with the OLS fits and their flags, grouped (the
paper's three; what the driver accepts), presses marked by direction with each side's line where the
analysis fitted one, correlations, fit summaries (pooled and per direction), undefined indicators."""

import streamlit as st

from dashboard import docs_site, figures, loaders, views, widgets
from dashboard.context import workspace
from indicators.plots import correlation_table, following_vs_speed, indicator_vs_speed


def main() -> None:
    st.title("Drivers")
    widgets.page_help("indicators")
    ws = workspace()
    key = loaders.analysis_stamp(ws.root)
    tables = loaders.analysis(str(ws.root), key)
    if "decisions" not in tables:
        st.info(
            "No analysis yet: ingest logs on the Data page, then run the analysis on the Styles page "
            f"(or `{views.cli_hint('analyze', ws.root)}`)."
        )
        return
    if loaders.analysis_is_stale(ws.root):
        st.info("Recordings were added or removed since this analysis ran: run it again on the Styles page.")
    meta = loaders.analysis_meta(str(ws.root), key)
    decisions, fits, side_fits = tables["decisions"], tables.get("fits"), tables.get("fits_by_direction")
    drivers = views.drivers_of(tables)
    driver = st.selectbox("Driver", drivers, key="driver")
    styles = views.for_driver(tables.get("styles"), driver)
    mine = views.for_driver(decisions, driver)  # the figures read this driver's rows only (fewer to scan)
    side_fit = views.for_driver(side_fits, driver) if side_fits is not None else None
    n_press = int((mine["label"] == "change").sum())
    style_txt = f", style **{views.md_escape(styles.iloc[0]['style'])}**" if len(styles) and "style" in styles else ""
    sides = views.driver_presses_by_direction(mine, driver)
    sides_txt = f" ({sides['left']} to the left, {sides['right']} to the right)" if sides else ""
    st.markdown(f"**{views.md_escape(driver)}**: {views.plural(n_press, 'lane-change decision')}{sides_txt}{style_txt}")

    fit = views.for_driver(fits, driver)
    flagged = views.flagged_fits(fit)
    if len(flagged):
        st.warning(
            f"{views.plural(len(flagged), 'line')} of this driver mean little and are drawn dotted: "
            + "; ".join(f"**{r.indicator}**: {r.flag}" for r in flagged.itertuples())
        )

    groups = views.indicator_groups_of(decisions, fits)
    chosen = views.chosen_indicators(meta)
    labels = list(groups)
    default = next((i for i, g in enumerate(labels) if set(groups[g]) & set(chosen) - {"t_f", "t_nf", "dv_nb"}), 0)
    group = (
        st.radio(
            "Indicators",
            labels,
            index=default,
            key="indicator_group",
            horizontal=True,
            help=docs_site.with_more(
                "The paper's three, or what the driver accepts (the acceptance "
                "indicators are in the decisions table of analyses made since "
                "they exist)",
                "indicators",
            ),
        )
        if len(labels) > 1
        else labels[0]
    )
    inds = groups[group]
    for start in range(0, len(inds), 3):
        cols = st.columns(3)
        for col, ind in zip(cols, inds[start : start + 3]):
            with col:
                fig = figures.compact(indicator_vs_speed(mine, fit, driver, ind, fits_by_direction=side_fit))
                st.plotly_chart(fig, key=f"ivs_{ind}")
    st.caption(
        "Each y axis is set by the bulk of the driver's points: a value beyond it (a TTC of minutes behind "
        "a leader that hardly closes) is drawn as a triangle at the axis edge, counted in the legend, its "
        "value in the hover."
        + (
            " Presses to the left (overtaking) are blue circles, to the right (returning) orange diamonds; "
            "where a side has enough presses its own line is drawn dashed beside the pooled one."
            if sides
            else ""
        )
    )

    following = tables.get("following")
    if following is not None:
        st.subheader("Headway kept in steady following")
        st.caption(
            "Over the whole drive, press or not: every stretch of at least 2 s at the leader's speed "
            "(within 1 m/s) while held below its free speed; marker area by its length. The line is the "
            "level the styles read (thw_follow) where the feature set holds it."
        )
        st.plotly_chart(following_vs_speed(following, driver), key="following")

    st.subheader("Correlation with ego speed")
    corr = views.for_driver(tables.get("correlations"), driver)
    if len(corr):
        st.plotly_chart(figures.bare_table(correlation_table(corr), len(corr)), key="correlations")
    else:
        st.caption("No correlations for this driver.")
    share = meta.get("summary", {}).get("share_significant")
    if share:
        st.caption(
            "Drivers with a significant linear correlation (all drivers): "
            + ", ".join(f"{k} {v:.0%}" for k, v in share.items() if v is not None)
            + " (the study reports 80 %)."
        )
    st.subheader("Fits  I = A·v_e + b")
    if len(fit):
        st.caption(
            "v_e in m/s; A in the indicator's unit per m/s, b in its unit; [lo, hi] are 95 % confidence "
            "intervals; a non-empty flag: the line means little (R² below the threshold, a slope interval "
            "spanning 0, or few points) and the style's reference lines do not use it as it is."
        )
        st.dataframe(views.fit_summary(fit), hide_index=True, width="stretch")
    else:
        st.caption("No fits for this driver.")
    side_table = views.direction_fit_summary(side_fit)
    if len(side_table):
        st.subheader("Fits per direction")
        st.caption(
            "The same fits on the presses to each side (left: overtaking, right: returning). A side with "
            "too few presses has no line: its reason says so, and the pooled line above stands for it."
        )
        st.dataframe(side_table, hide_index=True, width="stretch", key="fits_by_direction")

    st.subheader("Decisions with undefined indicators")
    bad = views.undefined_decisions(mine, driver)
    if len(bad):
        st.caption(
            f"{len(bad)} of {n_press} presses: 'absent' = no such vehicle, 'not_closing' = the gap "
            "is not closing (TTC undefined), 'far' = follower beyond the no-influence distance."
        )
        st.dataframe(bad, hide_index=True, width="stretch")
    else:
        st.caption("All indicators defined at every press.")
    skipped = views.for_driver(tables.get("skipped"), driver)
    if len(skipped):
        if box := widgets.lazy_expander(f"Skipped by the analysis ({len(skipped)})", key="skipped_open"):
            box.dataframe(skipped, hide_index=True, width="stretch")
    widgets.next_step(ws, "drivers")


main()
