"""Plotly figures of the per-driver statistics (no Streamlit here; the dashboard shows them)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from indicators.stats import INDICATOR_COLUMNS, LineFit, indicator_points
from laneprint.plotting import axis_range, clip_to_axis

LABELS = {"t_f": "t_f: TTC to the ego-lane leader [s]", "t_nf": "t_nf: TTC to the target-lane leader [s]",
          "dv_nb": "dv_nb: v_ego - v_nb, target-lane follower [m/s]"}
SPEED_LABEL = "ego speed v_e [m/s]"


def indicator_vs_speed(decisions: pd.DataFrame, fits: pd.DataFrame, driver_id: str, indicator: str,
                       alpha: float = 0.05) -> go.Figure:
    """One driver's presses: the indicator against ego speed, the OLS line, its (1 - alpha)
    confidence band and prediction band. Points left out of the fit are grey, with their reason.

    The y axis is scaled to the used points; excluded points beyond it are drawn at its
    edge as triangles (pointing where they are) with their true value in the hover.

    Traces (by name): 'used', 'excluded' and 'excluded, off the axis (n)' (if any), and
    when the fit is 'ok': 'prediction band', 'confidence band', 'OLS line'.
    """
    if indicator not in INDICATOR_COLUMNS:
        raise ValueError(f"unknown indicator {indicator!r}")
    pts = indicator_points(decisions[decisions["driver_id"].astype(str) == str(driver_id)])
    pts = pts[pts["indicator"] == indicator]
    fig = go.Figure()
    used = pts[pts["used"]]
    fig.add_trace(go.Scatter(x=used["v"], y=used["y"], mode="markers", name="used",
                             marker={"color": "#1f77b4", "size": 7},
                             text=used["decision_id"], hovertemplate="%{text}<br>v=%{x:.2f} m/s<br>%{y:.2f}"))
    excl = pts[~pts["used"] & np.isfinite(pts["y"])]
    # the axis follows the points the fit used: a few excluded TTCs of minutes would flatten them
    yrange = axis_range(used["y"]) if len(used) else None
    if len(excl):
        drawn = clip_to_axis(excl["y"], *yrange) if yrange else clip_to_axis(excl["y"], -np.inf, np.inf)
        inside = (drawn["side"] == "").to_numpy()
        part = excl[inside]
        if len(part):
            fig.add_trace(go.Scatter(x=part["v"], y=part["y"], mode="markers", name="excluded",
                                     marker={"color": "#bbbbbb", "size": 7, "symbol": "x"},
                                     text=part["decision_id"] + ": " + part["status"],
                                     hovertemplate="%{text}<br>v=%{x:.2f} m/s<br>%{y:.2f}"))
        off, where = excl[~inside], drawn[~inside]
        if len(off):
            fig.add_trace(go.Scatter(
                x=off["v"], y=where["y"], mode="markers", name=f"excluded, off the axis ({len(off)})",
                marker={"color": "#999999", "size": 9, "symbol": np.where(where["side"] == "above", "triangle-up",
                                                                           "triangle-down").tolist()},
                cliponaxis=False, customdata=where["value"], text=off["decision_id"] + ": " + off["status"],
                hovertemplate="%{text}<br>v=%{x:.2f} m/s<br>%{customdata:.2f} (off the axis)<extra></extra>"))
    row = fits[(fits["driver_id"].astype(str) == str(driver_id)) & (fits["indicator"] == indicator)]
    title = f"driver {driver_id}: {indicator} against ego speed"
    if len(row) and row.iloc[0]["status"] == "ok":
        r = row.iloc[0]
        fit = LineFit.from_row(r, alpha=alpha)
        grid = np.linspace(float(r["v_min"]), float(r["v_max"]), 60)
        b = fit.bands(grid)
        pct = int(round(100 * (1 - alpha)))
        for lo, hi, name, color in (("pi_lo", "pi_hi", "prediction band", "rgba(31,119,180,0.10)"),
                                    ("ci_lo", "ci_hi", "confidence band", "rgba(31,119,180,0.30)")):
            fig.add_trace(go.Scatter(x=np.r_[grid, grid[::-1]], y=np.r_[b[hi], b[lo][::-1]], fill="toself",
                                     fillcolor=color, line={"width": 0}, name=name, hoverinfo="skip",
                                     legendgroup=name))
        fig.add_trace(go.Scatter(x=grid, y=b["mean"], mode="lines", name="OLS line", line={"color": "#d62728"}))
        title += f" — {indicator} = {r['A']:.3f} v_e + {r['b']:.2f} (R² {r['r2']:.2f}, n {int(r['n'])}, {pct} % bands)"
    elif len(row):
        title += f" — no fit: {row.iloc[0]['reason']}"
    fig.update_layout(title=title, xaxis_title=SPEED_LABEL, yaxis_title=LABELS[indicator], template="plotly_white")
    if yrange:
        fig.update_yaxes(range=list(yrange))
    return fig


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
    fig = go.Figure(go.Table(header={"values": list(cols), "fill_color": "#dddddd", "align": "left"},
                             cells={"values": [list(v) for v in cols.values()], "fill_color": [fill] * len(cols),
                                    "align": "left"}))
    fig.update_layout(title="Correlation of each indicator with ego speed, per driver (Pearson p < alpha = significant)")
    return fig
