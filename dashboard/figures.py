"""Plotly figures the dashboard needs that no stage draws, and layout fixes for the stages' ones.

The analysis and training figures come from the stages (`indicators.plots`,
`clustering.plots`, `rl.plots`); here are the Data page's recording viewer, the run
comparison, the k-score curve, the held-out vs in-sample figures of a
cross-validation (`laneprint crossval`), and `compact`/`bare_table` to fit a stage
figure in a column.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from dashboard.views import CROSSVAL_POLICIES
from laneprint.plotting import ema_smooth, even_indices
from rl.plots import EPISODE_LABEL, LOSS_LABEL, MAX_CURVE_POINTS, REWARD_LABEL

#: The run comparison's curves: metric -> axis title, as the Training page names them.
CURVE_LABELS = {"loss": LOSS_LABEL, "mean_step_reward": REWARD_LABEL}

MAX_POINTS = 20_000

POLICIES = CROSSVAL_POLICIES
IN_SAMPLE_COLOUR = "#9ecae1"
HELD_OUT_COLOUR = "#08519c"
POLICY_COLOURS = {"agent": "#1f77b4", "greedy": "#ff7f0e", "imitation": "#9467bd", "driver": "#2ca02c"}


def press_times(ego: pd.DataFrame) -> pd.DataFrame:
    """Rising edges of the lane-change button: t_s, direction, ego speed and lane at the press."""
    pressed = ego["lc_button"].astype(bool).to_numpy()
    rising = np.flatnonzero(pressed & ~np.concatenate([[False], pressed[:-1]]))
    out = ego.iloc[rising][["t_s", "ego_v_mps", "ego_lane"]].copy()
    out["direction"] = ego["lc_direction"].iloc[rising].fillna("").to_numpy() if "lc_direction" in ego else ""
    return out.reset_index(drop=True)


def lane_gaps(ego: pd.DataFrame, traffic: pd.DataFrame, tolerance_s: float = 0.1) -> pd.DataFrame:
    """Bumper-to-bumper gaps to the nearest leader and follower in the ego's lane over time [m].

    Traffic samples are matched to the nearest ego sample within `tolerance_s`; NaN when
    no such vehicle is in the scene.
    """
    cols = ["t_s", "lead_gap_m", "follow_gap_m"]
    if traffic.empty or ego.empty:
        return pd.DataFrame(columns=cols)
    e = ego[["t_s", "ego_x_m", "ego_lane", "ego_length_m"]].sort_values("t_s")
    tr = traffic[["t_s", "x_m", "lane", "length_m"]].sort_values("t_s")
    m = pd.merge_asof(tr, e, on="t_s", direction="nearest", tolerance=tolerance_s).dropna(subset=["ego_x_m"])
    m = m[m["lane"] == m["ego_lane"]]
    if m.empty:
        return pd.DataFrame({"t_s": e["t_s"], "lead_gap_m": np.nan, "follow_gap_m": np.nan})
    gap = (m["x_m"] - m["ego_x_m"]).abs() - (m["length_m"] + m["ego_length_m"]) / 2
    ahead = m["x_m"] > m["ego_x_m"]
    lead = gap[ahead].groupby(m.loc[ahead, "t_s"]).min().rename("lead_gap_m")
    follow = gap[~ahead].groupby(m.loc[~ahead, "t_s"]).min().rename("follow_gap_m")
    out = pd.concat([lead, follow], axis=1).sort_index()
    out.index.name = "t_s"
    return out.reset_index()[cols]


def _thin(df: pd.DataFrame, max_points: int = MAX_POINTS) -> pd.DataFrame:
    step = max(1, int(np.ceil(len(df) / max_points)))
    return df.iloc[::step]


def recording_timeline(ego: pd.DataFrame, traffic: pd.DataFrame, title: str = "") -> go.Figure:
    """Ego speed, lane and gaps to the ego-lane leader/follower over time, presses marked."""
    fig = make_subplots(rows=3, cols=1, shared_xaxes=True, vertical_spacing=0.05, row_heights=[0.4, 0.2, 0.4])
    e = _thin(ego)
    fig.add_trace(go.Scatter(x=e["t_s"], y=e["ego_v_mps"], name="ego speed", mode="lines"), row=1, col=1)
    fig.add_trace(go.Scatter(x=e["t_s"], y=e["ego_lane"], name="ego lane", mode="lines", line_shape="hv"), row=2, col=1)
    gaps = _thin(lane_gaps(ego, traffic))
    fig.add_trace(go.Scatter(x=gaps["t_s"], y=gaps["lead_gap_m"], name="gap to leader", mode="lines"), row=3, col=1)
    fig.add_trace(go.Scatter(x=gaps["t_s"], y=gaps["follow_gap_m"], name="gap to follower", mode="lines"), row=3, col=1)
    presses = press_times(ego)
    if len(presses):
        fig.add_trace(
            go.Scatter(
                x=presses["t_s"],
                y=presses["ego_v_mps"],
                mode="markers",
                name="button press",
                marker=dict(symbol="triangle-down", size=11, color="crimson"),
                text=[f"press {i + 1} {d}".strip() for i, d in enumerate(presses["direction"])],
                hovertemplate="%{text}<br>t = %{x:.2f} s<br>v = %{y:.2f} m/s<extra></extra>",
            ),
            row=1,
            col=1,
        )
        for t in presses["t_s"]:
            for row in (1, 2, 3):
                fig.add_vline(x=float(t), line=dict(color="crimson", width=1, dash="dot"), row=row, col=1)
    fig.update_yaxes(title_text="ego speed [m/s]", row=1, col=1)
    fig.update_yaxes(title_text="lane [index, 0 = right]", dtick=1, row=2, col=1)
    fig.update_yaxes(title_text="gap in ego lane [m]", row=3, col=1)
    fig.update_xaxes(title_text="time [s]", row=3, col=1)
    fig.update_layout(
        title=title or None, height=640, margin=dict(t=40 if title else 20), legend=dict(orientation="h", y=-0.12)
    )
    return fig


def runs_curves(
    metrics: dict[str, pd.DataFrame],
    column: str,
    label: str | None = None,
    smoothing: float = 0.95,
    max_points: int = MAX_CURVE_POINTS,
) -> go.Figure:
    """One metric per episode for several runs on one plot, smoothed as TensorBoard does (run comparison);
    each smoothed curve (computed on every episode) is drawn at `max_points` points at most, as a line
    through the episodes that have a value (a run's loss is empty until learning starts and on episodes
    without an update: those are joined, not left as specks). Axis titles as on the Training page."""
    fig = go.Figure()
    for run_id, df in metrics.items():
        if column in df:
            y = ema_smooth(df[column], smoothing)
            ok = np.flatnonzero(np.isfinite(y))
            thin = ok[even_indices(len(ok), max_points)]
            fig.add_trace(
                go.Scatter(x=df["episode"].to_numpy()[thin], y=y[thin], mode="lines", name=run_id, connectgaps=True)
            )
    fig.update_layout(
        xaxis_title=EPISODE_LABEL,
        yaxis_title=label or CURVE_LABELS.get(column, column),
        height=360,
        legend=dict(orientation="h", y=-0.25),
    )
    return fig


def fit_title(fig: go.Figure, width_chars: int = 95) -> go.Figure:
    """A copy of `fig` whose title fits a page-wide figure: a title longer than `width_chars` keeps its first
    part (up to the first ' — ') as the heading and the rest, wrapped, in smaller lines under it; the top
    margin grown to hold them. A short title is left as it is."""
    import re
    import textwrap

    title = fig.layout.title.text or ""
    plain = re.sub(r"<[^>]+>", "", title)
    if len(plain) <= width_chars or "<br>" in title:
        return fig
    head, *rest = title.split(" — ")
    heads = textwrap.wrap(head, width_chars) or [""]
    lines = [ln for part in rest for ln in textwrap.wrap(part, int(width_chars * 1.3))]
    text = "<br>".join(heads) + ("<br><span style='font-size:12px'>" + "<br>".join(lines) + "</span>" if lines else "")
    out = go.Figure(fig)
    top = 40 + 22 * len(heads) + 16 * len(lines)
    out.update_layout(
        title=dict(
            text=text, x=0, xanchor="left", xref="container", y=1, yanchor="top", yref="container", pad=dict(t=14, l=8)
        ),
        margin=dict(t=max(top, (fig.layout.margin.t or 0))),
    )
    return out


def compact(fig: go.Figure, height: int = 440, width_chars: int = 58) -> go.Figure:
    """Fit a stage's figure into a narrow column: the title's first part as a short heading, the
    rest (parts split at ' — ', wrapped at `width_chars`) in smaller lines under it, the top
    margin grown to hold them (so the title clears the plot and anything drawn at its top
    edge), the legend below."""
    import textwrap

    title = fig.layout.title.text or ""
    head, *rest = title.split(" — ")
    heads = textwrap.wrap(head, width_chars) or [""]
    lines = [ln for part in rest for ln in textwrap.wrap(part, width_chars + 8)]
    text = "<br>".join(heads)
    if lines:
        text += "<br><span style='font-size:11px'>" + "<br>".join(lines) + "</span>"
    top = 32 + 17 * len(heads) + 14 * len(lines) + 14
    # a long axis title ('dv_nb: v_ego - v_nb, target-lane follower [m/s]'), rotated, is taller than a
    # narrow plot and runs into the title: keep its name and unit ('dv_nb [m/s]')
    for name in [k for k in fig.layout.to_plotly_json() if k.startswith(("xaxis", "yaxis"))]:
        axis_title = fig.layout[name].title.text or ""
        if len(axis_title) > 30 and ": " in axis_title and "[" in axis_title:
            fig.layout[name].title.text = f"{axis_title.split(': ', 1)[0]} [{axis_title.rsplit('[', 1)[1]}"
    # the legend below the x axis title, one entry a line, in a bottom margin made for it: the plot keeps
    # its height (a legend Plotly fits by itself shrinks the plot until the legend covers the axis title)
    bottom = 70 + 22 * legend_entries(fig)
    plot_px = height - 90
    fig.update_layout(
        title=dict(
            text=text,
            font=dict(size=13),
            x=0,
            xanchor="left",
            xref="container",
            y=1,
            yanchor="top",
            yref="container",
            pad=dict(t=18, l=8),
        ),
        legend=dict(orientation="v", yanchor="top", y=-60 / plot_px, x=0, font=dict(size=11), tracegroupgap=0),
        height=plot_px + top + bottom,
        margin=dict(l=10, r=10, t=top, b=bottom),
    )
    return fig


def legend_entries(fig: go.Figure) -> int:
    """How many entries the figure's legend shows (named traces, one per legend group)."""
    seen = set()
    for i, tr in enumerate(fig.data):
        if tr.showlegend is False or not tr.name:
            continue
        seen.add(tr.legendgroup or f"_{i}")
    return len(seen)


def bare_table(fig: go.Figure, n_rows: int) -> go.Figure:
    """A Plotly table without its title, as tall as its rows."""
    fig.update_layout(title=None, height=30 + 22 * (n_rows + 1), margin=dict(l=0, r=0, t=0, b=0))
    return fig


def k_scores(scores: pd.DataFrame, method: str) -> go.Figure:
    """The score of each k tried when k was chosen automatically; the chosen one marked."""
    fig = go.Figure(go.Scatter(x=scores["k"], y=scores["score"], mode="lines+markers", name=method))
    fig.update_layout(
        xaxis_title="number of styles k [-]",
        yaxis_title=f"{method} score [-]",
        height=300,
        xaxis=dict(dtick=1),
        margin=dict(t=20),
    )
    return fig


def _by_policy(summary: list[dict] | None) -> dict[str, dict]:
    return {str(r.get("who")): r for r in summary or []}


def _scaled(row: dict | None, key: str, scale: float) -> float | None:
    v = (row or {}).get(key)
    return None if v is None or not np.isfinite(float(v)) else float(v) * scale


def _error_bars(rows: list[dict | None], key: str, ci_key: str, scale: float) -> dict:
    """`error_y` of a bar trace from [lo, hi] intervals (no bar where an interval is missing)."""
    plus: list[float | None] = []
    minus: list[float | None] = []
    for row in rows:
        v, ci = _scaled(row, key, scale), (row or {}).get(ci_key)
        if v is not None and ci is not None and len(ci) == 2 and None not in ci:
            plus.append(max(0.0, float(ci[1]) * scale - v))
            minus.append(max(0.0, v - float(ci[0]) * scale))
        else:
            plus.append(None)
            minus.append(None)
    return dict(type="data", symmetric=False, array=plus, arrayminus=minus, thickness=1.5, width=6)


def heldout_vs_insample(
    held_out: list[dict] | None, in_sample: list[dict] | None = None, policies: tuple[str, ...] = POLICIES
) -> go.Figure:
    """Balanced accuracy and timing error per policy: in-sample bars next to held-out bars with 95 % intervals.

    `held_out`: a cross-validation's `summary` (one dict per policy with
    `balanced_accuracy`, `balanced_accuracy_ci`, `timing_mae_s`, `timing_mae_ci`);
    `in_sample`: a run evaluation's summary rows (no intervals), or None. A policy
    missing from one of them has no bar there.
    """
    held, ins = _by_policy(held_out), _by_policy(in_sample)
    names = [p for p in policies if p in held or p in ins]
    fig = make_subplots(
        rows=1,
        cols=2,
        horizontal_spacing=0.12,
        subplot_titles=("balanced accuracy (higher is better)", "timing error (lower is better)"),
    )
    panels = (
        (1, "balanced_accuracy", "balanced_accuracy_ci", 100.0, "%{y:.1f} %"),
        (2, "timing_mae_s", "timing_mae_ci", 1.0, "%{y:.2f} s"),
    )
    for col, key, ci_key, scale, fmt in panels:
        if in_sample is not None:
            fig.add_trace(
                go.Bar(
                    x=names,
                    y=[_scaled(ins.get(p), key, scale) for p in names],
                    name="in-sample",
                    marker_color=IN_SAMPLE_COLOUR,
                    legendgroup="in",
                    showlegend=col == 1,
                    hovertemplate=f"%{{x}} in-sample: {fmt}<extra></extra>",
                ),
                row=1,
                col=col,
            )
        rows = [held.get(p) for p in names]
        fig.add_trace(
            go.Bar(
                x=names,
                y=[_scaled(r, key, scale) for r in rows],
                name="held out (95 % interval)",
                marker_color=HELD_OUT_COLOUR,
                legendgroup="out",
                showlegend=col == 1,
                error_y=_error_bars(rows, key, ci_key, scale),
                hovertemplate=f"%{{x}} held out: {fmt}<extra></extra>",
            ),
            row=1,
            col=col,
        )
    fig.update_yaxes(title_text="balanced accuracy [%]", range=[0, 105], row=1, col=1)
    fig.update_yaxes(title_text="timing MAE [s]", rangemode="tozero", row=1, col=2)
    fig.update_xaxes(title_text="policy", row=1, col=1)
    fig.update_xaxes(title_text="policy", row=1, col=2)
    fig.update_layout(
        barmode="group", height=380, margin=dict(t=40), legend=dict(orientation="h", yanchor="top", y=-0.22, x=0)
    )
    return fig


def crossval_folds(per_fold: list[dict] | None, policies: tuple[str, ...] = POLICIES) -> go.Figure:
    """Each fold's held-out balanced accuracy per policy (how much the figure moves between folds)."""
    df = pd.DataFrame(per_fold or [])
    fig = go.Figure()
    if not df.empty and "fold" in df:
        df = df.sort_values("fold")
        for p in policies:
            col = f"{p}_balanced_accuracy"
            if col in df:
                fig.add_trace(
                    go.Scatter(
                        x=df["fold"] + 1,
                        y=pd.to_numeric(df[col], errors="coerce") * 100.0,
                        mode="lines+markers",
                        name=p,
                        marker=dict(color=POLICY_COLOURS.get(p), size=9),
                        line=dict(width=1),
                        customdata=df.get("n_decisions"),
                        hovertemplate=f"{p}, fold %{{x}}: %{{y:.1f}} % (%{{customdata}} decisions)<extra></extra>",
                    )
                )
    fig.update_layout(
        xaxis=dict(title="held-out fold [-]", dtick=1),
        height=320,
        margin=dict(t=20),
        yaxis=dict(title="balanced accuracy [%]", range=[0, 105]),
        legend=dict(orientation="h", yanchor="top", y=-0.25, x=0),
    )
    return fig


FLEET_SYMBOLS = {"agent": "circle", "greedy": "diamond", "imitation": "square"}


def fleet_agreement(table: pd.DataFrame, policies: tuple[str, ...] = POLICIES) -> go.Figure:
    """Per-target agreement with the drivers: one row per driver (or style), sorted by the agent's
    balanced accuracy, a marker per policy (mean over the target's seeds; an open agent marker:
    not every seed meets the target)."""
    fig = go.Figure()
    done = table[table["agent_balanced_accuracy"].notna()]
    if done.empty:
        fig.update_layout(title="no agent evaluated yet", height=200)
        return fig
    cols = [f"{p}_balanced_accuracy" for p in policies]
    per = done.groupby("target", sort=False).agg(
        **{c: (c, "mean") for c in cols},
        seeds=("seed", "count"),
        meets=("meets_target", lambda s: bool((s == True).all())),  # noqa: E712
    )
    per = per.sort_values("agent_balanced_accuracy")
    names = per.index.astype(str)
    for p, c in zip(policies, cols):
        if per[c].notna().any():
            open_ = p == "agent"
            fig.add_trace(
                go.Scatter(
                    x=per[c] * 100.0,
                    y=names,
                    mode="markers",
                    name="agent (open: misses its target)" if open_ else p,
                    marker=dict(
                        color=POLICY_COLOURS.get(p),
                        symbol=[FLEET_SYMBOLS[p] + ("" if not open_ or m else "-open") for m in per["meets"]],
                        size=9,
                        line=dict(width=1.5, color=POLICY_COLOURS.get(p)),
                    ),
                    customdata=np.c_[per["seeds"]],
                    hovertemplate=f"%{{y}}: {p} %{{x:.1f}} % (mean of %{{customdata[0]}} seeds)<extra></extra>",
                )
            )
    height = int(min(3000, max(320, 16 * len(per) + 140)))
    fig.update_layout(
        xaxis=dict(title="balanced accuracy on the target's decisions [%] (in-sample)", side="top"),
        yaxis=dict(title="target, by agent BA", type="category", tickfont=dict(size=10), range=[-0.6, len(per) - 0.4]),
        height=height,
        margin=dict(t=100, b=20),
        # above the x axis drawn on top (its ticks and title take ~55 px)
        legend=dict(orientation="h", yanchor="bottom", y=1.0 + 58 / (height - 120), x=0),
    )
    return fig
