"""Plotly figures of a run (no streamlit here): the study's Figs. 9, 10 and 11.

All take what `rl.runs.load_run` returns (frames and dicts from the run folder).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from laneprint.plotting import (
    clip_to_axis,
    ema_smooth,
    envelope_indices,
    even_indices,
    plateau_judgement,
    sample_rows,
    symbol_codes,
    tail_range,
)
from laneprint.reference import INDICATORS

_UNITS = {"t_f": "t_f [s]", "t_nf": "t_nf [s]", "dv_nb": "dv_nb [m/s]"}
_COLS = {"t_f": "t_f_s", "t_nf": "t_nf_s", "dv_nb": "dv_nb_mps"}
_COLOURS = {"agent": "#1f77b4", "greedy": "#ff7f0e", "driver": "#2ca02c"}

#: Points drawn per curve of Fig. 9: a 100 000-episode run draws as fast as a short one.
MAX_CURVE_POINTS = 2000
#: Markers drawn per figure of Figs. 10 and 11 (a random sample of the points beyond that; counts use all).
#: Drawn as SVG, not WebGL: WebGL is several times slower where the browser has no GPU (software GL).
MAX_MARKERS = 2000

#: Axis titles of the training curves, the same on every page that draws them.
EPISODE_LABEL = "episode [-]"
LOSS_LABEL = "loss [reward²]"
REWARD_LABEL = "reward per step [1]"


def training_curves(
    metrics: pd.DataFrame,
    smoothing: float = 0.95,
    max_points: int = MAX_CURVE_POINTS,
    learning_starts: int | None = None,
) -> go.Figure:
    """Fig. 9: loss and mean step reward per episode: raw values faint, TensorBoard-style smoothed line
    (exponential moving average with debiasing, weight `smoothing` in [0, 1); 0 = raw) over them.

    Each curve draws at most `max_points` points: the smoothed line is computed on every
    episode and then thinned; the raw one keeps each stretch's lowest and highest value.
    The smoothed line joins the episodes that had no update (no loss). When no episode
    has a loss, the loss panel says why (`learning_starts`: transitions stored before the
    first update; the metrics' `env_steps`: transitions taken so far)."""
    fig = make_subplots(rows=1, cols=2, subplot_titles=("training loss", "mean step reward"))
    if metrics is None or metrics.empty:
        fig.update_layout(title="no metrics yet")
        return fig
    m = metrics.sort_values("episode")
    episodes = m["episode"].to_numpy()
    reward = pd.to_numeric(m["mean_step_reward"], errors="coerce") if "mean_step_reward" in m else []
    state, judged = plateau_judgement(reward)
    fig.add_annotation(
        text=f"<b>{state}</b>",
        xref="x2 domain",
        yref="y2 domain",
        x=0.98,
        y=0.04,
        showarrow=False,
        font={"size": 12, "color": "#b45309" if state in ("rising", "falling") else "#555"},
        xanchor="right",
        hovertext=judged,
    )
    for col, key in ((1, "loss"), (2, "mean_step_reward")):
        y = (pd.to_numeric(m[key], errors="coerce") if key in m else pd.Series(np.nan, index=m.index)).to_numpy()
        y = y.astype(float)
        raw = envelope_indices(y, max_points)
        smooth = ema_smooth(y, smoothing)
        ok = np.flatnonzero(np.isfinite(smooth))
        thin = ok[even_indices(len(ok), max_points)]
        fig.add_trace(
            go.Scatter(
                x=episodes[raw],
                y=y[raw],
                mode="lines",
                line={"color": "#9ecae1", "width": 1},
                opacity=0.45,
                name=f"{key} (per episode)",
                showlegend=False,
            ),
            row=1,
            col=col,
        )
        fig.add_trace(
            go.Scatter(
                x=episodes[thin],
                y=smooth[thin],
                mode="lines",
                line={"color": "#08519c", "width": 2},
                name=f"{key} (smoothed {smoothing:g})",
                showlegend=False,
            ),
            row=1,
            col=col,
        )
        fig.update_xaxes(title_text=EPISODE_LABEL, row=1, col=col)
        if key == "loss" and not np.isfinite(y).any():
            fig.add_annotation(
                text=no_loss_note(m, learning_starts),
                xref="x domain",
                yref="y domain",
                x=0.5,
                y=0.5,
                showarrow=False,
                font={"size": 12, "color": "#b45309"},
                align="center",
            )
    fig.update_yaxes(title_text=LOSS_LABEL, row=1, col=1)
    fig.update_yaxes(title_text=REWARD_LABEL, row=1, col=2)
    fig.update_layout(
        title=f"Training (Fig. 9): per episode (faint), smoothed {smoothing:g} (dark)<br><sup>reward {judged}</sup>",
        height=400,
        margin={"t": 90},
    )
    fig.layout.meta = {"plateau": judged}
    return fig


def no_loss_note(metrics: pd.DataFrame, learning_starts: int | None = None) -> str:
    """Why a run has no loss: 'No update yet: learning starts after 2000 transitions,<br>this run
    has taken 1616 (300 episodes).'"""
    steps = pd.to_numeric(metrics.get("env_steps"), errors="coerce") if "env_steps" in metrics else None
    taken = int(steps.max()) if steps is not None and steps.notna().any() else None
    episodes = int(pd.to_numeric(metrics["episode"], errors="coerce").max()) if len(metrics) else 0
    start = (
        f"after {learning_starts:,} transitions"
        if learning_starts
        else "once the replay memory holds enough transitions"
    )
    took = (
        f"this run has taken {taken:,} ({episodes:,} episodes)"
        if taken is not None
        else f"none in {episodes:,} episodes"
    )
    return f"No update yet: learning starts {start};<br>{took}. The agent has learnt nothing."


def _drawn_note(drawn: int, total: int, what: str) -> str:
    return f" ({drawn} of {total} {what} drawn, at random)" if drawn < total else ""


def indicators_at_decisions(
    changes: pd.DataFrame,
    lines: dict,
    who: tuple[str, ...] = ("agent", "greedy", "driver"),
    v_range: tuple[float, float] | None = None,
    max_markers: int = MAX_MARKERS,
) -> go.Figure:
    """Fig. 10: indicators at the changes of the agent, the greedy benchmark and the driver vs the reference lines.

    `changes` is a run's ``eval_changes`` table; `lines` the run config's ``lines`` dict
    (indicator -> [A, b]). Beyond `max_markers` changes a seeded random sample of them is
    drawn (said in the title); the speed range and the legend's counts use them all. Each
    panel's y axis is set by the bulk of its values (`laneprint.plotting.tail_range`): a
    value beyond it is drawn at its edge as an open triangle and counted in the panel's
    title. A policy none of whose changes has a defined indicator says so in the legend.
    """
    fig = make_subplots(rows=1, cols=3, subplot_titles=tuple(_UNITS[k] for k in INDICATORS), horizontal_spacing=0.08)
    if changes is None or changes.empty:
        fig.update_layout(title="no evaluation yet")
        return fig
    shown = changes[changes["who"].isin(who)]
    speeds = pd.to_numeric(shown["v_e_mps"], errors="coerce")
    x_beyond = 0
    drawn = sample_rows(shown, max(1, max_markers // len(INDICATORS)))
    defined = {
        name: bool(
            np.isfinite(
                shown.loc[shown["who"] == name, [_COLS[k] for k in INDICATORS if _COLS[k] in shown]].to_numpy(
                    dtype=float
                )
            ).any()
        )
        for name in who
    }
    titles = []
    for col, k in enumerate(INDICATORS, start=1):
        values = pd.to_numeric(shown.get(_COLS[k]), errors="coerce") if _COLS[k] in shown else pd.Series(dtype=float)
        yrange = tail_range(values)
        n_beyond = int(((values < yrange[0]) | (values > yrange[1])).sum()) if yrange else 0
        # the speed axis too follows the bulk of the changes drawn in the panel: a lone change far slower than
        # the rest is drawn at its edge
        v = speeds[np.isfinite(values.to_numpy(dtype=float))].dropna() if len(values) else speeds.iloc[:0]
        xrange = None if v_range else tail_range(v)
        lo, hi = v_range or (
            (float(v[v >= xrange[0]].min()), float(v[v <= xrange[1]].max())) if xrange else (15.0, 27.0)
        )
        grid = np.linspace(lo, hi, 20)
        x_beyond += int(((v < xrange[0]) | (v > xrange[1])).sum()) if xrange else 0
        for name in who:
            part = drawn[(drawn["who"] == name)]
            part = (
                part[np.isfinite(pd.to_numeric(part.get(_COLS[k]), errors="coerce").to_numpy(dtype=float))]
                if _COLS[k] in part
                else part.iloc[:0]
            )
            where = clip_to_axis(part[_COLS[k]] if _COLS[k] in part else [], *(yrange or (-np.inf, np.inf)))
            n_all = int((shown["who"] == name).sum())
            label = f"{name} ({n_all})" + ("" if defined[name] or not n_all else ", none with a defined indicator")
            wx = clip_to_axis(part["v_e_mps"], *(xrange or (-np.inf, np.inf)))
            symbols = symbol_codes(
                np.where(
                    where["side"] == "above",
                    "triangle-up-open",
                    np.where(
                        where["side"] == "below",
                        "triangle-down-open",
                        np.where(
                            wx["side"] == "above",
                            "triangle-right-open",
                            np.where(wx["side"] == "below", "triangle-left-open", "circle"),
                        ),
                    ),
                )
            )
            fig.add_trace(
                go.Scatter(
                    x=wx["y"],
                    y=where["y"],
                    mode="markers",
                    name=label,
                    marker={"color": _COLOURS.get(name), "size": 6, "opacity": 0.7, "symbol": symbols},
                    customdata=where["value"],
                    cliponaxis=False,
                    text=[f"{x:.2f}" for x in wx["value"]],
                    # the true speeds of the changes drawn at the axis's edge (`meta`'s x)
                    meta={"x": wx["value"].tolist()} if (wx["side"] != "").any() else None,
                    hovertemplate=f"{name}<br>v_e %{{text}} m/s<br>{_UNITS[k]}: %{{customdata:.2f}}<extra></extra>",
                    legendgroup=name,
                    showlegend=col == 1,
                ),
                row=1,
                col=col,
            )
        a, b = lines[k]
        fig.add_trace(
            go.Scatter(
                x=grid,
                y=a * grid + b,
                mode="lines",
                name="reference line",
                line={"color": "red"},
                legendgroup="ref",
                showlegend=col == 1,
            ),
            row=1,
            col=col,
        )
        fig.update_xaxes(title_text="ego speed v_e [m/s]", row=1, col=col)
        if xrange:
            fig.update_xaxes(range=list(xrange), row=1, col=col)
        fig.update_yaxes(title_text=_UNITS[k], row=1, col=col)
        if yrange:
            fig.update_yaxes(range=list(yrange), row=1, col=col)
        titles.append(_UNITS[k] + (f" — {n_beyond} off the axis (open ▲▼)" if n_beyond else ""))
    for ann, text in zip(fig.layout.annotations, titles):
        ann.text = text
    fig.update_layout(
        title="Indicators at the lane changes vs the reference lines (Fig. 10)"
        + _drawn_note(len(drawn), len(shown), "changes")
        + (f"<br><sub>{x_beyond} points at speeds off the axis (open ◀▶)</sub>" if x_beyond else ""),
        height=420,
    )
    return fig


def agreement_figures(states: pd.DataFrame, who: str = "agent") -> dict[str, float | int]:
    """How `who` decides against the drivers on their recorded states: at the presses (recall: share
    changed), before them (specificity: share kept), their balanced accuracy, and the share of all
    states decided the same (dominated by the many not-yet states)."""
    change = states["label"] == "change"
    acted = states[f"action_{who}"] == 0
    n_press, n_keep = int(change.sum()), int((~change).sum())
    recall = float((acted & change).sum() / n_press) if n_press else float("nan")
    spec = float((~acted & ~change).sum() / n_keep) if n_keep else float("nan")
    parts = [x for x in (recall, spec) if x == x]
    return {
        "n_press": n_press,
        "n_keep": n_keep,
        "recall": recall,
        "specificity": spec,
        "balanced_accuracy": float(np.mean(parts)) if parts else float("nan"),
        "same": float((acted == change).mean()) if len(states) else float("nan"),
    }


def decision_agreement(
    states: pd.DataFrame, who: str = "agent", x: str = "v_e_mps", y: str = "t_f_s", max_markers: int = MAX_MARKERS
) -> go.Figure:
    """Fig. 11: same / opposite decisions of `who` and the drivers on their recorded states.

    `states` is a run's ``eval_states`` table (label + ``action_<who>``, 0 change / 1 keep).
    Beyond `max_markers` states a seeded random sample of them is drawn (said in the title);
    the counts and the figures in the title use them all. The title leads with the balanced
    accuracy (presses changed, not-yet states kept), not the share of same decisions, which
    the many not-yet states dominate. The y axis is set by the bulk of the values: a state
    beyond it is drawn open at its edge and counted in the title.
    """
    fig = go.Figure()
    if states is None or states.empty or f"action_{who}" not in states:
        fig.update_layout(title="no evaluation yet")
        return fig
    states = states.reset_index(drop=True)
    driver_change = states["label"] == "change"
    same = (states[f"action_{who}"] == 0) == driver_change
    drawn = sample_rows(states, max_markers)
    values = pd.to_numeric(states[y], errors="coerce") if y in states else pd.Series(np.nan, index=states.index)
    yrange = tail_range(values)
    n_beyond = int(((values < yrange[0]) | (values > yrange[1])).sum()) if yrange else 0
    for ok, name, symbol, colour in (
        (True, "same decision", "circle", "#1f77b4"),
        (False, "opposite decision", "triangle-up", "#d62728"),
    ):
        part = drawn[same.loc[drawn.index] == ok]
        where = clip_to_axis(
            pd.to_numeric(part[y], errors="coerce") if y in part else np.full(len(part), np.nan),
            *(yrange or (-np.inf, np.inf)),
        )
        fig.add_trace(
            go.Scatter(
                x=part[x],
                y=where["y"],
                mode="markers",
                name=f"{name} ({int((same == ok).sum())})",
                marker={
                    "symbol": symbol_codes(np.where(where["side"] != "", symbol + "-open", symbol)),
                    "color": colour,
                    "size": 6,
                    "opacity": 0.6,
                },
                text=part["label"],
                customdata=where["value"],
                cliponaxis=False,
                hovertemplate="%{text}<br>%{x:.1f}, %{customdata:.2f}<extra></extra>",
            )
        )
    f = agreement_figures(states, who)
    labels = {"v_e_mps": "ego speed v_e [m/s]", "t_f_s": "t_f [s]", "t_nf_s": "t_nf [s]", "dv_nb_mps": "dv_nb [m/s]"}

    def pct(v: float) -> str:
        return "–" if v != v else f"{v:.1%}"

    title = (
        f"Decisions of the {who} vs the drivers (Fig. 11) — balanced accuracy {pct(f['balanced_accuracy'])}"
        f" — changed at {pct(f['recall'])} of {f['n_press']} presses, kept at {pct(f['specificity'])} of "
        f"{f['n_keep']} not-yet states ({same.mean():.1%} the same over all {len(states)} states)"
        + (f" — {n_beyond} off the axis, drawn open at its edge" if n_beyond else "")
        + _drawn_note(len(drawn), len(states), "states")
    )
    fig.update_layout(title=title, xaxis_title=labels.get(x, x), yaxis_title=labels.get(y, y), height=420)
    if yrange:
        fig.update_yaxes(range=list(yrange))
    return fig


def drive_fidelity(fid: dict) -> go.Figure:
    """A drive beside its drivers (`rl.drive.fidelity`): lane changes per km with 95 % intervals, then, per
    indicator at the presses, each side's median with its interquartile range as the bar; last, where
    each side drove (time in each lane, lane changes per km by lane pair) when the report has it."""
    from indicators.plots import label_of

    names = list(fid["indicators"])
    lanes = fid.get("lanes")  # drives before the by-lane comparison have none
    panels = (
        ["lane changes per km [1/km]"]
        + [label_of(k, short=True) for k in names]
        + (["time in each lane [share]", "lane changes per km by lane pair"] if lanes else [])
    )
    cols = 3
    rows = -(-len(panels) // cols)
    fig = make_subplots(rows=rows, cols=cols, subplot_titles=panels, horizontal_spacing=0.08, vertical_spacing=0.12)
    colours = {"agent": _COLOURS["agent"], "drivers": _COLOURS["driver"]}
    rate = fid["rate"]
    for who in ("agent", "drivers"):
        r = rate[who]
        lo, hi = r["per_km_ci"]
        fig.add_trace(
            go.Scatter(
                x=[who],
                y=[r["per_km"]],
                mode="markers",
                marker=dict(color=colours[who], size=10),
                name=who,
                legendgroup=who,
                error_y=dict(
                    type="data",
                    symmetric=False,
                    array=[(hi or r["per_km"]) - r["per_km"]],
                    arrayminus=[r["per_km"] - (lo or r["per_km"])],
                ),
            ),
            row=1,
            col=1,
        )
    d = rate["drivers"]["per_km"]
    if d:
        tol = fid.get("tolerance", 0.2)
        fig.add_hrect(
            y0=d * (1 - tol), y1=d * (1 + tol), fillcolor=colours["drivers"], opacity=0.12, line_width=0, row=1, col=1
        )
    for k, name in enumerate(names, start=1):
        row, col = k // cols + 1, k % cols + 1
        v = fid["indicators"][name]
        for who, side in (("agent", v["agent"]), ("drivers", v["drivers"])):
            if side["median"] is None:
                continue
            fig.add_trace(
                go.Scatter(
                    x=[who],
                    y=[side["median"]],
                    mode="markers",
                    marker=dict(color=colours[who], size=10),
                    name=who,
                    legendgroup=who,
                    showlegend=False,
                    hovertemplate=f"{who}: median %{{y:.2f}}, n={side['n']}",
                    error_y=dict(
                        type="data",
                        symmetric=False,
                        array=[side["q3"] - side["median"]],
                        arrayminus=[side["median"] - side["q1"]],
                    ),
                ),
                row=row,
                col=col,
            )
        if v["median_in_iqr"] is False:
            fig.layout.annotations[k].text = f"{panels[k]} (outside the drivers' IQR)"
    if lanes:
        for k, key in ((len(names) + 1, "time_share"), (len(names) + 2, "pairs_per_km")):
            row, col = k // cols + 1, k % cols + 1
            cats = sorted(set(lanes["agent"][key]) | set(lanes["drivers"][key]), key=lambda c: (len(c), c))
            for who in ("agent", "drivers"):
                fig.add_trace(
                    go.Bar(
                        x=cats,
                        y=[lanes[who][key].get(c, 0.0) for c in cats],
                        name=who,
                        legendgroup=who,
                        showlegend=False,
                        marker_color=colours[who],
                        offsetgroup=who,
                    ),
                    row=row,
                    col=col,
                )
    a = rate["agent"]["per_km"]
    fig.update_layout(
        height=260 * rows,
        margin=dict(t=70, l=50, r=20, b=30),
        title=f"The drive beside its drivers: {fid['medians_in_iqr']} medians inside their IQR, "
        f"lane changes {'-' if a is None else format(a, '.2f')} against "
        f"{'-' if d is None else format(d, '.2f')} per km (bars: 95 % interval; IQR)",
    )
    return fig
