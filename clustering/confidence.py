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

from clustering.features import (
    feature_groups,
    feature_names,
    feature_speeds,
    fit_method,
    group_values,
    lines_by_row,
    to_space,
)
from clustering.styles import StyleClusterer
from indicators.settings import AnalysisSettings


def bootstrap_stability(
    points: pd.DataFrame, drivers: list[str], labels: np.ndarray, clf: StyleClusterer, settings: AnalysisSettings
) -> np.ndarray:
    """Share of `settings.n_bootstrap` resamples in which each driver keeps its label."""
    rng = np.random.default_rng(settings.random_state)
    speeds = np.asarray(settings.feature_speeds_kph, dtype=float) / 3.6
    n = len(speeds)
    B = settings.n_bootstrap
    values = np.full((B, len(drivers), len(feature_names(settings))), np.nan)
    for di, ii, g in feature_groups(points, drivers, settings):
        if len(g.v) == 0:
            continue
        ys = to_space(g.y, g.indicator, settings)
        idx = rng.integers(0, len(g.v), (B, len(g.v)))
        if group_values(g.v, g.y, g.indicator, settings, speeds)[1]:
            # too few points / no speed spread: the feature is the median, so resample the median
            values[:, di, ii * n : (ii + 1) * n] = np.median(ys[idx], axis=1)[:, None]
            continue
        A, b = lines_by_row(g.v[idx], ys[idx], fit_method(g.indicator, settings))
        at = feature_speeds(speeds, g.v, settings)  # the driver's own range, as its features
        values[:, di, ii * n : (ii + 1) * n] = A[:, None] * at[None, :] + b[:, None]
    flat = pd.DataFrame(values.reshape(B * len(drivers), -1), columns=clf.feature_names_in_)
    pred = clf.predict(flat).reshape(B, len(drivers))
    return (pred == labels[None, :]).mean(axis=0)
