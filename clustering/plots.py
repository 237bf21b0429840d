"""Plotly figures of the styles (no Streamlit here; the dashboard shows them)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from indicators.plots import PAPER_INDICATORS, SPEED_LABEL, label_of
from laneprint.plotting import clip_to_axis, line_formula, log_ticks, spread_labels, tail_range

STYLE_COLORS = {"Defensive": "#2ca02c", "Normal": "#1f77b4", "Aggressive": "#d62728", "unassigned": "#999999"}
_EXTRA_COLORS = ["#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22"]


#: Annotation offsets [px] of a label written on each side of its point.
_LABEL_OFFSETS: dict[str, dict[str, Any]] = {
    "top": {"yshift": 12},
    "bottom": {"yshift": -12},
    "right": {"xshift": 8, "xanchor": "left"},
    "left": {"xshift": -8, "xanchor": "right"},
}

#: Arrow tail offsets [px] of a typical driver's label on each side of its star.
_ARROW = {"top": (0, -40), "bottom": (0, 40), "right": (50, 0), "left": (-50, 0)}


def style_color(style: str, i: int = 0) -> str:
    return STYLE_COLORS.get(style, _EXTRA_COLORS[i % len(_EXTRA_COLORS)])


_FEATURE_UNITS = {"s": "s", "m": "m", "mps": "m/s", "share": "x limit", "permin": "/min"}
#: Prefixes of the behaviour parameters' columns, and what each reads.
_BEHAVIOUR_PREFIXES = {"crit_": "critical value", "kept_": "kept while following", "drive_": "over the drive"}


#: Features that are a level over the whole drive, not a line read at a speed.
_DRIVE_LEVELS = {"thw_follow": "headway kept in steady following"}


def _feature_label(col: str) -> str:
    # 't_f_at_80kph_s' -> 't_f at 80 km/h [s]', 'gap_f_at_80kph_m' -> 'gap_f at 80 km/h [m]'
    if col.startswith(tuple(_BEHAVIOUR_PREFIXES)):  # 'crit_thw_nb_s' -> 'thw_nb critical value [s]'
        ind, unit = col.split("_", 1)[1].rsplit("_", 1)
        what = _BEHAVIOUR_PREFIXES[col.split("_", 1)[0] + "_"]
        return f"{ind} {what} [{_FEATURE_UNITS.get(unit, unit)}]"
    ind, rest = col.rsplit("_at_", 1)
    kph, unit = rest.split("kph_")
    if ind in _DRIVE_LEVELS:
        return f"{ind}: {_DRIVE_LEVELS[ind]} [{_FEATURE_UNITS.get(unit, unit)}]"
    return f"{ind} at {kph} km/h [{_FEATURE_UNITS.get(unit, unit)}]"


def feature_columns(styles: pd.DataFrame) -> list[str]:
    """The clustering feature columns of a styles table (`<indicator>_at_<kph>kph_<unit>`), else its
    behaviour parameters (`crit_<indicator>_<unit>`, `kept_thw_follow_s`) with a value for some driver."""
    lines = [c for c in styles.columns if "_at_" in c and "kph_" in c]
    return lines or [c for c in styles.columns if c.startswith(tuple(_BEHAVIOUR_PREFIXES)) and styles[c].notna().any()]


def feature_indicator(col: str) -> str:
    """'gap_f_at_80kph_m' -> 'gap_f'; 'crit_thw_nb_s' -> 'thw_nb'."""
    if col.startswith(tuple(_BEHAVIOUR_PREFIXES)):
        return col.split("_", 1)[1].rsplit("_", 1)[0]
    return col.rsplit("_at_", 1)[0]


def cluster_scatter(
    styles: pd.DataFrame,
    x: str | None = None,
    y: str | None = None,
    max_labels: int = 12,
    indicators: list[str] | tuple[str, ...] | None = None,
) -> go.Figure:
    """Drivers in feature space (default: the first two of `indicators`, the clustering's
    chosen ones, else t_f and t_nf, each driver's line at 80 km/h), one trace per style,
    typical drivers as stars (trace 'typical drivers'); marker opacity follows the
    assignment confidence. Each axis is set by the bulk of the drivers
    (`laneprint.plotting.tail_range`); a driver beyond it is drawn at its edge as an open
    diamond, its true values in the hover, and counted in the title. Every driver's id is in its hover; at
    most `max_labels` ids are written on the plot (annotations), typical drivers first,
    only where a label overlaps no other label or point."""
    feats = feature_columns(styles)
    if not feats:
        raise ValueError("styles table has no feature columns")

    def pick(prefix: str) -> str | None:
        cands = [c for c in feats if feature_indicator(c) == prefix]
        return next((c for c in cands if "_at_80kph" in c), cands[len(cands) // 2] if cands else None)

    chosen = [i for i in (indicators or []) if pick(i)]
    if len(chosen) >= 2:
        x, y = x or pick(chosen[0]), y or pick(chosen[1])
    x = x or pick("t_f") or feats[0]
    y = (
        y
        or pick("t_nf")
        or next(
            (c for c in feats if feature_indicator(c) != feature_indicator(x)), feats[1] if len(feats) > 1 else feats[0]
        )
    )
    # heavy tails (a driver whose t_f line reads minutes): the axes follow the bulk, the rest at the edge
    ranges = {c: tail_range(styles[c]) for c in (x, y)}
    where = {c: clip_to_axis(styles[c], *(ranges[c] or (-np.inf, np.inf))) for c in (x, y)}
    styles = styles.assign(
        _x=where[x]["y"].to_numpy(),
        _y=where[y]["y"].to_numpy(),
        _off=((where[x]["side"] != "") | (where[y]["side"] != "")).to_numpy(),
    )
    n_off = int(styles["_off"].sum())
    fig = go.Figure()
    order = styles.sort_values("cluster")["style"].unique()
    for i, style in enumerate(order):
        g = styles[styles["style"] == style]
        conf = g["confidence"].fillna(0).clip(0, 1).to_numpy()
        fig.add_trace(
            go.Scatter(
                x=g["_x"],
                y=g["_y"],
                mode="markers",
                name=style,
                text=g["driver_id"],
                cliponaxis=False,
                marker={
                    "color": style_color(style, i),
                    "size": 11,
                    "opacity": list(0.35 + 0.65 * conf),
                    "symbol": np.where(g["_off"], "diamond-open", "circle").tolist(),
                },
                customdata=np.c_[conf, g["n_decisions"], g[x], g[y]],
                hovertemplate="%{text}<br>confidence %{customdata[0]:.2f}<br>presses %{customdata[1]}<br>"
                f"{_feature_label(x)}: %{{customdata[2]:.2f}}<br>{_feature_label(y)}: "
                "%{customdata[3]:.2f}<extra>" + style + "</extra>",
            )
        )
    typ = styles[styles["is_typical"].astype(bool)]
    fig.add_trace(
        go.Scatter(
            x=typ["_x"],
            y=typ["_y"],
            mode="markers",
            name="typical drivers",
            text=typ["driver_id"],
            cliponaxis=False,
            marker={"symbol": "star", "size": 20, "color": "rgba(0,0,0,0)", "line": {"width": 2, "color": "black"}},
            hovertemplate="typical: %{text}<extra></extra>",
        )
    )
    # every driver is named in the hover; on the plot only labels that overlap nothing, typical drivers first
    sides = spread_labels(
        styles["_x"],
        styles["_y"],
        styles["driver_id"].astype(str),
        priority=styles["is_typical"].astype(bool).astype(float),
        max_labels=max_labels,
    )
    labels = []
    for r, side in zip(styles[["_x", "_y", "driver_id", "is_typical"]].to_dict("records"), sides):
        if not side:
            continue
        # a typical driver's label stands off its star on an arrow: the star is large, its cluster dense
        place = (
            {"showarrow": True, "arrowwidth": 1, "arrowcolor": "#444", "ax": _ARROW[side][0], "ay": _ARROW[side][1]}
            if bool(r["is_typical"])
            else {"showarrow": False, **_LABEL_OFFSETS[side]}
        )
        labels.append(
            {
                "x": r["_x"],
                "y": r["_y"],
                "text": str(r["driver_id"]),
                "font": {"size": 11},
                "bgcolor": "rgba(255,255,255,0.8)",
                "borderpad": 1,
                **place,
            }
        )
    fig.update_layout(annotations=labels)  # at once: one validation, not one per label
    for axis, c in (("xaxis", x), ("yaxis", y)):
        axis_range = ranges[c]
        if axis_range:
            fig.update_layout({axis: {"range": list(axis_range)}})
    # on a line of its own: one line of both was wider than the plot of a narrow page (measured in Chromium)
    off_note = (
        f"<br><sub>{n_off} driver{'s' if n_off != 1 else ''} beyond the axes, drawn at the edge (open diamond)</sub>"
        if n_off
        else ""
    )
    fig.update_layout(
        title="Drivers in feature space (each driver's robust line evaluated at one speed)" + off_note,
        xaxis_title=_feature_label(x),
        yaxis_title=_feature_label(y),
        template="plotly_white",
    )
    return fig


#: direction of a reference line -> how the figures name its presses.
DIRECTION_NAMES = {
    "both": "every press",
    "left": "presses to the left (overtaking)",
    "right": "presses to the right (returning)",
}


def line_directions(reference_lines: pd.DataFrame | None) -> list[str]:
    """The directions the styles' lines exist for: ['both'] (an analysis made before directions, or
    no side with a typical line), else 'both' and the sides that have one."""
    if reference_lines is None or "direction" not in reference_lines:
        return ["both"]
    r = reference_lines[(reference_lines["scope"] == "style") & (reference_lines["kind"] == "typical")]
    have = set(r["direction"].astype(str))
    return ["both", *[d for d in ("left", "right") if d in have]]


def reference_lines(
    reference_lines: pd.DataFrame,
    kinds: tuple[str, ...] = ("typical", "paper"),
    v_range_mps: tuple[float, float] = (60 / 3.6, 95 / 3.6),
    indicators: list[str] | tuple[str, ...] | None = None,
    columns: int = 3,
    direction: str = "both",
) -> go.Figure:
    """The styles' reference lines overlaid, one panel per indicator (the paper's three first,
    then any other the table has, or `indicators`), `columns` panels a row: 'typical'
    solid, 'pooled' dashed, 'paper' (Table 1) dotted. Trace names are '<style> <kind>';
    the hover names how the line was fitted (the table's `fit`: 'ols', 'huber' or
    'level', when present). Axis titles are short ('t_nf [s]') so that they stay inside
    their panel.

    `direction` ('both', 'left', 'right'; the table's `direction` column): 'both' draws the
    lines fitted on every press; a side draws each style's typical line on that side's
    presses (solid, '<style> typical, to the <side>'), the typical line on every press
    dashed beside it, and Table 1 dotted."""
    refs = reference_lines[(reference_lines["scope"] == "style") & reference_lines["kind"].isin(kinds)]
    if "direction" in refs:
        if direction != "both":
            side = refs[(refs["direction"] == direction) & (refs["kind"] == "typical")]
            pooled = refs[(refs["direction"] == "both") & (refs["kind"] == "typical")]
            refs = pd.concat(
                [
                    side.assign(kind=f"typical, to the {direction}"),
                    pooled.assign(kind="typical, every press"),
                    refs[(refs["direction"] == "both") & (refs["kind"] == "paper")],
                ]
            )
            kinds = (f"typical, to the {direction}", "typical, every press", "paper")
        else:
            refs = refs[refs["direction"] == "both"]
    present = list(dict.fromkeys(refs["indicator"]))
    inds = [i for i in (indicators or [*PAPER_INDICATORS, *present]) if i in present] or list(PAPER_INDICATORS)
    inds = list(dict.fromkeys(inds))
    ncol = min(columns, len(inds))
    nrow = -(-len(inds) // ncol)
    fig = make_subplots(
        rows=nrow,
        cols=ncol,
        subplot_titles=inds,
        horizontal_spacing=0.09,
        vertical_spacing=min(0.25, 0.6 / nrow) if nrow > 1 else 0.2,
    )
    grid = np.linspace(*v_range_mps, 30)
    dash = {
        "typical": "solid",
        "pooled": "dash",
        "paper": "dot",
        f"typical, to the {direction}": "solid",
        "typical, every press": "dash",
    }
    names = list(dict.fromkeys(refs["name"]))
    traces, rows, cols = [], [], []  # added at once: Plotly's add_trace per panel costs ~10 ms a call
    for k, ind in enumerate(inds):
        row, col = k // ncol + 1, k % ncol + 1
        for i, name in enumerate(names):
            for kind in kinds:
                r = refs[(refs["name"] == name) & (refs["indicator"] == ind) & (refs["kind"] == kind)]
                if not len(r):
                    continue
                r = r.iloc[0]
                how = f" ({r['fit']} fit)" if "fit" in r and isinstance(r["fit"], str) and r["fit"] else ""
                traces.append(
                    go.Scatter(
                        x=grid,
                        y=r["A"] * grid + r["b"],
                        mode="lines",
                        name=f"{name} {kind}",
                        legendgroup=f"{name} {kind}",
                        showlegend=k == 0,
                        line={"color": style_color(name, i), "dash": dash.get(kind, "solid")},
                        hovertemplate=f"{name} {kind}{how}: "
                        f"{line_formula(ind, float(r['A']), float(r['b']))}"
                        f"<br>{r['source']}<extra></extra>",
                    )
                )
                rows.append(row)
                cols.append(col)
        fig.update_xaxes(title_text=SPEED_LABEL, row=row, col=col)
        fig.update_yaxes(title_text=label_of(ind, short=True), row=row, col=col)
    if traces:
        fig.add_traces(traces, rows=rows, cols=cols)
    title = (
        "Reference lines per style (solid: typical driver, dotted: Table 1)"
        if direction == "both"
        else f"Reference lines per style on the {DIRECTION_NAMES.get(direction, direction)} (solid: typical "
        "driver on that side, dashed: on every press, dotted: Table 1)"
    )
    fig.update_layout(title=title, template="plotly_white", height=max(420, 330 * nrow))
    return fig


def following_headways(following: pd.DataFrame, styles: pd.DataFrame) -> go.Figure:
    """Every steady-following episode's time headway per driver (log axis), drivers grouped and
    coloured by style, each driver's `thw_follow` level (the low quantile the styles read) as a
    black bar; the hover gives the episode's speed, gap and length."""
    from indicators.following import FOLLOW_QUANTILE, following_levels

    style_of = styles.set_index("driver_id")["style"].astype(str).to_dict()
    order = styles.sort_values(["cluster", "driver_id"])["driver_id"].astype(str).tolist()
    f = following.assign(driver_id=following["driver_id"].astype(str))
    f = f[f["driver_id"].isin(order)]
    fig = go.Figure()
    for i, style in enumerate(dict.fromkeys(style_of[d] for d in order)):
        g = f[f["driver_id"].map(style_of) == style]
        fig.add_trace(
            go.Box(
                x=g["driver_id"],
                y=g["thw_s"],
                name=style,
                boxpoints="all",
                jitter=0.4,
                pointpos=0,
                marker={"color": style_color(style, i), "size": 5},
                line={"width": 1},
                fillcolor="rgba(0,0,0,0)",
                customdata=np.c_[g["ego_v_mps"] * 3.6, g["f_gap_m"], g["duration_s"]],
                hovertemplate="%{x}: %{y:.2f} s at %{customdata[0]:.0f} km/h, gap %{customdata[1]:.0f} m,"
                " %{customdata[2]:.0f} s<extra>" + style + "</extra>",
            )
        )
    levels = following_levels(f)
    fig.add_trace(
        go.Scatter(
            x=levels["driver_id"].tolist(),
            y=levels["thw_follow_s"].tolist(),
            mode="markers",
            name="level (thw_follow)",
            marker={"symbol": "line-ew-open", "size": 28, "color": "black", "line": {"width": 3, "color": "black"}},
            customdata=levels["episodes"],
            hovertemplate="%{x}: level %{y:.2f} s from %{customdata} episodes<extra></extra>",
        )
    )
    none = [d for d in order if d not in set(levels["driver_id"])]
    note = f" — no episode: {', '.join(none)}" if none else ""
    fig.update_layout(
        title=f"Time headway kept in steady following, per episode; bar: the {FOLLOW_QUANTILE:.0%} quantile{note}",
        template="plotly_white",
        boxmode="overlay",
        xaxis={"title": "driver", "categoryorder": "array", "categoryarray": order},
        yaxis={"title": "time headway [s] (log)", "type": "log", **log_ticks(f["thw_s"])},
    )
    return fig
