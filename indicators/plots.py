"""Plotly figures of the per-driver statistics (no Streamlit here; the dashboard shows them)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from indicators.directions import directions
from indicators.stats import INDICATOR_COLUMNS, LineFit, indicator_points
from laneprint.plotting import clip_to_axis, line_formula, log_ticks, needs_log_axis, tail_range

#: The paper's three indicators (Li & Liu), always first.
PAPER_INDICATORS: tuple[str, ...] = ("t_f", "t_nf", "dv_nb")

LABELS = {
    "t_f": "t_f: TTC to the ego-lane leader [s]",
    "t_nf": "t_nf: TTC to the target-lane leader [s]",
    "dv_nb": "dv_nb: v_ego - v_nb, target-lane follower [m/s]",
    "gap_f": "gap_f: gap to the ego-lane leader [m]",
    "thw_f": "thw_f: time headway to the ego-lane leader, gap / v_e [s]",
    "dv_f": "dv_f: v_ego - v_f, ego-lane leader [m/s]",
    "gap_nf": "gap_nf: lead gap in the target lane [m]",
    "dv_nf": "dv_nf: v_ego - v_nf, target-lane leader [m/s]",
    "gap_nb": "gap_nb: lag gap in the target lane [m]",
    "thw_nb": "thw_nb: time headway of the target-lane follower, lag gap / v_nb [s]",
}
#: Short axis titles (name and unit) where a panel is narrow.
SHORT_LABELS = {k: f"{k} [{v.rsplit('[', 1)[1]}" for k, v in LABELS.items()}
SPEED_LABEL = "ego speed v_e [m/s]"

#: Gaps and headways: below 0 the two vehicles overlap lengthwise (bumper to bumper).
GAP_INDICATORS: tuple[str, ...] = ("gap_f", "gap_nf", "gap_nb", "thw_f", "thw_nb")
#: What a gap below 0 means, written on the figures that have one.
OVERLAP_NOTE = "below 0: the vehicles overlap lengthwise (side by side as the ego moves over)"

#: What the Drivers page groups the indicators by; an indicator this analysis lacks is left out.
INDICATOR_GROUPS: dict[str, tuple[str, ...]] = {
    "The paper's three: times to collision and the follower's closing speed": PAPER_INDICATORS,
    "What the driver accepts: gaps and time headways": ("gap_f", "thw_f", "gap_nf", "gap_nb", "thw_nb"),
    "What the driver accepts: relative speeds": ("dv_f", "dv_nf"),
}


def indicator_columns() -> dict[str, tuple[str, str, str]]:
    """indicator -> (value column, status column, unit) as the analysis stage defines them."""
    return dict(INDICATOR_COLUMNS)


def unit_of(indicator: str) -> str:
    """The indicator's unit ('s', 'm', 'm/s'), '' when unknown."""
    cols = indicator_columns().get(indicator)
    if cols:
        return cols[2]
    label = LABELS.get(indicator, "")
    return label.rsplit("[", 1)[1].rstrip("]") if "[" in label else ""


def label_of(indicator: str, short: bool = False) -> str:
    """Axis title with the unit: 't_f: TTC to the ego-lane leader [s]' (short: 't_f [s]')."""
    if indicator in LABELS:
        return SHORT_LABELS[indicator] if short else LABELS[indicator]
    unit = unit_of(indicator)
    return f"{indicator} [{unit}]" if unit else indicator


def indicator_groups(available) -> dict[str, tuple[str, ...]]:
    """`INDICATOR_GROUPS` restricted to the `available` indicators (empty groups dropped); indicators in
    no group go to a last group 'Other indicators'."""
    available = list(dict.fromkeys(available))
    out = {name: tuple(i for i in inds if i in available) for name, inds in INDICATOR_GROUPS.items()}
    out = {k: v for k, v in out.items() if v}
    grouped = {i for v in out.values() for i in v}
    rest = tuple(i for i in available if i not in grouped)
    if rest:
        out["Other indicators"] = rest
    return out


def fit_flag(row: pd.Series | dict | None) -> str:
    """The analysis' flag of a fit ('' when the line means something, or when the analysis predates flags)."""
    if row is None:
        return ""
    flag = row.get("flag") if hasattr(row, "get") else None
    return "" if flag is None or (isinstance(flag, float) and np.isnan(flag)) else str(flag)


def _off_axis_trace(
    part: pd.DataFrame, where: pd.DataFrame, name: str, color: str | list[str], unit: str, what: pd.Series | None = None
) -> go.Scatter:
    text = part["decision_id"] + ": " + part["status"] + ("" if what is None else ", " + what)
    return go.Scatter(
        x=part["v"],
        y=where["y"],
        mode="markers",
        name=f"{name}, off the axis ({len(part)})",
        marker={
            "color": color,
            "size": 9,
            "symbol": np.where(where["side"] == "above", "triangle-up", "triangle-down").tolist(),
        },
        cliponaxis=False,
        customdata=where["value"],
        text=text,
        hovertemplate="%{text}<br>v=%{x:.2f} m/s<br>%{customdata:.2f} " + unit + " (off the axis)<extra></extra>",
    )


def indicator_vs_speed(
    decisions: pd.DataFrame,
    fits: pd.DataFrame,
    driver_id: str,
    indicator: str,
    alpha: float = 0.05,
    fits_by_direction: pd.DataFrame | None = None,
) -> go.Figure:
    """One driver's presses: the indicator against ego speed, the OLS line, its (1 - alpha)
    confidence band and prediction band. Points left out of the fit are grey, with their reason.

    The y axis is set by the bulk of the points drawn (`laneprint.plotting.tail_range`: a
    TTC of minutes among seconds does not flatten the rest); any point beyond it, used
    or excluded, is drawn at its edge as a triangle (pointing where it is), counted in
    its trace's name, with its true value in the hover. The title names the fit's flag
    when the analysis flagged it (a low R², a slope interval spanning 0).

    Presses are marked by the side of their target lane when the decisions table has the
    lanes (`DIRECTION_STYLE`: blue circles to the left, overtaking; orange diamonds to the
    right, returning). With `fits_by_direction` (the analysis' per-direction fits), each side
    the driver has a fit for gets its own dashed line beside the pooled one.

    Traces (by name): 'used' (or, with lanes, 'used, to the left (n)' and 'used, to the right
    (n)'), 'used, off the axis (n)', 'excluded' and 'excluded, off the axis (n)' (each only
    when it has points), and when the fit is 'ok': 'prediction band', 'confidence band', 'OLS
    line'; 'line to the left' / 'line to the right' for each side's fit.
    """
    columns = indicator_columns()
    if indicator not in columns:
        raise ValueError(f"unknown indicator {indicator!r}")
    unit = columns[indicator][2]
    d = decisions[decisions["driver_id"].astype(str) == str(driver_id)]
    pts = (
        indicator_points(d)
        if len(d)
        else pd.DataFrame(columns=["indicator", "used", "y", "v", "status", "decision_id"])
    )
    pts = pts[pts["indicator"] == indicator]
    fig = go.Figure()
    used = pts[pts["used"].astype(bool)]
    excl = pts[~pts["used"].astype(bool) & np.isfinite(pts["y"].astype(float))]
    # the axis follows the bulk of the points drawn (the fit's and those it left out alike), covering 95 % of
    # them; when that would flatten the bulk (a TTC of minutes among a dozen of seconds), a log axis holds all
    every = pd.concat([used["y"], excl["y"]]).astype(float)
    log_axis = needs_log_axis(every)
    yrange = None if log_axis else tail_range(every)
    lo, hi = yrange if yrange else (-np.inf, np.inf)
    drawn = clip_to_axis(used["y"], lo, hi)
    inside = (drawn["side"] == "").to_numpy()
    sides = press_directions(d)
    if sides is None:
        fig.add_trace(
            go.Scatter(
                x=used["v"][inside],
                y=used["y"][inside],
                mode="markers",
                name="used",
                marker={"color": "#1f77b4", "size": 7},
                text=used["decision_id"][inside],
                hovertemplate="%{text}<br>v=%{x:.2f} m/s<br>%{y:.2f} " + unit,
            )
        )
    else:
        side = used["decision_id"].map(sides).fillna("").to_numpy()
        for name, (color, symbol, what) in DIRECTION_STYLE.items():
            part = used[inside & (side == name)]
            if len(part):
                fig.add_trace(
                    go.Scatter(
                        x=part["v"],
                        y=part["y"],
                        mode="markers",
                        name=f"used, to the {name} ({len(part)})",
                        marker={"color": color, "size": 7, "symbol": symbol},
                        text=part["decision_id"] + f": {what}",
                        hovertemplate="%{text}<br>v=%{x:.2f} m/s<br>%{y:.2f} " + unit + "<extra></extra>",
                    )
                )
    if (~inside).any():
        off = used[~inside]
        if sides is None:
            fig.add_trace(_off_axis_trace(off, drawn[~inside], "used", "#1f77b4", unit))
        else:  # coloured by direction, as the points on the axis
            side = off["decision_id"].map(sides).fillna("")
            fig.add_trace(
                _off_axis_trace(
                    off,
                    drawn[~inside],
                    "used",
                    [DIRECTION_STYLE.get(s, ("#1f77b4",))[0] for s in side],
                    unit,
                    side.map(lambda s: DIRECTION_STYLE[s][2] if s in DIRECTION_STYLE else ""),
                )
            )
    if len(excl):
        drawn = clip_to_axis(excl["y"], lo, hi)
        inside = (drawn["side"] == "").to_numpy()
        part = excl[inside]
        if len(part):
            fig.add_trace(
                go.Scatter(
                    x=part["v"],
                    y=part["y"],
                    mode="markers",
                    name="excluded",
                    marker={"color": "#bbbbbb", "size": 7, "symbol": "x"},
                    text=part["decision_id"] + ": " + part["status"],
                    hovertemplate="%{text}<br>v=%{x:.2f} m/s<br>%{y:.2f} " + unit,
                )
            )
        if (~inside).any():
            fig.add_trace(_off_axis_trace(excl[~inside], drawn[~inside], "excluded", "#999999", unit))
    row = (
        fits[(fits["driver_id"].astype(str) == str(driver_id)) & (fits["indicator"] == indicator)]
        if fits is not None and len(fits)
        else pd.DataFrame()
    )
    title = f"driver {driver_id}: {indicator} against ego speed"
    notes = []
    if len(row) and row.iloc[0]["status"] == "ok":
        r = row.iloc[0]
        fit = LineFit.from_row(r, alpha=alpha)
        grid = np.linspace(float(r["v_min"]), float(r["v_max"]), 60)
        b = fit.bands(grid)
        pct = int(round(100 * (1 - alpha)))
        for lo_, hi_, name, color in (
            ("pi_lo", "pi_hi", "prediction band", "rgba(31,119,180,0.10)"),
            ("ci_lo", "ci_hi", "confidence band", "rgba(31,119,180,0.30)"),
        ):
            fig.add_trace(
                go.Scatter(
                    x=np.r_[grid, grid[::-1]],
                    y=np.r_[b[hi_], b[lo_][::-1]],
                    fill="toself",
                    fillcolor=color,
                    line={"width": 0},
                    name=name,
                    hoverinfo="skip",
                    legendgroup=name,
                )
            )
        flag = fit_flag(r)
        fig.add_trace(
            go.Scatter(
                x=grid,
                y=b["mean"],
                mode="lines",
                name="OLS line",
                line={"color": "#d62728", "dash": "dot" if flag else "solid"},
            )
        )
        notes.append(
            f"{line_formula(indicator, float(r['A']), float(r['b']))} [{unit}], v_e in m/s "
            f"(R² {r['r2']:.2f}, n {int(r['n'])}, {pct} % bands)"
        )
        if flag:
            notes.append(f"flagged: {flag}")
    elif len(row):
        notes.append(f"no fit: {row.iloc[0]['reason']}")
    if log_axis:
        notes.append("log axis: a few values far above the rest (a leader that hardly closes)")
    for trace in direction_lines(fits_by_direction, driver_id, indicator, unit):
        fig.add_trace(trace)
    # the details go on lines of their own below the title, so that it is never wider than the plot
    subtitle = "<br>".join(f"<sup>{n}</sup>" for n in notes)
    fig.update_layout(
        title={"text": title + ("<br>" + subtitle if subtitle else "")},
        xaxis_title=SPEED_LABEL,
        yaxis_title=label_of(indicator),
        template="plotly_white",
        margin={"t": 60 + 18 * len(notes)},
    )
    mark_overlap(fig, indicator, pd.concat([used["y"], excl["y"]]).astype(float).to_numpy(), yrange)
    if yrange:
        fig.update_yaxes(range=list(yrange))
    if log_axis:
        v = every[np.isfinite(every)]
        fig.update_yaxes(
            type="log", range=[float(np.log10(v.min() / 1.15)), float(np.log10(v.max() * 1.15))], **log_ticks(v)
        )
    return fig


def mark_overlap(fig: go.Figure, indicator: str, values: np.ndarray, yrange: tuple[float, float] | None) -> None:
    """Shade the part of a gap or headway axis below 0 and say what it means (the two vehicles overlap
    lengthwise), when any of `values` is there."""
    values = values[np.isfinite(values)]
    if indicator not in GAP_INDICATORS or not (values < 0).any():
        return
    floor = min(float(values.min()), yrange[0] if yrange else 0.0)
    fig.add_hrect(
        y0=floor,
        y1=0,
        fillcolor="rgba(214,39,40,0.06)",
        line_width=0,
        annotation_text=OVERLAP_NOTE,
        annotation_position="bottom left",
        annotation_font={"size": 11, "color": "#a02020"},
    )


#: direction -> (colour, marker symbol, what it means) of the presses to each side.
DIRECTION_STYLE: dict[str, tuple[str, str, str]] = {
    "left": ("#1f77b4", "circle", "to the left (overtaking)"),
    "right": ("#ff7f0e", "diamond", "to the right (returning)"),
}


def press_directions(decisions: pd.DataFrame) -> pd.Series | None:
    """decision_id -> 'left' / 'right' (the side of the target lane; lanes count from the right) of the
    presses in `decisions`; None when the table has no lanes (an analysis made before directions)."""
    if not {"target_lane", "ego_lane", "decision_id"} <= set(decisions.columns):
        return None
    d = decisions[decisions["label"] == "change"] if "label" in decisions else decisions
    return pd.Series(directions(d), index=d["decision_id"].astype(str).to_numpy())


def direction_lines(
    fits_by_direction: pd.DataFrame | None, driver_id: str, indicator: str, unit: str = ""
) -> list[go.Scatter]:
    """The driver's per-direction OLS lines of `indicator` (status 'ok' only), dashed, over each side's
    speed range: traces 'line to the left' / 'line to the right'; a flagged line is drawn dash-dotted and
    says so in its name. Empty without per-direction fits."""
    f = fits_by_direction
    if f is None or f.empty or "direction" not in f:
        return []
    rows = f[(f["driver_id"].astype(str) == str(driver_id)) & (f["indicator"] == indicator) & (f["status"] == "ok")]
    out = []
    for name, (color, _, what) in DIRECTION_STYLE.items():
        r = rows[rows["direction"] == name]
        if not len(r):
            continue
        r = r.iloc[0]
        flag = fit_flag(r)
        grid = np.linspace(float(r["v_min"]), float(r["v_max"]), 30)
        formula = line_formula(indicator, float(r["A"]), float(r["b"]))
        out.append(
            go.Scatter(
                x=grid,
                y=float(r["A"]) * grid + float(r["b"]),
                mode="lines",
                name=f"line to the {name}" + (" (flagged)" if flag else ""),
                line={"color": color, "width": 2, "dash": "dashdot" if flag else "dash"},
                hovertemplate=f"presses {what}: {formula} [{unit}]<br>R² {float(r['r2']):.2f}, n {int(r['n'])}"
                + (f"<br>flagged: {flag}" if flag else "")
                + "<extra></extra>",
            )
        )
    return out


def correlation_table(correlations: pd.DataFrame) -> go.Figure:
    """The correlations table as a Plotly table (significant rows highlighted)."""
    c = correlations.copy()

    def fmt(x: float, spec: str) -> str:
        return "-" if pd.isna(x) else format(x, spec)

    cols = {
        "driver": c["driver_id"].astype(str),
        "indicator": c["indicator"],
        "n": c["n"].astype(int).astype(str),
        "Pearson r": [fmt(x, ".3f") for x in c["pearson_r"]],
        "p": [fmt(x, ".2g") for x in c["pearson_p"]],
        "Spearman rho": [fmt(x, ".3f") for x in c["spearman_rho"]],
        "p (Spearman)": [fmt(x, ".2g") for x in c["spearman_p"]],
        "significant": ["yes" if s else "no" for s in c["significant"]],
        "reason": c["reason"].fillna(""),
    }
    fill = ["#e6f2e6" if s else "#ffffff" for s in c["significant"]]
    fig = go.Figure(
        go.Table(
            header={"values": list(cols), "fill_color": "#dddddd", "align": "left"},
            cells={"values": [list(v) for v in cols.values()], "fill_color": [fill] * len(cols), "align": "left"},
        )
    )
    fig.update_layout(
        title="Correlation of each indicator with ego speed, per driver (Pearson p < alpha = significant)"
    )
    return fig


def following_vs_speed(following: pd.DataFrame, driver: str) -> go.Figure:
    """One driver's steady-following episodes (`indicators.following`): time headway against ego
    speed on a log axis, marker area by the episode's length, and its `thw_follow` level (the low
    quantile the styles read) as a line."""
    from indicators.following import FOLLOW_QUANTILE, following_levels

    mine = following[following["driver_id"].astype(str) == str(driver)]
    fig = go.Figure()
    size = np.clip(np.sqrt(mine["duration_s"].to_numpy(dtype=float)) * 3, 5, 18)
    fig.add_trace(
        go.Scatter(
            x=mine["ego_v_mps"].tolist(),
            y=mine["thw_s"].tolist(),
            mode="markers",
            name="episodes",
            marker={"size": size.tolist(), "color": "#1f77b4", "opacity": 0.7},
            customdata=np.c_[mine["f_gap_m"], mine["duration_s"]].tolist(),
            hovertemplate="%{y:.2f} s at %{x:.1f} m/s, gap %{customdata[0]:.0f} m, %{customdata[1]:.0f} s<extra></extra>",
        )
    )
    level = following_levels(mine)
    title = f"{driver}: no steady following in its drives"
    if len(level):
        thw, n = float(level["thw_follow_s"].iloc[0]), int(level["episodes"].iloc[0])
        fig.add_hline(
            y=thw,
            line={"color": "black", "width": 2},
            annotation_text=f"thw_follow {thw:.2f} s",
            annotation_position="top left",
        )
        title = (
            f"{driver}: time headway kept in steady following, {n} episode{'s' if n != 1 else ''}; "
            f"line: the {FOLLOW_QUANTILE:.0%} quantile"
        )
    fig.update_layout(
        title=title,
        template="plotly_white",
        showlegend=False,
        xaxis={"title": SPEED_LABEL},
        yaxis={"title": "time headway gap / v_e [s] (log)", "type": "log", **log_ticks(mine["thw_s"])},
    )
    return fig
