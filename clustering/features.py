"""Per-driver clustering features: each driver's (robustly fitted) indicator line,
evaluated at the section speeds.

For every driver and indicator in `feature_indicators`, a line of the indicator
against ego speed is fitted on the driver's presses (Theil-Sen by default, on
log-TTC by default, so a few decisions made behind a slow leader with TTCs of tens
of seconds do not drag the line) and evaluated at `feature_speeds_kph`. Values are
reported back in the indicator's unit (seconds for TTCs). When a line cannot be
fitted (fewer than 3 points or no speed spread) the driver's median is used at
every speed; when there are no defined values at all the features are NaN and the
reason is returned (the clusterer imputes them).
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from indicators.settings import AnalysisSettings
from indicators.stats import INDICATOR_COLUMNS, iter_groups

_LOG_FLOOR_S = 0.05  # TTCs are clipped here before the log (a zero gap gives TTC 0)


def feature_name(indicator: str, kph: float) -> str:
    """Column name of a feature, e.g. 't_f_at_80kph_s'."""
    unit = "s" if INDICATOR_COLUMNS[indicator][2] == "s" else "mps"
    return f"{indicator}_at_{kph:g}kph_{unit}"


def feature_names(settings: AnalysisSettings) -> list[str]:
    return [feature_name(ind, kph) for ind in settings.feature_indicators for kph in settings.feature_speeds_kph]


def robust_line(v: np.ndarray, y: np.ndarray, method: str) -> tuple[float, float]:
    """(A, b) of y = A v + b by 'theilsen', 'huber' or 'ols'."""
    if method == "theilsen":  # as scipy's theilslopes (method 'separate'), without its overhead
        i, j = np.triu_indices(len(v), 1)
        dv = v[j] - v[i]
        ok = dv != 0
        slope = float(np.median((y[j] - y[i])[ok] / dv[ok]))
        return slope, float(np.median(y) - slope * np.median(v))
    if method == "huber":
        import statsmodels.api as sm

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = sm.RLM(y, sm.add_constant(v, has_constant="add"), M=sm.robust.norms.HuberT()).fit()
        return float(res.params[1]), float(res.params[0])
    if method == "ols":
        A, b = np.polyfit(v, y, 1)
        return float(A), float(b)
    raise ValueError(f"unknown feature_fit {method!r}: use 'theilsen', 'huber' or 'ols'")


def driver_features(points: pd.DataFrame, drivers: list[str],
                    settings: AnalysisSettings | None = None) -> tuple[pd.DataFrame, dict[str, list[str]]]:
    """Feature table (index driver_id) and per driver the notes on features not from a line.

    `points` is `indicators.stats.indicator_points(decisions)`.
    """
    settings = settings or AnalysisSettings()
    speeds = np.asarray(settings.feature_speeds_kph, dtype=float) / 3.6
    names = feature_names(settings)
    values = np.full((len(drivers), len(names)), np.nan)
    notes: dict[str, list[str]] = {d: [] for d in drivers}
    n_speeds = len(speeds)
    inds = tuple(settings.feature_indicators)
    for j, g in enumerate(iter_groups(points, drivers, inds)):
        di, ii = divmod(j, len(inds))
        ind, drv = g.indicator, g.driver_id
        if len(g.v) == 0:
            notes[drv].append(f"{ind}: no defined values, imputed")
            continue
        is_ttc = INDICATOR_COLUMNS[ind][2] == "s"
        yt = np.log(np.maximum(g.y, _LOG_FLOOR_S)) if (is_ttc and settings.feature_log) else g.y
        if len(g.v) < 3 or np.ptp(g.v) < settings.min_speed_spread_mps:
            vals = np.full(n_speeds, float(np.median(yt)))
            notes[drv].append(f"{ind}: {'too few points' if len(g.v) < 3 else 'no speed spread'}, median used")
        else:
            A, b = robust_line(g.v, yt, settings.feature_fit)
            vals = A * speeds + b
        values[di, ii * n_speeds:(ii + 1) * n_speeds] = np.exp(vals) if (is_ttc and settings.feature_log) else vals
    feats = pd.DataFrame(values, index=pd.Index(drivers, name="driver_id"), columns=names)
    return feats, notes


def transform_features(feats: pd.DataFrame, settings: AnalysisSettings) -> pd.DataFrame:
    """The space clustering works in: log of TTC features when `feature_log`, else as is."""
    out = feats.copy()
    if settings.feature_log:
        for c in out.columns:
            if c.endswith("_s"):
                out[c] = np.log(np.maximum(out[c], _LOG_FLOOR_S))
    return out
