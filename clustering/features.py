"""Per-driver clustering features: each driver's (robustly fitted) indicator line,
evaluated at the section speeds (within the speeds of the driver's own presses).

For every driver and indicator in `feature_indicators`, a line of the indicator
against ego speed is fitted on the driver's presses (Huber by default, on
log-TTC by default, so a few decisions made behind a slow leader with TTCs of tens
of seconds do not drag the line) and evaluated at `feature_speeds_kph`, each
clipped to the range of speeds the driver's presses of that indicator span: a
line is not extrapolated (see `AnalysisSettings.feature_extrapolate`). Values are
reported back in the indicator's unit (seconds for TTCs). When a line cannot be
fitted (fewer than 3 points or no speed spread) the driver's median is used at
every speed; when there are no defined values at all the features are NaN and the
reason is returned (the clusterer imputes them).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from indicators.settings import FEATURE_FITS, AnalysisSettings
from indicators.following import FOLLOW_QUANTILE
from indicators.stats import FEATURE_UNITS, PAPER_COLUMNS, TRAIT_UNITS, iter_groups

LOG_FLOOR_S = 0.05  # TTCs and headways are clipped here before the log (a zero gap gives 0)
LOG_FLOOR_M = 0.5  # gaps are clipped here before the log (a car alongside has a gap <= 0)
_SUFFIX = {"s": "s", "m": "m", "m/s": "mps"}
_LOG_FLOOR = {"s": LOG_FLOOR_S, "m": LOG_FLOOR_M}  # units whose features live on a log scale


def feature_name(indicator: str, kph: float) -> str:
    """Column name of a feature, e.g. 't_f_at_80kph_s', 'gap_f_at_80kph_m'."""
    return f"{indicator}_at_{kph:g}kph_{_SUFFIX[FEATURE_UNITS[indicator]]}"


def column_floor(column: str) -> float | None:
    """The log floor of a feature column by its unit suffix (None: not on a log scale)."""
    return LOG_FLOOR_S if column.endswith("_s") else LOG_FLOOR_M if column.endswith("_m") else None


def feature_names(settings: AnalysisSettings) -> list[str]:
    return [feature_name(ind, kph) for ind in settings.feature_indicators for kph in settings.feature_speeds_kph]


def lines_by_row(V: np.ndarray, Y: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) of Y[r] = A[r] V[r] + b[r] for every row r, by 'theilsen', 'huber', 'ols' or 'median'.

    Vectorised over rows (all drivers at once, or the resamples of a bootstrap); rows
    of different lengths are padded with NaN. 'theilsen': median of pairwise slopes,
    intercept median(y) - A median(v), as scipy's `theilslopes`; 'huber': IRLS with
    Huber's t = 1.345 and MAD scale (about zero) re-estimated every step, as
    statsmodels' `RLM(M=HuberT())`; 'median': a flat line at the median (A = 0); 'trimmed':
    a flat line at the mean of the values left after cutting `TRIM` of them at each end
    (as scipy's `trim_mean`); 'q25': a flat line at the `FOLLOW_QUANTILE` quantile.
    """
    V = np.atleast_2d(np.asarray(V, dtype=float))
    Y = np.atleast_2d(np.asarray(Y, dtype=float))
    ok = np.isfinite(V) & np.isfinite(Y)
    if method == "median":
        return np.zeros(len(Y)), _row_nanmedian(np.where(ok, Y, np.nan))
    if method == "trimmed":
        return np.zeros(len(Y)), _row_trimmed_mean(np.where(ok, Y, np.nan), TRIM)
    if method == "q25":
        with np.errstate(all="ignore"):
            return np.zeros(len(Y)), np.nanquantile(np.where(ok, Y, np.nan), FOLLOW_QUANTILE, axis=1)
    if method == "theilsen":
        i, j = np.triu_indices(V.shape[1], 1)
        dv = V[:, j] - V[:, i]
        with np.errstate(invalid="ignore", divide="ignore"):
            slopes = np.where(ok[:, i] & ok[:, j] & (dv != 0), (Y[:, j] - Y[:, i]) / dv, np.nan)
        A = _row_nanmedian(slopes)
        return A, _row_nanmedian(np.where(ok, Y, np.nan)) - A * _row_nanmedian(np.where(ok, V, np.nan))
    V0, Y0, W1 = np.where(ok, V, 0.0), np.where(ok, Y, 0.0), ok.astype(float)
    if method == "ols":
        return _wls(V0, Y0, W1)
    if method == "huber":
        A, b = _wls(V0, Y0, W1)
        for _ in range(_HUBER_MAXITER):
            r = Y0 - (A[:, None] * V0 + b[:, None])
            scale = _row_nanmedian(np.where(ok, np.abs(r), np.nan)) / 0.6744897501960817
            scale = np.where(scale > 0, scale, 1.0)
            z = np.abs(r) / scale[:, None]
            w = np.where(z <= _HUBER_T, 1.0, _HUBER_T / np.maximum(z, 1e-300)) * W1
            A_new, b_new = _wls(V0, Y0, w)
            done = np.all(np.abs(A_new - A) <= 1e-10 * (1 + np.abs(A))) and np.all(
                np.abs(b_new - b) <= 1e-10 * (1 + np.abs(b))
            )
            A, b = A_new, b_new
            if done:
                break
        return A, b
    raise ValueError(f"unknown feature_fit {method!r}: use one of {', '.join(FEATURE_FITS)}")


_HUBER_T = 1.345
_HUBER_MAXITER = 50


def _wls(V: np.ndarray, Y: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sw = W.sum(axis=1)
    vm = (W * V).sum(axis=1) / sw
    ym = (W * Y).sum(axis=1) / sw
    dv = V - vm[:, None]
    sxx = (W * dv * dv).sum(axis=1)
    A = np.where(sxx > 0, (W * dv * (Y - ym[:, None])).sum(axis=1) / np.where(sxx > 0, sxx, 1.0), 0.0)
    return A, ym - A * vm


#: Share of a driver's values cut at each end before the 'trimmed' mean.
TRIM = 0.2


def _row_trimmed_mean(x: np.ndarray, cut: float) -> np.ndarray:
    """Mean of each row ignoring NaN after dropping int(cut * n) values at each end (as
    scipy.stats.trim_mean on the row's n defined values)."""
    srt = np.sort(x, axis=1)  # NaN last
    c = (~np.isnan(x)).sum(axis=1)
    k = (cut * c).astype(int)
    csum = np.concatenate([np.zeros((len(x), 1)), np.cumsum(np.nan_to_num(srt), axis=1)], axis=1)
    rows = np.arange(len(x))
    m = c - 2 * k
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(c > 0, (csum[rows, c - k] - csum[rows, k]) / np.where(m > 0, m, 1), np.nan)


def _row_nanmedian(x: np.ndarray) -> np.ndarray:
    """Median of each row ignoring NaN (as np.nanmedian, several times faster: one sort)."""
    srt = np.sort(x, axis=1)  # NaN last
    c = (~np.isnan(x)).sum(axis=1)
    rows = np.arange(len(x))
    lo = srt[rows, np.maximum((c - 1) // 2, 0)]
    hi = srt[rows, np.maximum(c // 2, 0)]
    return np.where(c > 0, (lo + hi) / 2, np.nan)


def fit_method(indicator: str, settings: AnalysisSettings) -> str:
    """How `indicator`'s feature line is fitted: `feature_fit` for the study's indicators,
    `acceptance_fit` for those of what the driver accepts (gaps, headways, relative speeds),
    the low quantile 'q25' for the headway kept in steady following (`indicators.following`)."""
    if indicator in TRAIT_UNITS:
        return "q25"
    return settings.feature_fit if indicator in PAPER_COLUMNS else settings.acceptance_fit


def robust_line(v: np.ndarray, y: np.ndarray, method: str) -> tuple[float, float]:
    """(A, b) of y = A v + b by 'theilsen', 'huber' or 'ols' (see `lines_by_row`)."""
    A, b = lines_by_row(v[None, :], y[None, :], method)
    return float(A[0]), float(b[0])


def to_space(y: np.ndarray, indicator: str, settings: AnalysisSettings) -> np.ndarray:
    """Indicator values in the clustering space (log of times and gaps when `feature_log`)."""
    floor = _LOG_FLOOR.get(FEATURE_UNITS[indicator])
    return np.log(np.maximum(y, floor)) if (floor is not None and settings.feature_log) else y


def feature_speeds(speeds_mps: np.ndarray, v: np.ndarray, settings: AnalysisSettings) -> np.ndarray:
    """Where a driver's line is read for its features: `speeds_mps`, or, unless
    `feature_extrapolate`, those speeds clipped to the range of the driver's own presses
    `v` (a line fitted on 7 presses at 68-87 km/h says little about 60 km/h)."""
    if settings.feature_extrapolate or len(v) == 0:
        return speeds_mps
    return np.clip(speeds_mps, np.min(v), np.max(v))


def group_values(
    v: np.ndarray, y: np.ndarray, indicator: str, settings: AnalysisSettings, speeds_mps: np.ndarray
) -> tuple[np.ndarray, str]:
    """Feature values of one driver/indicator at `speeds_mps`, in the clustering space
    (log seconds for TTCs when `feature_log`), and a note when not from a line."""
    yt = to_space(y, indicator, settings)
    if indicator in TRAIT_UNITS:  # a level over the drive's episodes: no line, no speed spread needed
        A, b = robust_line(v, yt, fit_method(indicator, settings))
        return np.full(len(speeds_mps), b), ""
    if len(v) < 3 or np.ptp(v) < settings.min_speed_spread_mps:
        why = "too few points" if len(v) < 3 else "no speed spread"
        return np.full(len(speeds_mps), float(np.median(yt))), f"{indicator}: {why}, median used"
    A, b = robust_line(v, yt, fit_method(indicator, settings))
    return A * feature_speeds(speeds_mps, v, settings) + b, ""


def feature_groups(points: pd.DataFrame, drivers: list[str], settings: AnalysisSettings):
    """(driver index, indicator index, Group) for every driver x feature indicator."""
    inds = tuple(settings.feature_indicators)
    for j, g in enumerate(iter_groups(points, drivers, inds)):
        di, ii = divmod(j, len(inds))
        yield di, ii, g


def to_units(values: np.ndarray, settings: AnalysisSettings) -> np.ndarray:
    """Clustering-space feature matrix back to the indicators' units (seconds for TTCs)."""
    out = values.copy()
    if settings.feature_log:
        n = len(settings.feature_speeds_kph)
        for ii, ind in enumerate(settings.feature_indicators):
            if FEATURE_UNITS[ind] in _LOG_FLOOR:
                out[:, ii * n : (ii + 1) * n] = np.exp(out[:, ii * n : (ii + 1) * n])
    return out


def driver_features(
    points: pd.DataFrame, drivers: list[str], settings: AnalysisSettings | None = None
) -> tuple[pd.DataFrame, dict[str, list[str]]]:
    """Feature table (index driver_id, indicators' units) and per driver the notes on
    features not from a line. `points` is `indicators.stats.indicator_points(decisions)`."""
    settings = settings or AnalysisSettings()
    speeds = np.asarray(settings.feature_speeds_kph, dtype=float) / 3.6
    n = len(speeds)
    values = np.full((len(drivers), len(feature_names(settings))), np.nan)
    notes: dict[str, list[str]] = {d: [] for d in drivers}
    lines = []  # (di, ii, v, y in the clustering space) of groups fitted with a line
    for di, ii, g in feature_groups(points, drivers, settings):
        if len(g.v) == 0:
            notes[g.driver_id].append(f"{g.indicator}: no defined values, imputed")
            continue
        if len(g.v) < 3 or np.ptp(g.v) < settings.min_speed_spread_mps:
            vals, note = group_values(g.v, g.y, g.indicator, settings, speeds)
            if note:
                notes[g.driver_id].append(note)
            values[di, ii * n : (ii + 1) * n] = vals
            continue
        lines.append((di, ii, g.v, to_space(g.y, g.indicator, settings), fit_method(g.indicator, settings)))
    # all lines of one fit method in one vectorised fit, rows padded with NaN to the longest
    for method in sorted({c[4] for c in lines}):
        same = [c for c in lines if c[4] == method]
        for start in range(0, len(same), 4096):
            chunk = same[start : start + 4096]
            width = max(len(c[2]) for c in chunk)
            V = np.full((len(chunk), width), np.nan)
            Y = np.full((len(chunk), width), np.nan)
            for r, (_, _, v, y, _) in enumerate(chunk):
                V[r, : len(v)], Y[r, : len(y)] = v, y
            A, b = lines_by_row(V, Y, method)
            for r, (di, ii, v, _, _) in enumerate(chunk):
                values[di, ii * n : (ii + 1) * n] = A[r] * feature_speeds(speeds, v, settings) + b[r]
    feats = pd.DataFrame(
        to_units(values, settings), index=pd.Index(drivers, name="driver_id"), columns=feature_names(settings)
    )
    return feats, notes


def transform_features(feats: pd.DataFrame, settings: AnalysisSettings) -> pd.DataFrame:
    """The space clustering works in: log of time and gap features when `feature_log`, else as is."""
    out = feats.copy()
    if settings.feature_log:
        for c in out.columns:
            floor = column_floor(c)
            if floor is not None:
                out[c] = np.log(np.maximum(out[c], floor))
    return out
