"""Per-driver indicator lines by partial pooling: a linear mixed model over all drivers.

`I = (A + a_d) v_e + (b + b_d) + e`, with a random intercept and slope `(b_d, a_d)` per driver
(statsmodels `MixedLM`, REML), speed centred at the drivers' mean for a stable fit. A driver's
line is its best linear unbiased prediction: with many presses close to its own OLS line, with a
few pulled towards the population's line instead of being a meaningless OLS fit. Its standard
errors are those of the prediction error (the conditional covariance of the driver's random
effects given its data, plus the fixed effects' covariance), so a driver with three presses gets
a wide interval, and `indicators.stats.fit_flag` flags it as for OLS.

statsmodels stays inside this module: `mixed_fits` returns rows of `indicators.stats.FIT_COLUMNS`.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from scipy import stats as sstats

#: A driver needs at least this many points to enter the mixed model (one point pins no line).
MIN_MIXED_POINTS = 2


def mixed_fits(groups: list, alpha: float = 0.05) -> dict[str, dict[str, float]] | None:
    """Per driver (of `groups`: `indicators.stats.Group` of one indicator) the fields of a
    `LineFit` from the mixed model, or None when the model cannot be fitted (fewer than two
    drivers with points, or no convergence)."""
    import statsmodels.formula.api as smf

    usable = [g for g in groups if len(g.v) >= MIN_MIXED_POINTS]
    if len(usable) < 2:
        return None
    df = pd.DataFrame(
        {
            "driver": np.concatenate([[g.driver_id] * len(g.v) for g in usable]),
            "v": np.concatenate([g.v for g in usable]),
            "y": np.concatenate([g.y for g in usable]),
        }
    )
    v0 = float(df["v"].mean())
    df["vc"] = df["v"] - v0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            res = smf.mixedlm("y ~ vc", df, groups=df["driver"], re_formula="~vc").fit(reml=True)
        except (ValueError, np.linalg.LinAlgError):
            return None
    if not np.all(np.isfinite(res.fe_params)):
        return None
    fe = res.fe_params.to_numpy()  # (intercept at v0, slope)
    fe_cov = res.cov_params().iloc[:2, :2].to_numpy()
    psi = np.asarray(res.cov_re, dtype=float)
    sigma2 = float(res.scale)
    try:
        psi_inv = np.linalg.pinv(psi)
    except np.linalg.LinAlgError:
        return None
    blups = res.random_effects
    z = sstats.norm.ppf(1 - alpha / 2)
    out = {}
    for g in usable:
        u = np.asarray(blups[g.driver_id], dtype=float)
        Z = np.column_stack([np.ones(len(g.v)), g.v - v0])
        cond = np.linalg.pinv(Z.T @ Z / sigma2 + psi_inv)  # conditional covariance of the driver's effects
        cov = cond + fe_cov
        b0, A = fe[0] + u[0], fe[1] + u[1]
        b = b0 - A * v0
        A_se = float(np.sqrt(max(cov[1, 1], 0.0)))
        var_b = cov[0, 0] + v0**2 * cov[1, 1] - 2 * v0 * cov[0, 1]
        b_se = float(np.sqrt(max(var_b, 0.0)))
        pred = A * g.v + b
        ss_tot = float(((g.y - g.y.mean()) ** 2).sum())
        r2 = 1 - float(((g.y - pred) ** 2).sum()) / ss_tot if ss_tot > 0 else 0.0
        out[g.driver_id] = {
            "A": float(A),
            "b": float(b),
            "A_se": A_se,
            "b_se": b_se,
            "A_lo": float(A - z * A_se),
            "A_hi": float(A + z * A_se),
            "b_lo": float(b - z * b_se),
            "b_hi": float(b + z * b_se),
            "r2": float(r2),
            "n": int(len(g.v)),
            "cov_Ab": float(cov[1, 0] - v0 * cov[1, 1]),
            "resid_sd": float(np.sqrt(sigma2)),
            "df_resid": int(max(len(g.v) - 2, 0)),
        }
    return out
