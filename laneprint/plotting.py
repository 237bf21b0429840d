"""Small pure helpers the stages' Plotly figures share: a smoothed curve, an axis scaled to the
points that matter (the rest marked at its edge), labels that do not overlap, and fewer points to
draw (a long curve's envelope, a random sample of a dense cloud) so that pages stay quick in a browser."""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import pandas as pd


def ema_smooth(values: Sequence[float] | np.ndarray | pd.Series, weight: float) -> np.ndarray:
    """TensorBoard's smoothing: an exponential moving average with debiasing.

    s_t = (w s_{t-1} + (1 - w) x_t) / (1 - w^n_t), s_0 = 0, n_t the number of finite
    values so far: the first points are not pulled towards zero. Non-finite values
    stay NaN and do not enter the average; `weight` 0 returns the values unchanged.
    """
    if not 0.0 <= weight < 1.0:
        raise ValueError(f"smoothing weight must be in [0, 1), not {weight}")
    y = pd.to_numeric(pd.Series(np.asarray(values, dtype=object)), errors="coerce").astype(float)
    out = np.full(len(y), np.nan)
    ok = np.isfinite(y.to_numpy())
    if ok.any():
        # pandas' adjusted EWM is sum(w^i x_{t-i}) / sum(w^i): exactly the debiased average
        out[ok] = y[ok].ewm(alpha=1.0 - weight, adjust=True).mean().to_numpy()
    return out


def even_indices(n: int, max_points: int) -> np.ndarray:
    """At most `max_points` indices of `n` values, evenly spread, first and last included
    (enough to draw a smooth curve)."""
    return np.unique(np.linspace(0, n - 1, min(n, max_points)).round().astype(int)) if n else np.arange(0)


def envelope_indices(values: Sequence[float] | np.ndarray, max_points: int) -> np.ndarray:
    """Indices of at most `max_points` values that draw the same curve at screen resolution: the
    values cut into runs, the lowest and the highest of each run kept with the first and last value
    (in order), so spikes and the curve's extent survive. All indices when there are no more than `max_points`."""
    v = np.asarray(values, dtype=float)
    n = len(v)
    if n <= max_points:
        return np.arange(n)
    edges = np.linspace(0, n, max(1, (max_points - 2) // 2) + 1).astype(int)
    filled = np.where(np.isfinite(v), v, np.nan)  # inf as a gap, as Plotly draws it
    keep = {0, n - 1}
    for lo, hi in zip(edges[:-1], edges[1:]):
        run = filled[lo:hi]
        if hi <= lo or np.isnan(run).all():
            keep.add(lo)
            continue
        keep.update((lo + int(np.nanargmin(run)), lo + int(np.nanargmax(run))))
    return np.array(sorted(keep))


def sample_rows(df: pd.DataFrame, max_rows: int, seed: int = 0) -> pd.DataFrame:
    """At most `max_rows` rows of `df` drawn at random (seeded), in their original order; all of
    them when there are no more. A uniform sample keeps the cloud's shape and the groups' shares."""
    if len(df) <= max_rows:
        return df
    rng = np.random.default_rng(seed)
    return df.iloc[np.sort(rng.choice(len(df), size=max_rows, replace=False))]


def axis_range(
    values: Sequence[float] | np.ndarray, pad: float = 0.08, min_span: float = 1e-6
) -> tuple[float, float] | None:
    """[lo, hi] around the finite `values`, padded by `pad` of their span (None when there are none)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not len(v):
        return None
    lo, hi = float(v.min()), float(v.max())
    span = max(hi - lo, abs(hi) * 0.1, min_span)
    return lo - pad * span, hi + pad * span


def clip_to_axis(values: Sequence[float] | np.ndarray, lo: float, hi: float) -> pd.DataFrame:
    """Where each value is drawn on an axis [lo, hi]: `y` (clipped to the edge) and `side`
    ('above', 'below' or '' when inside); `value` keeps the true value for the hover."""
    v = np.asarray(values, dtype=float)
    side = np.where(v > hi, "above", np.where(v < lo, "below", ""))
    return pd.DataFrame({"value": v, "y": np.clip(v, lo, hi), "side": side})


#: Plotly's number of each marker symbol ('-open': + 100). A long per-point list of symbol names costs
#: Plotly's validator a regex pass per point (0.16 s for Fig. 11's 4000 points); numbers skip it.
SYMBOL_CODES = {
    "circle": 0,
    "square": 1,
    "diamond": 2,
    "triangle-up": 5,
    "triangle-down": 6,
    "triangle-left": 7,
    "triangle-right": 8,
}


def symbol_codes(names: Sequence[str] | np.ndarray) -> list[int]:
    """Plotly marker symbol numbers of symbol `names` ('circle', 'triangle-up-open', ...), per point."""
    codes = {**SYMBOL_CODES, **{f"{k}-open": v + 100 for k, v in SYMBOL_CODES.items()}}
    return [codes[n] for n in names]


LABEL_SIDES = ("top", "bottom", "right", "left")


def _label_box(ux: float, uy: float, side: str, width: float, height: float, gap: float) -> tuple[float, ...]:
    if side == "top":
        return ux - width / 2, ux + width / 2, uy + gap, uy + gap + height
    if side == "bottom":
        return ux - width / 2, ux + width / 2, uy - gap - height, uy - gap
    if side == "right":
        return ux + gap, ux + gap + width, uy - height / 2, uy + height / 2
    return ux - gap - width, ux - gap, uy - height / 2, uy + height / 2


def _apart(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[1] <= b[0] or a[0] >= b[1] or a[3] <= b[2] or a[2] >= b[3]


def spread_labels(
    x: Sequence[float],
    y: Sequence[float],
    texts: Sequence[str],
    priority: Sequence[float] | None = None,
    max_labels: int = 12,
    char_width: float = 0.014,
    height: float = 0.05,
    marker: float = 0.015,
    priority_gap: float = 0.08,
) -> np.ndarray:
    """Where to write each point's text so that no two labels overlap: 'top', 'bottom',
    'right', 'left' or '' (no label).

    Positions are scaled to [0, 1] per axis; a label is a box `char_width` per
    character wide and `height` tall beside its point. Points are taken by descending
    `priority` (then in order); each gets the first side whose box is clear of the
    labels already placed and of every other point (a marker `marker` wide), up to
    `max_labels`. A point with priority > 0 has its label `priority_gap` away (drawn on
    an arrow) and is labelled even among points, as long as its label overlaps no other.
    """
    xs, ys = (np.asarray(a, dtype=float) for a in (x, y))
    n = len(xs)
    where = np.full(n, "", dtype=object)
    if n == 0:
        return where

    def unit(a: np.ndarray) -> np.ndarray:
        finite = a[np.isfinite(a)]
        if not len(finite):
            return np.full_like(a, np.nan)
        span = float(finite.max() - finite.min()) or 1.0
        return (a - finite.min()) / span

    ux, uy = unit(xs), unit(ys)
    prio = np.zeros(n) if priority is None else np.nan_to_num(np.asarray(priority, dtype=float))
    boxes: list[tuple[float, ...]] = []
    for i in np.argsort(-prio, kind="stable"):
        if len(boxes) >= max_labels or not (np.isfinite(ux[i]) and np.isfinite(uy[i])):
            continue
        width = char_width * max(len(str(texts[i])), 1)
        near = (np.abs(ux - ux[i]) < marker) & (np.abs(uy - uy[i]) < marker)  # this point's own marker
        fallback = None
        for side in LABEL_SIDES:
            box = _label_box(ux[i], uy[i], side, width, height, priority_gap if prio[i] > 0 else marker)
            if not all(_apart(box, b) for b in boxes):
                continue
            fallback = fallback or (side, box)
            hit = (
                ~near
                & (ux > box[0] - marker)
                & (ux < box[1] + marker)
                & (uy > box[2] - marker)
                & (uy < box[3] + marker)
            )
            if not hit.any():
                where[i] = side
                boxes.append(box)
                break
        if not where[i] and prio[i] > 0 and fallback:
            where[i], box = fallback
            boxes.append(box)
    return where


#: Share of the points that may sit beyond each end of a heavy-tailed axis (drawn at its edge, counted).
TAIL_SHARE = 0.01
#: Tukey fence [IQRs beyond the quartiles]: with few points one far value is more than 1 % of them,
#: so the axis also stops at q3 + TAIL_FENCE * IQR (q1 - ... below) when that is nearer.
TAIL_FENCE = 3.0


#: At most this share of the points may be off a tail-ranged axis in all (it covers at least 95 % of them).
COVER_SHARE_OFF = 0.05


def tail_range(
    values: Sequence[float] | np.ndarray,
    share: float = TAIL_SHARE,
    fence: float = TAIL_FENCE,
    pad: float = 0.08,
    cover: bool = True,
) -> tuple[float, float] | None:
    """An axis [lo, hi] set by the bulk of the finite `values`, not by their tail (None when there are none).

    Each end is the nearer of the `share` quantile (so fewer than `share` of the points lie
    beyond it: no end is set by fewer than that share of the points) and the Tukey fence
    `fence` interquartile ranges beyond the quartiles (with 20 points, one TTC of 2500 s
    among values of 5-30 s is 5 % of them, but far beyond the fence). Never narrower than
    the quartiles, and never leaving more than `COVER_SHARE_OFF` (5 %) of the points off the axis:
    the farthest from the median stay off, the others bring its ends back (with under 20 points, every
    point is on it; `cover` False: the fence alone, the bulk's own range). Padded by `pad` of the span. Points beyond are the caller's to mark at the edge
    (`clip_to_axis`) and count.
    """
    v = np.asarray(values, dtype=float)
    v = np.sort(v[np.isfinite(v)])
    if not len(v):
        return None
    n = len(v)
    k = int(np.ceil(share * n)) - 1  # the most points that are fewer than `share` of them
    q_lo, q_hi = v[max(k, 0)], v[n - 1 - max(k, 0)]
    q1, q3 = np.quantile(v, [0.25, 0.75])
    iqr = q3 - q1
    f_lo, f_hi = (q1 - fence * iqr, q3 + fence * iqr) if iqr > 0 else (-np.inf, np.inf)
    cut_lo = max(min(q_lo, q1), min(f_lo, q1))
    cut_hi = min(max(q_hi, q3), max(f_hi, q3))
    beyond = np.flatnonzero((v < cut_lo) | (v > cut_hi))
    allowed = int(np.floor(COVER_SHARE_OFF * n))
    if (
        cover and len(beyond) > allowed
    ):  # never more than 5 % off the axis: the nearest of those beyond come back on it,
        # those the fence cut first (the `share` at each end stays off: no end is set by fewer than that)
        med, kq = float(np.median(v)), max(k, 0)
        fenced = (beyond >= kq) & (beyond <= n - 1 - kq)
        order = np.lexsort((np.abs(v[beyond] - med), ~fenced))  # fence-cut first, nearest first
        back = beyond[order[: len(beyond) - allowed]]
        cut_lo, cut_hi = min(cut_lo, float(v[back].min())), max(cut_hi, float(v[back].max()))
    lo, hi = float(v[v >= cut_lo][0]), float(v[v <= cut_hi][-1])  # the axis hugs the points it keeps
    span = max(hi - lo, abs(hi) * 0.1, 1e-6)
    return float(lo - pad * span), float(hi + pad * span)


def needs_log_axis(values: Sequence[float] | np.ndarray, spread: float = 8.0) -> bool:
    """Whether positive `values` are best drawn on a log axis: an axis covering 95 % of them (`tail_range`)
    would be more than `spread` times as tall as their bulk's (a TTC of minutes among a few seconds: with
    a dozen points, one is more than 5 % of them), so the bulk would sit in the bottom eighth."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not len(v) or (v <= 0).any():
        return False
    covered, bulk = tail_range(v), tail_range(v, cover=False)
    if covered is None or bulk is None:
        return False
    return (covered[1] - covered[0]) > spread * (bulk[1] - bulk[0])


def range_set_by_few(
    values: Sequence[float] | np.ndarray, axis: Sequence[float], share: float = TAIL_SHARE, pad: float = 0.08
) -> bool:
    """True when an axis `[lo, hi]` (padded by `pad` of its data span) reaches out to points that are fewer
    than `share` of `values`: without them, its data span would end nearer. The check the issue asks of
    every TTC and gap axis; used by the tests."""
    v = np.sort(np.asarray(values, dtype=float))
    v = v[np.isfinite(v)]
    if not len(v):
        return False
    lo_axis, hi_axis = float(axis[0]), float(axis[1])
    span = (hi_axis - lo_axis) / (1 + 2 * pad)
    lo, hi = lo_axis + pad * span, hi_axis - pad * span  # the data span the axis was drawn for
    n = len(v)
    k = int(np.ceil(share * n)) - 1
    if k < 1:
        return False
    tol = 1e-6 * max(1.0, abs(span))
    return bool(hi > v[n - 1 - k] + tol or lo < v[k] - tol)


def signed(x: float, digits: int = 2) -> str:
    """' + 1.20' or ' − 6.92' (a true minus sign): the second term of a formula."""
    return f" {'−' if x < 0 else '+'} {abs(x):.{digits}f}"


def line_formula(name: str, a: float, b: float, x: str = "v_e", digits_a: int = 3, digits_b: int = 2) -> str:
    """'t_f = 0.850 v_e − 6.92' (signs printed properly, a minus sign for a negative slope too)."""
    slope = f"{'−' if a < 0 else ''}{abs(a):.{digits_a}f}"
    return f"{name} = {slope} {x}{signed(b, digits_b)}"


def log_ticks(values: Sequence[float] | np.ndarray, max_ticks: int = 9) -> dict[str, Any]:
    """Tick positions and labels of a log axis over the positive finite `values`, written as the values
    they stand for ('0.5', '1', '2', '5', '10' s), never as Plotly's minor digits ('9 8 7 6 5' under 1
    on an axis shorter than a decade): every 1-9 step of each decade within the values' span, thinned
    to 1-2-5, 1-3 or 1 per decade when there would be more than `max_ticks`. `{}` when there are no values.
    Give it to `update_yaxes(**log_ticks(y))` (with `type='log'`)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    if not len(v):
        return {}
    lo, hi = float(v.min()), float(v.max())
    d_lo, d_hi = int(np.floor(np.log10(lo))), int(np.ceil(np.log10(hi)))
    for steps in (tuple(range(1, 10)), (1, 2, 5), (1, 3), (1,)):
        ticks = [float(f"{m * 10.0**d:.12g}") for d in range(d_lo, d_hi + 1) for m in steps]
        inside = [t for t in ticks if lo / 1.25 <= t <= hi * 1.25]
        if len(inside) <= max_ticks:
            break
    if len(inside) < 2:  # a narrow span: its ends, rounded
        inside = sorted({float(f"{lo:.2g}"), float(f"{hi:.2g}")})
    return {"tickvals": inside, "ticktext": [f"{t:g}" for t in inside], "tickmode": "array"}


def plateau_judgement(values: Sequence[float] | np.ndarray, tail: float = 0.1, min_points: int = 40) -> tuple[str, str]:
    """Whether a learning curve has levelled off at its end: ('plateau' | 'rising' | 'falling' | 'short', a
    sentence). Compares the mean of the last `tail` of the finite values with the mean of the `tail`
    before it: a difference beyond two standard errors of it and beyond 5 % of the curve's spread
    (the 5th-95th percentile) is 'rising' or 'falling'; 'short' under `min_points` values."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if len(v) < min_points:
        return "short", f"too few episodes ({len(v)}) to judge whether the curve has levelled off"
    w = max(int(len(v) * tail), 5)
    last, before = v[-w:], v[-2 * w : -w]
    diff = float(last.mean() - before.mean())
    se = float(np.sqrt(last.var(ddof=1) / len(last) + before.var(ddof=1) / len(before)))
    spread = float(np.subtract(*np.percentile(v, [95, 5])))
    share = f"{round(100 * tail)} %"
    if abs(diff) <= max(2 * se, 0.05 * spread):
        return "plateau", (
            f"levelled off: the last {share} of the episodes average {last.mean():.3g}, within noise "
            f"of the {share} before ({before.mean():.3g})"
        )
    if diff > 0:
        return "rising", (
            f"still rising at the end ({before.mean():.3g} → {last.mean():.3g} over the last two "
            f"{share} of the episodes): more episodes may help"
        )
    return "falling", (
        f"falling at the end ({before.mean():.3g} → {last.mean():.3g} over the last two {share} of "
        "the episodes): the last episodes did worse; look at the loss and the exploration rate"
    )
