"""Per-driver statistics of the indicators against ego speed: correlations and OLS lines.

Both work on the presses (label 'change') of a decisions table, one indicator at a
time, using only defined values (status 'ok'; 'far' followers too when
`fit_far_followers`). A driver/indicator with fewer than `min_fit_points` points, or
whose speeds span less than `min_speed_spread_mps`, gets no fit and a reason. A fit
that says little (R² below `min_fit_r2`, a slope interval that spans zero, fewer than
`min_flag_points` points) is kept and flagged (`flag` says why): it is no line to
steer by (see `clustering.pipeline.reference_lines`).

The indicators are the study's three (`t_f`, `t_nf`, `dv_nb`) and those of what the
driver accepts (gaps, headways, relative speeds: `indicators.acceptance`).

statsmodels stays inside this module: callers get tables and `LineFit` dataclasses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from scipy import special
from scipy import stats as sstats

from indicators.acceptance import ACCEPTANCE_COLUMNS, add_acceptance, has_acceptance
from indicators.settings import INDICATOR_SETS, AnalysisSettings  # noqa: F401  (INDICATOR_SETS: public here too)

#: The study's three indicators: indicator -> (value column, status column, unit)
PAPER_COLUMNS: dict[str, tuple[str, str, str]] = {
    "t_f": ("t_f_s", "t_f_status", "s"),
    "t_nf": ("t_nf_s", "t_nf_status", "s"),
    "dv_nb": ("dv_nb_mps", "dv_nb_status", "m/s"),
}
#: Every indicator: the study's three, then what the driver accepts.
INDICATOR_COLUMNS: dict[str, tuple[str, str, str]] = {**PAPER_COLUMNS, **ACCEPTANCE_COLUMNS}
INDICATORS: tuple[str, ...] = tuple(INDICATOR_COLUMNS)
PAPER_INDICATORS: tuple[str, ...] = tuple(PAPER_COLUMNS)
#: Driver traits read over the whole drive rather than at the decisions (unit per trait):
#: clustering features, not columns of the decisions table (`indicators.following`).
TRAIT_UNITS: dict[str, str] = {"thw_follow": "s"}
#: Everything a clustering feature can be made of, with its unit.
FEATURE_UNITS: dict[str, str] = {**{k: v[2] for k, v in INDICATOR_COLUMNS.items()}, **TRAIT_UNITS}

CORRELATION_COLUMNS = [
    "driver_id",
    "indicator",
    "n",
    "pearson_r",
    "pearson_p",
    "spearman_rho",
    "spearman_p",
    "significant",
    "reason",
]
FIT_COLUMNS = [
    "driver_id",
    "indicator",
    "A",
    "b",
    "A_se",
    "b_se",
    "A_lo",
    "A_hi",
    "b_lo",
    "b_hi",
    "r2",
    "n",
    "status",
    "reason",
    "cov_Ab",
    "resid_sd",
    "df_resid",
    "v_min",
    "v_max",
    "flag",
    "level",
]


@dataclass(frozen=True)
class LineFit:
    """An OLS line I = A * v + b with what is needed for its confidence and prediction bands."""

    A: float
    b: float
    A_se: float
    b_se: float
    A_lo: float
    A_hi: float
    b_lo: float
    b_hi: float
    r2: float
    n: int
    cov_Ab: float
    resid_sd: float
    df_resid: int
    alpha: float = 0.05

    def bands(self, v: np.ndarray) -> dict[str, np.ndarray]:
        """Mean line, (1 - alpha) confidence band of the mean and prediction band at speeds `v`."""
        v = np.asarray(v, dtype=float)
        mean = self.A * v + self.b
        var_mean = (v**2) * self.A_se**2 + self.b_se**2 + 2 * v * self.cov_Ab
        var_mean = np.maximum(var_mean, 0.0)
        q = sstats.t.ppf(1 - self.alpha / 2, max(self.df_resid, 1))
        ci = q * np.sqrt(var_mean)
        pi = q * np.sqrt(var_mean + self.resid_sd**2)
        return {"mean": mean, "ci_lo": mean - ci, "ci_hi": mean + ci, "pi_lo": mean - pi, "pi_hi": mean + pi}

    @classmethod
    def from_row(cls, row: pd.Series | dict, alpha: float = 0.05) -> "LineFit":
        """Rebuild from a row of the fits table (status 'ok')."""
        return cls(
            **{
                k: row[k]
                for k in (
                    "A",
                    "b",
                    "A_se",
                    "b_se",
                    "A_lo",
                    "A_hi",
                    "b_lo",
                    "b_hi",
                    "r2",
                    "n",
                    "cov_Ab",
                    "resid_sd",
                    "df_resid",
                )
            },
            alpha=alpha,
        )


def fit_line(v: np.ndarray, y: np.ndarray, alpha: float = 0.05) -> LineFit:
    """OLS of y on v with an intercept (statsmodels); needs at least 3 points and speed spread."""
    import statsmodels.api as sm

    v = np.asarray(v, dtype=float)
    y = np.asarray(y, dtype=float)
    X = sm.add_constant(v, has_constant="add")
    res = sm.OLS(y, X).fit()
    ci = res.conf_int(alpha)
    cov = res.cov_params()
    return LineFit(
        A=float(res.params[1]),
        b=float(res.params[0]),
        A_se=float(res.bse[1]),
        b_se=float(res.bse[0]),
        A_lo=float(ci[1, 0]),
        A_hi=float(ci[1, 1]),
        b_lo=float(ci[0, 0]),
        b_hi=float(ci[0, 1]),
        r2=float(res.rsquared),
        n=int(res.nobs),
        cov_Ab=float(cov[0, 1]),
        resid_sd=float(np.sqrt(res.scale)),
        df_resid=int(res.df_resid),
        alpha=alpha,
    )


def fit_reasons(decisions: pd.DataFrame, settings: AnalysisSettings | None = None) -> dict[str, np.ndarray]:
    """Per indicator, why each row's value is left out of fits ('' = used).

    'absent' / 'not_closing' / 'far' come from the status columns; a defined TTC whose
    closing speed is below `min_closing_mps` gets 'following'; a front gap or headway whose
    leader pulls away faster than `max_receding_mps` gets 'receding'.
    """
    settings = settings or AnalysisSettings()
    if not has_acceptance(decisions):
        decisions = add_acceptance(decisions, settings)
    out = {}
    v_e = decisions["ego_v_mps"].to_numpy(dtype=float)
    for ind, (col, status_col, _) in INDICATOR_COLUMNS.items():
        status = decisions[status_col].astype(str).to_numpy(dtype=object)
        y = decisions[col].to_numpy(dtype=float)
        reason = np.where(status == "ok", "", status).astype(object)
        if ind in ("dv_nb", "gap_nb", "thw_nb") and settings.fit_far_followers:
            reason[status == "far"] = ""
        reason[(reason == "") & ~np.isfinite(y)] = "undefined"
        if ind in ("t_f", "t_nf"):
            role = ind[2:]
            other = (
                decisions[f"{role}_v_mps"].to_numpy(dtype=float)
                if f"{role}_v_mps" in decisions
                else np.full(len(y), np.nan)
            )
            with np.errstate(invalid="ignore"):
                slow = (reason == "") & ((v_e - other) < settings.min_closing_mps)
            reason[slow] = "following"
        if ind in ("gap_f", "thw_f") and settings.max_receding_mps is not None and "dv_f_mps" in decisions:
            with np.errstate(invalid="ignore"):
                away = (reason == "") & (decisions["dv_f_mps"].to_numpy(dtype=float) < -settings.max_receding_mps)
            reason[away] = "receding"
        out[ind] = reason
    return out


def indicator_points(
    decisions: pd.DataFrame, settings: AnalysisSettings | None = None, following: pd.DataFrame | None = None
) -> pd.DataFrame:
    """Long table of the presses' indicator values: driver_id, decision_id, indicator, v, y, status, used.

    `status` is the reason a value is not used ('' when used: see `fit_reasons`);
    unused rows are kept so callers can say why a driver has no points. With `following` (the
    drives' steady-following episodes) also one 'thw_follow' row per episode, its id as decision_id.
    """
    settings = settings or AnalysisSettings()
    d = decisions[decisions["label"] == "change"]
    if not settings.fit_cancelled:
        d = d[~d["cancelled"].astype(bool)]
    if not has_acceptance(d):
        d = add_acceptance(d, settings)
    reasons = fit_reasons(d, settings)
    drivers = d["driver_id"].astype(str).to_numpy(dtype=object)
    dec_ids = d["decision_id"].astype(str).to_numpy(dtype=object)
    v = d["ego_v_mps"].to_numpy(dtype=float)
    parts = []
    for ind, (col, _, _) in INDICATOR_COLUMNS.items():
        why = reasons[ind]
        parts.append(
            pd.DataFrame(
                {
                    "driver_id": drivers,
                    "decision_id": dec_ids,
                    "indicator": ind,
                    "v": v,
                    "y": d[col].to_numpy(dtype=float),
                    "status": np.where(why == "", "ok", why),
                    "used": why == "",
                }
            )
        )
    if following is not None and len(following):
        parts.append(following_points(following))
    return pd.concat(parts, ignore_index=True)


def following_points(following: pd.DataFrame) -> pd.DataFrame:
    """Steady-following episodes (`indicators.following`) as rows of `indicator_points`
    (indicator 'thw_follow', one point per episode, `decision_id` = the episode)."""
    if following is None or following.empty:
        return pd.DataFrame(columns=["driver_id", "decision_id", "indicator", "v", "y", "status", "used"])
    return pd.DataFrame(
        {
            "driver_id": following["driver_id"].astype(str).to_numpy(dtype=object),
            "decision_id": following["episode_id"].astype(str).to_numpy(dtype=object),
            "indicator": "thw_follow",
            "v": following["ego_v_mps"].to_numpy(dtype=float),
            "y": following["thw_s"].to_numpy(dtype=float),
            "status": "ok",
            "used": True,
        }
    )


@dataclass(frozen=True)
class Group:
    """The presses of one driver for one indicator, as arrays."""

    driver_id: str
    indicator: str
    v: np.ndarray  # speeds of the usable points [m/s]
    y: np.ndarray  # indicator values of the usable points
    statuses: np.ndarray  # status of every press (usable or not)


def _why_not(g: Group, settings: AnalysisSettings) -> str:
    """Reason a driver/indicator gets no fit, or '' when it can be fitted."""
    if len(g.v) == 0:
        labels, counts = np.unique(g.statuses, return_counts=True)
        detail = ", ".join(f"{n} {s}" for s, n in zip(labels, counts))
        return f"no defined values ({detail})" if detail else "no presses"
    if len(g.v) < settings.min_fit_points:
        return f"too few defined values: {len(g.v)} < {settings.min_fit_points}"
    spread = float(g.v.max() - g.v.min())
    if spread < settings.min_speed_spread_mps:
        return f"no speed spread: {spread:.2f} m/s < {settings.min_speed_spread_mps:g} m/s"
    return ""


def iter_groups(points: pd.DataFrame, drivers: list[str], indicators: tuple[str, ...] = INDICATORS):
    """A `Group` for every driver x indicator (in that order), empty ones included."""
    d_code = pd.Index(drivers).get_indexer(points["driver_id"].astype(str)).astype(np.int64)
    i_code = pd.Index(list(indicators)).get_indexer(points["indicator"]).astype(np.int64)
    key = d_code * len(indicators) + i_code
    key[(d_code < 0) | (i_code < 0)] = -1  # rows of other drivers/indicators sort first, outside every group
    order = np.argsort(key, kind="stable")
    key = key[order]
    v = points["v"].to_numpy(dtype=float)[order]
    y = points["y"].to_numpy(dtype=float)[order]
    used = points["used"].to_numpy(dtype=bool)[order]
    status = points["status"].to_numpy(dtype=object)[order]
    bounds = np.searchsorted(key, np.arange(len(drivers) * len(indicators) + 1), side="left")
    for di, drv in enumerate(drivers):
        for ii, ind in enumerate(indicators):
            k = di * len(indicators) + ii
            sl = slice(bounds[k], bounds[k + 1])
            u = used[sl]
            yield Group(drv, ind, v[sl][u], y[sl][u], status[sl])


def _drivers(decisions: pd.DataFrame) -> list[str]:
    return sorted(decisions["driver_id"].astype(str).unique())


def pearson(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Pearson r and its two-sided p-value (t test with n - 2 df), as scipy's `pearsonr`,
    without its per-call overhead (thousands of drivers). On ranks it is Spearman's rho
    with scipy's `spearmanr` p-value."""
    n = len(x)
    xm, ym = x - x.mean(), y - y.mean()
    denom = np.sqrt((xm @ xm) * (ym @ ym))
    r = float(np.clip((xm @ ym) / denom, -1.0, 1.0)) if denom > 0 else np.nan
    if not np.isfinite(r) or n < 3:
        return r, np.nan
    if abs(r) == 1.0:
        return r, 0.0
    t = r * np.sqrt((n - 2) / (1 - r * r))
    return r, float(2 * special.stdtr(n - 2, -abs(t)))


def ranks(x: np.ndarray) -> np.ndarray:
    """Average ranks (as scipy's `rankdata`), fast when there are no ties."""
    order = np.argsort(x, kind="mergesort")
    if np.all(np.diff(x[order]) != 0):
        r = np.empty(len(x))
        r[order] = np.arange(1, len(x) + 1)
        return r
    return sstats.rankdata(x)


def correlate(
    decisions: pd.DataFrame,
    settings: AnalysisSettings | None = None,
    points: pd.DataFrame | None = None,
    drivers: list[str] | None = None,
    indicators: tuple[str, ...] = INDICATORS,
) -> pd.DataFrame:
    """Pearson and Spearman correlation of each indicator with ego speed, per driver.

    `significant` = Pearson p < alpha (a linear correlation, as the study counts).
    """
    settings = settings or AnalysisSettings()
    points = indicator_points(decisions, settings) if points is None else points
    rows = []
    for g in iter_groups(points, drivers if drivers is not None else _drivers(decisions), indicators):
        reason = _why_not(g, settings)
        row = {
            "driver_id": g.driver_id,
            "indicator": g.indicator,
            "n": int(len(g.v)),
            "pearson_r": np.nan,
            "pearson_p": np.nan,
            "spearman_rho": np.nan,
            "spearman_p": np.nan,
            "significant": False,
            "reason": reason,
        }
        if not reason:
            v, y = g.v, g.y
            if np.ptp(y) == 0:
                row["reason"] = "indicator is constant"
            else:
                r, p = pearson(v, y)
                rho, p_rho = pearson(ranks(v), ranks(y))
                row.update(
                    pearson_r=r, pearson_p=p, spearman_rho=rho, spearman_p=p_rho, significant=bool(p < settings.alpha)
                )
        rows.append(row)
    return pd.DataFrame(rows, columns=CORRELATION_COLUMNS)


def fit_lines(
    decisions: pd.DataFrame,
    settings: AnalysisSettings | None = None,
    points: pd.DataFrame | None = None,
    drivers: list[str] | None = None,
    indicators: tuple[str, ...] = INDICATORS,
) -> pd.DataFrame:
    """`I = A * v_e + b` per driver and indicator, with SEs, CIs, R², n; 'skipped' rows say why.

    `settings.driver_lines`: 'ols' (each driver's own OLS line, the study's way) or 'mixed' (the
    driver's prediction from a mixed model over every driver, `indicators.mixed`: a driver with
    few presses borrows from the others). With 'mixed', a driver needs only
    `indicators.mixed.MIN_MIXED_POINTS` points for a line, which `fit_flag` flags when it rests on
    few; where the mixed model cannot be fitted, OLS stands in."""
    from indicators.mixed import MIN_MIXED_POINTS, mixed_fits

    settings = settings or AnalysisSettings()
    points = indicator_points(decisions, settings) if points is None else points
    groups = list(iter_groups(points, drivers if drivers is not None else _drivers(decisions), indicators))
    mixed: dict[str, dict | None] = {}
    if settings.driver_lines == "mixed":
        for ind in indicators:
            mixed[ind] = mixed_fits(
                [g for g in groups if g.indicator == ind and len(g.v) >= MIN_MIXED_POINTS], settings.alpha
            )
    rows = []
    for g in groups:
        reason = _why_not(g, settings)
        row: dict[str, Any] = {c: np.nan for c in FIT_COLUMNS}
        row.update(
            driver_id=g.driver_id,
            indicator=g.indicator,
            n=int(len(g.v)),
            status="skipped",
            reason=reason,
            df_resid=0,
            flag="",
            level=float(np.median(g.y)) if len(g.y) else np.nan,
        )
        pooled = (mixed.get(g.indicator) or {}).get(g.driver_id)
        if pooled is not None:
            row.update(v_min=float(g.v.min()), v_max=float(g.v.max()), **pooled)
            row.update(status="ok", reason="", flag=fit_flag(LineFit(**pooled, alpha=settings.alpha), settings))
        elif not reason:
            row.update(v_min=float(g.v.min()), v_max=float(g.v.max()))
            fit = fit_line(g.v, g.y, settings.alpha)
            row.update(
                {
                    k: getattr(fit, k)
                    for k in (
                        "A",
                        "b",
                        "A_se",
                        "b_se",
                        "A_lo",
                        "A_hi",
                        "b_lo",
                        "b_hi",
                        "r2",
                        "n",
                        "cov_Ab",
                        "resid_sd",
                        "df_resid",
                    )
                }
            )
            row.update(status="ok", reason="", flag=fit_flag(fit, settings))
        rows.append(row)
    out = pd.DataFrame(rows, columns=FIT_COLUMNS)
    out["n"] = out["n"].astype("int64")
    out["df_resid"] = out["df_resid"].astype("int64")
    return out


def fit_flag(fit: LineFit, settings: AnalysisSettings) -> str:
    """Why a fitted line says little about how the indicator moves with speed ('' when it does)."""
    why = []
    if not fit.r2 >= settings.min_fit_r2:
        why.append(f"R² {fit.r2:.2f} < {settings.min_fit_r2:.2f}")
    if fit.A_lo <= 0 <= fit.A_hi or not np.isfinite(fit.A_lo):
        why.append(f"slope interval [{fit.A_lo:.3g}, {fit.A_hi:.3g}] spans 0")
    if fit.n < settings.min_flag_points:
        why.append(f"only {fit.n} points")
    return "; ".join(why)


def fit_pooled(
    points: pd.DataFrame, drivers: list[str], indicator: str, settings: AnalysisSettings | None = None
) -> tuple[LineFit | None, str]:
    """One OLS line over the presses of several drivers (a style's pooled line), or (None, reason)."""
    settings = settings or AnalysisSettings()
    sel = points[(points["indicator"] == indicator) & points["driver_id"].isin(drivers)]
    used = sel["used"].to_numpy(dtype=bool)
    g = Group(
        "+".join(drivers),
        indicator,
        sel["v"].to_numpy(dtype=float)[used],
        sel["y"].to_numpy(dtype=float)[used],
        sel["status"].to_numpy(dtype=object),
    )
    reason = _why_not(g, settings)
    if reason:
        return None, reason
    return fit_line(g.v, g.y, settings.alpha), ""
