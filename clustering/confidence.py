"""Bootstrap stability of style assignments.

Each bootstrap resamples, with replacement, every driver's usable presses per
indicator, recomputes the driver's features, and assigns them to the fitted centres
(the clustering itself is not redone, so labels stay comparable). A driver's
stability is the share of resamples that give the style it was assigned: 1 when its
own decisions leave no doubt, near 1/k when a few decisions more or less would move it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from clustering.features import LOG_FLOOR_S, feature_groups, feature_names, group_values
from clustering.styles import StyleClusterer
from indicators.settings import AnalysisSettings
from indicators.stats import INDICATOR_COLUMNS


def _row_nanmedian(x: np.ndarray) -> np.ndarray:
    """Median of each row ignoring NaN (np.nanmedian, several times faster: one sort)."""
    srt = np.sort(x, axis=1)  # NaN last
    c = (~np.isnan(x)).sum(axis=1)
    rows = np.arange(len(x))
    lo = srt[rows, np.maximum((c - 1) // 2, 0)]
    hi = srt[rows, np.maximum(c // 2, 0)]
    return np.where(c > 0, (lo + hi) / 2, np.nan)


def _resampled_lines(v: np.ndarray, y: np.ndarray, idx: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) of each resample (rows of `idx`), vectorised over resamples."""
    V, Y = v[idx], y[idx]
    if method == "theilsen":
        i, j = np.triu_indices(idx.shape[1], 1)
        dv = V[:, j] - V[:, i]
        with np.errstate(invalid="ignore", divide="ignore"):
            slopes = np.where(dv != 0, (Y[:, j] - Y[:, i]) / dv, np.nan)
        A = _row_nanmedian(slopes)
        return A, np.median(Y, axis=1) - A * np.median(V, axis=1)
    # OLS (also used for 'huber' here: the bootstrap is about spread, not the tails)
    vm, ym = V.mean(axis=1, keepdims=True), Y.mean(axis=1, keepdims=True)
    sxx = ((V - vm) ** 2).sum(axis=1)
    A = np.where(sxx > 0, ((V - vm) * (Y - ym)).sum(axis=1) / np.where(sxx > 0, sxx, 1), 0.0)
    return A, ym[:, 0] - A * vm[:, 0]


def bootstrap_stability(points: pd.DataFrame, drivers: list[str], labels: np.ndarray, clf: StyleClusterer,
                        settings: AnalysisSettings) -> np.ndarray:
    """Share of `settings.n_bootstrap` resamples in which each driver keeps its label."""
    rng = np.random.default_rng(settings.random_state)
    speeds = np.asarray(settings.feature_speeds_kph, dtype=float) / 3.6
    n = len(speeds)
    B = settings.n_bootstrap
    values = np.full((B, len(drivers), len(feature_names(settings))), np.nan)
    for di, ii, g in feature_groups(points, drivers, settings):
        if len(g.v) == 0:
            continue
        is_ttc = INDICATOR_COLUMNS[g.indicator][2] == "s"
        ys = np.log(np.maximum(g.y, LOG_FLOOR_S)) if (is_ttc and settings.feature_log) else g.y
        idx = rng.integers(0, len(g.v), (B, len(g.v)))
        if group_values(g.v, g.y, g.indicator, settings, speeds)[1]:
            # too few points / no speed spread: the feature is the median, so resample the median
            values[:, di, ii * n:(ii + 1) * n] = np.median(ys[idx], axis=1)[:, None]
            continue
        A, b = _resampled_lines(g.v, ys, idx, settings.feature_fit)
        values[:, di, ii * n:(ii + 1) * n] = A[:, None] * speeds[None, :] + b[:, None]
    flat = pd.DataFrame(values.reshape(B * len(drivers), -1), columns=clf.feature_names_in_)
    pred = clf.predict(flat).reshape(B, len(drivers))
    return (pred == labels[None, :]).mean(axis=0)
