"""The figures' helpers: TensorBoard smoothing, an axis scaled to the used points, labels that do not overlap."""

import numpy as np
import pytest

from laneprint.plotting import axis_range, clip_to_axis, ema_smooth, spread_labels


def test_ema_is_debiased_as_tensorboard():
    # by hand, w = 0.5: last = 0.5*0 + 0.5*2 = 1 -> 1/(1-0.5) = 2;  last = 0.5 + 2 = 2.5 -> 2.5/0.75;
    # last = 1.25 + 0.5*8 = 5.25 -> 5.25/0.875 = 6
    assert ema_smooth([2.0, 4.0, 8.0], 0.5).tolist() == pytest.approx([2.0, 2.5 / 0.75, 6.0])
    assert ema_smooth([3.0, 3.0, 3.0], 0.99).tolist() == pytest.approx([3.0] * 3)  # no pull towards 0
    assert ema_smooth([1.0, 5.0, 2.0], 0.0).tolist() == [1.0, 5.0, 2.0]


def test_ema_skips_missing_values():
    out = ema_smooth([2.0, None, np.nan, 4.0, "x"], 0.5)
    assert out[0] == 2.0 and np.isnan(out[1]) and np.isnan(out[2]) and np.isnan(out[4])
    assert out[3] == pytest.approx(2.5 / 0.75)  # as if the gaps were not there
    assert len(ema_smooth([], 0.9)) == 0
    with pytest.raises(ValueError):
        ema_smooth([1.0], 1.0)


def test_ema_smooths_noise_towards_the_trend():
    rng = np.random.default_rng(0)
    noisy = np.linspace(0, 1, 2000) + rng.normal(0, 0.5, 2000)
    smooth = ema_smooth(noisy, 0.95)
    trend = np.linspace(0, 1, 2000)
    assert np.std(np.diff(smooth)) < 0.1 * np.std(np.diff(noisy))
    assert np.abs(smooth - trend).mean() < 0.3 * np.abs(noisy - trend).mean()


def test_axis_range_pads_the_used_points():
    assert axis_range([1.0, 3.0, np.nan], pad=0.1) == pytest.approx((0.8, 3.2))
    assert axis_range([np.nan]) is None and axis_range([]) is None
    lo, hi = axis_range([5.0, 5.0])  # one value: a span around it, not a zero-height axis
    assert lo < 5.0 < hi


def test_clip_to_axis_marks_the_edge_and_keeps_the_value():
    c = clip_to_axis([0.5, 2.0, 350.0, -3.0], 0.0, 10.0)
    assert c["y"].tolist() == [0.5, 2.0, 10.0, 0.0]
    assert c["side"].tolist() == ["", "", "above", "below"]
    assert c["value"].tolist() == [0.5, 2.0, 350.0, -3.0]


def test_spread_labels_never_overlap_and_prefer_priority():
    from laneprint.plotting import _apart, _label_box

    rng = np.random.default_rng(1)
    x, y = rng.normal(size=100), rng.normal(size=100)
    texts = [f"D{i:04d}" for i in range(100)]
    prio = np.zeros(100)
    prio[[17, 42, 99]] = 1.0
    sides = spread_labels(x, y, texts, priority=prio, max_labels=12)
    placed = np.flatnonzero(sides != "")
    assert 3 <= len(placed) <= 12 and {17, 42, 99} <= set(placed)
    ux, uy = (x - x.min()) / np.ptp(x), (y - y.min()) / np.ptp(y)
    boxes = [
        _label_box(ux[i], uy[i], sides[i], 0.014 * len(texts[i]), 0.05, 0.08 if prio[i] else 0.015) for i in placed
    ]
    assert all(_apart(a, b) for i, a in enumerate(boxes) for b in boxes[i + 1 :])
    # two points on one spot: the priority one's label stands off (on an arrow), the other's is next to it
    assert spread_labels([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], ["a", "b", "c"], priority=[0, 1, 0]).tolist() == [
        "top",
        "top",
        "top",
    ]
    assert spread_labels([0.0, 0.0, 1.0], [0.0, 0.0, 1.0], ["a", "b", "c"]).tolist() == ["top", "bottom", "top"]
    assert spread_labels(range(10), [0.0, 1.0] * 5, ["x"] * 10, max_labels=5).tolist().count("") == 5
    assert spread_labels([], [], []).tolist() == []


def test_envelope_keeps_extremes_and_ends_within_the_budget():
    from laneprint.plotting import envelope_indices

    y = np.sin(np.linspace(0, 60, 100_000))
    y[31_337] = 50.0  # one spike
    idx = envelope_indices(y, 2000)
    assert len(idx) <= 2000 and idx[0] == 0 and idx[-1] == len(y) - 1
    assert (np.diff(idx) > 0).all() and 31_337 in idx
    assert y[idx].min() == y.min() and y[idx].max() == 50.0
    assert envelope_indices(y[:50], 2000).tolist() == list(range(50))  # short curves drawn whole
    assert len(envelope_indices(np.full(10_000, np.nan), 100)) <= 100


def test_even_indices_and_sample_rows():
    import pandas as pd

    from laneprint.plotting import even_indices, sample_rows

    assert even_indices(10, 4).tolist() == [0, 3, 6, 9] and even_indices(3, 10).tolist() == [0, 1, 2]
    assert len(even_indices(0, 10)) == 0
    df = pd.DataFrame({"a": range(10_000)})
    s = sample_rows(df, 500, seed=1)
    assert len(s) == 500 and s["a"].is_monotonic_increasing and s.equals(sample_rows(df, 500, seed=1))
    assert sample_rows(df.head(20), 500) is not None and len(sample_rows(df.head(20), 500)) == 20
