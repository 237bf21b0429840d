"""Plotly figures of the styles (no Streamlit here; the dashboard shows them)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from indicators.plots import LABELS, SPEED_LABEL
from laneprint.plotting import spread_labels
from laneprint.reference import INDICATORS

STYLE_COLORS = {"Defensive": "#2ca02c", "Normal": "#1f77b4", "Aggressive": "#d62728", "unassigned": "#999999"}
_EXTRA_COLORS = ["#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22"]


#: Annotation offsets [px] of a label written on each side of its point.
_LABEL_OFFSETS = {"top": {"yshift": 12}, "bottom": {"yshift": -12}, "right": {"xshift": 8, "xanchor": "left"},
                  "left": {"xshift": -8, "xanchor": "right"}}

#: Arrow tail offsets [px] of a typical driver's label on each side of its star.
_ARROW = {"top": (0, -40), "bottom": (0, 40), "right": (50, 0), "left": (-50, 0)}


def style_color(style: str, i: int = 0) -> str:
    return STYLE_COLORS.get(style, _EXTRA_COLORS[i % len(_EXTRA_COLORS)])


def _feature_label(col: str) -> str:
    # 't_f_at_80kph_s' -> 't_f at 80 km/h [s]'
    ind, rest = col.split("_at_")
    kph, unit = rest.split("kph_")
    return f"{ind} at {kph} km/h [{'s' if unit == 's' else 'm/s'}]"


def cluster_scatter(styles: pd.DataFrame, x: str | None = None, y: str | None = None,
                    max_labels: int = 12) -> go.Figure:
    """Drivers in feature space (default: t_f and t_nf of each driver's line at 80 km/h),
    one trace per style, typical drivers as stars (trace 'typical drivers'); marker
    opacity follows the assignment confidence. Every driver's id is in its hover; at
    most `max_labels` ids are written on the plot (annotations), typical drivers first,
    only where a label overlaps no other label or point."""
    feats = [c for c in styles.columns if "_at_" in c and "kph_" in c]
    if not feats:
        raise ValueError("styles table has no feature columns")

    def pick(prefix: str) -> str | None:
        cands = [c for c in feats if c.startswith(prefix + "_at_")]
        return next((c for c in cands if "_at_80kph" in c), cands[len(cands) // 2] if cands else None)

    x = x or pick("t_f") or feats[0]
    y = y or pick("t_nf") or (feats[1] if len(feats) > 1 else feats[0])
    fig = go.Figure()
    order = styles.sort_values("cluster")["style"].unique()
    for i, style in enumerate(order):
        g = styles[styles["style"] == style]
        conf = g["confidence"].fillna(0).clip(0, 1).to_numpy()
        fig.add_trace(go.Scatter(
            x=g[x], y=g[y], mode="markers", name=style, text=g["driver_id"],
            marker={"color": style_color(style, i), "size": 11, "opacity": list(0.35 + 0.65 * conf)},
            customdata=np.c_[conf, g["n_decisions"]],
            hovertemplate="%{text}<br>confidence %{customdata[0]:.2f}<br>presses %{customdata[1]}<extra>" + style + "</extra>"))
    typ = styles[styles["is_typical"].astype(bool)]
    fig.add_trace(go.Scatter(x=typ[x], y=typ[y], mode="markers", name="typical drivers", text=typ["driver_id"],
                             marker={"symbol": "star", "size": 20, "color": "rgba(0,0,0,0)",
                                     "line": {"width": 2, "color": "black"}},
                             hovertemplate="typical: %{text}<extra></extra>"))
    # every driver is named in the hover; on the plot only labels that overlap nothing, typical drivers first
    sides = spread_labels(styles[x], styles[y], styles["driver_id"].astype(str),
                          priority=styles["is_typical"].astype(bool).astype(float), max_labels=max_labels)
    for (_, r), side in zip(styles.iterrows(), sides):
        if not side:
            continue
        # a typical driver's label stands off its star on an arrow: the star is large, its cluster dense
        place = ({"showarrow": True, "arrowwidth": 1, "arrowcolor": "#444", "ax": _ARROW[side][0],
                  "ay": _ARROW[side][1]} if bool(r["is_typical"]) else {"showarrow": False, **_LABEL_OFFSETS[side]})
        fig.add_annotation(x=r[x], y=r[y], text=str(r["driver_id"]), font={"size": 11},
                           bgcolor="rgba(255,255,255,0.8)", borderpad=1, **place)
    fig.update_layout(title="Drivers in feature space (each driver's robust line evaluated at one speed)",
                      xaxis_title=_feature_label(x), yaxis_title=_feature_label(y), template="plotly_white")
    return fig


def reference_lines(reference_lines: pd.DataFrame, kinds: tuple[str, ...] = ("typical", "paper"),
                    v_range_mps: tuple[float, float] = (60 / 3.6, 95 / 3.6)) -> go.Figure:
    """The styles' reference lines overlaid, one panel per indicator: 'typical' solid,
    'pooled' dashed, 'paper' (Table 1) dotted. Trace names are '<style> <kind>'."""
    refs = reference_lines[(reference_lines["scope"] == "style") & reference_lines["kind"].isin(kinds)]
    fig = make_subplots(rows=1, cols=len(INDICATORS), subplot_titles=[LABELS[i].split(":")[0] for i in INDICATORS])
    grid = np.linspace(*v_range_mps, 30)
    dash = {"typical": "solid", "pooled": "dash", "paper": "dot"}
    names = list(dict.fromkeys(refs["name"]))
    for col, ind in enumerate(INDICATORS, start=1):
        for i, name in enumerate(names):
            for kind in kinds:
                r = refs[(refs["name"] == name) & (refs["indicator"] == ind) & (refs["kind"] == kind)]
                if not len(r):
                    continue
                r = r.iloc[0]
                fig.add_trace(go.Scatter(x=grid, y=r["A"] * grid + r["b"], mode="lines", name=f"{name} {kind}",
                                         legendgroup=f"{name} {kind}", showlegend=col == 1,
                                         line={"color": style_color(name, i), "dash": dash.get(kind, "solid")},
                                         hovertemplate=f"{name} {kind}: {r['A']:.3f} v + {r['b']:.2f}<br>{r['source']}"
                                                       "<extra></extra>"), row=1, col=col)
        fig.update_xaxes(title_text=SPEED_LABEL, row=1, col=col)
        fig.update_yaxes(title_text=LABELS[ind], row=1, col=col)
    fig.update_layout(title="Reference lines per style (solid: typical driver, dotted: Table 1)",
                      template="plotly_white")
    return fig
