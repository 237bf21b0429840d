"""Plotly figures of a run (no streamlit here): the study's Figs. 9, 10 and 11.

All take what `rl.runs.load_run` returns (frames and dicts from the run folder).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from laneprint.plotting import ema_smooth, envelope_indices, even_indices, sample_rows
from laneprint.reference import INDICATORS

_UNITS = {"t_f": "t_f [s]", "t_nf": "t_nf [s]", "dv_nb": "dv_nb [m/s]"}
_COLS = {"t_f": "t_f_s", "t_nf": "t_nf_s", "dv_nb": "dv_nb_mps"}
_COLOURS = {"agent": "#1f77b4", "greedy": "#ff7f0e", "driver": "#2ca02c"}

#: Points drawn per curve of Fig. 9: a 100 000-episode run draws as fast as a short one.
MAX_CURVE_POINTS = 2000
#: Markers drawn per figure of Figs. 10 and 11 (a random sample of the points beyond that; counts use all).
#: Drawn as SVG, not WebGL: WebGL is several times slower where the browser has no GPU (software GL).
MAX_MARKERS = 2000


def training_curves(metrics: pd.DataFrame, smoothing: float = 0.95, max_points: int = MAX_CURVE_POINTS) -> go.Figure:
    """Fig. 9: loss and mean step reward per episode: raw values faint, TensorBoard-style smoothed line
    (exponential moving average with debiasing, weight `smoothing` in [0, 1); 0 = raw) over them.

    Each curve draws at most `max_points` points: the smoothed line is computed on every
    episode and then thinned; the raw one keeps each stretch's lowest and highest value."""
    fig = make_subplots(rows=1, cols=2, subplot_titles=("training loss", "mean step reward"))
    if metrics is None or metrics.empty:
        fig.update_layout(title="no metrics yet")
        return fig
    m = metrics.sort_values("episode")
    episodes = m["episode"].to_numpy()
    for col, key in ((1, "loss"), (2, "mean_step_reward")):
        y = (pd.to_numeric(m[key], errors="coerce") if key in m else pd.Series(np.nan, index=m.index)).to_numpy()
        raw = envelope_indices(y, max_points)
        smooth = ema_smooth(y, smoothing)
        thin = even_indices(len(y), max_points)
        fig.add_trace(go.Scatter(x=episodes[raw], y=y[raw], mode="lines", line={"color": "#9ecae1", "width": 1},
                                 opacity=0.45, name=f"{key} (per episode)", showlegend=False), row=1, col=col)
        fig.add_trace(go.Scatter(x=episodes[thin], y=smooth[thin], mode="lines",
                                 line={"color": "#08519c", "width": 2}, name=f"{key} (smoothed {smoothing:g})",
                                 showlegend=False), row=1, col=col)
        fig.update_xaxes(title_text="episode", row=1, col=col)
    fig.update_yaxes(title_text="loss [reward²]", row=1, col=1)
    fig.update_yaxes(title_text="reward per step [1]", row=1, col=2)
    fig.update_layout(title=f"Training (Fig. 9): per episode (faint), smoothed {smoothing:g} (dark)", height=380)
    return fig


def _drawn_note(drawn: int, total: int, what: str) -> str:
    return f" ({drawn} of {total} {what} drawn, at random)" if drawn < total else ""


def indicators_at_decisions(changes: pd.DataFrame, lines: dict, who: tuple[str, ...] = ("agent", "greedy", "driver"),
                            v_range: tuple[float, float] | None = None, max_markers: int = MAX_MARKERS) -> go.Figure:
    """Fig. 10: indicators at the changes of the agent, the greedy benchmark and the driver vs the reference lines.

    `changes` is a run's ``eval_changes`` table; `lines` the run config's ``lines`` dict
    (indicator -> [A, b]). Beyond `max_markers` changes a seeded random sample of them is
    drawn (said in the title); the speed range and the legend's counts use them all.
    """
    fig = make_subplots(rows=1, cols=3, subplot_titles=tuple(_UNITS[k] for k in INDICATORS))
    if changes is None or changes.empty:
        fig.update_layout(title="no evaluation yet")
        return fig
    v = changes["v_e_mps"].dropna()
    lo, hi = v_range or ((float(v.min()), float(v.max())) if len(v) else (15.0, 27.0))
    grid = np.linspace(lo, hi, 20)
    shown = changes[changes["who"].isin(who)]
    drawn = sample_rows(shown, max(1, max_markers // len(INDICATORS)))
    for col, k in enumerate(INDICATORS, start=1):
        for name in who:
            part = drawn[drawn["who"] == name]
            n_all = int((shown["who"] == name).sum())
            fig.add_trace(go.Scatter(x=part["v_e_mps"], y=part[_COLS[k]], mode="markers", name=f"{name} ({n_all})",
                                     marker={"color": _COLOURS.get(name), "size": 6, "opacity": 0.7},
                                     legendgroup=name, showlegend=col == 1), row=1, col=col)
        a, b = lines[k]
        fig.add_trace(go.Scatter(x=grid, y=a * grid + b, mode="lines", name="reference line",
                                 line={"color": "red"}, legendgroup="ref", showlegend=col == 1), row=1, col=col)
        fig.update_xaxes(title_text="ego speed v_e [m/s]", row=1, col=col)
        fig.update_yaxes(title_text=_UNITS[k], row=1, col=col)
    fig.update_layout(title="Indicators at the lane changes vs the reference lines (Fig. 10)"
                      + _drawn_note(len(drawn), len(shown), "changes"), height=400)
    return fig


def decision_agreement(states: pd.DataFrame, who: str = "agent", x: str = "v_e_mps", y: str = "t_f_s",
                       max_markers: int = MAX_MARKERS) -> go.Figure:
    """Fig. 11: same / opposite decisions of `who` and the drivers on their recorded states.

    `states` is a run's ``eval_states`` table (label + ``action_<who>``, 0 change / 1 keep).
    Beyond `max_markers` states a seeded random sample of them is drawn (said in the title);
    the counts and the share of same decisions use them all.
    """
    fig = go.Figure()
    if states is None or states.empty or f"action_{who}" not in states:
        fig.update_layout(title="no evaluation yet")
        return fig
    states = states.reset_index(drop=True)
    driver_change = states["label"] == "change"
    same = (states[f"action_{who}"] == 0) == driver_change
    drawn = sample_rows(states, max_markers)
    for ok, name, symbol, colour in ((True, "same decision", "circle", "#1f77b4"),
                                     (False, "opposite decision", "triangle-up", "#d62728")):
        part = drawn[same.loc[drawn.index] == ok]
        fig.add_trace(go.Scatter(x=part[x], y=part[y], mode="markers", name=f"{name} ({int((same == ok).sum())})",
                                 marker={"symbol": symbol, "color": colour, "size": 6, "opacity": 0.6},
                                 text=part["label"], hovertemplate="%{text}<br>%{x:.1f}, %{y:.2f}"))
    labels = {"v_e_mps": "ego speed v_e [m/s]", "t_f_s": "t_f [s]", "t_nf_s": "t_nf [s]", "dv_nb_mps": "dv_nb [m/s]"}
    fig.update_layout(title=f"Decisions of the {who} vs the drivers (Fig. 11): {same.mean():.1%} the same"
                      + _drawn_note(len(drawn), len(states), "states"),
                      xaxis_title=labels.get(x, x), yaxis_title=labels.get(y, y), height=420)
    return fig
