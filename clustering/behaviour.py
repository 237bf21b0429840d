"""Per-driver behaviour parameters: what each driver needs before it goes, estimated from
the presses *and* the states it let pass.

Medians of indicators at the presses mix the traffic a driver met with what it prefers:
a sporty driver meets other gaps and leaders than a calm one. The lane-change literature
reads a driver by its **critical values** instead (Ahmed 1999; Toledo et al. 2003): at every
state of an approach the driver goes when the scene meets all of them, and waits otherwise.
Here, at every decision state `i` of driver `g` (its presses, label 'change', and the
not-yet states before them, label 'keep'),

    P(press_i) = lapse + (hazard - lapse) * prod_j Phi(s_j (ln x_ij - mu_gj) / sigma_j)

- `x_ij` is the state's value of decision variable `j` (`VARIABLES`): the time headway of the
  target-lane follower `thw_nb` and the lead gap `gap_nf` / `t_nf` must be large enough
  (`s_j = +1`: gaps the driver accepts), the time headway or TTC to its own leader `thw_f` /
  `t_f` small enough (`s_j = -1`: how close a leader must come before the driver wants out).
  An undefined value (no such vehicle, a gap not closing) constrains nothing.
- `exp(mu_gj)` is the driver's **critical value** of `j` (in seconds or metres), `sigma_j` the
  spread of the critical value from one state to the next (shared by all drivers: people are
  inconsistent), `hazard` the chance of pressing at a state where everything is met, `lapse`
  the chance of a press nothing explains (a missed or accidental press).
- Partial pooling: every `mu_gj` has a normal prior around the population's `m_j` with
  standard deviation `PRIOR_SD` (log units), so a driver with three presses borrows from the
  others instead of getting a wild value.

The parameters are fitted by penalised maximum likelihood (L-BFGS with the analytic
gradient). Standard errors of each driver's parameters are cluster-robust (a sandwich over its
approaches: the states of one approach are not independent).

The **headway kept while following** (`thw_follow`, `indicators.following`) is read beside
them: the lower quartile of the driver's steady-following headways, its standard error
bootstrapped over episodes. So is the **free speed** (`v_free`): the speed the driver drives
at when nothing holds it back (`indicators.speed.free_speed`), as a share of the posted
limit, the median over its recordings, its standard error bootstrapped over recordings. And so
is the **lane-change rate** (`lc_rate`): the driver's presses per minute of driving, pooled over
its recordings (each press once, whatever its not-yet states), its standard error bootstrapped
over recordings. How often a driver asks to change lanes in the same traffic is a classic mark
of its style; a recording with no press yields no decisions, so the rate is that of the drives
in which the driver pressed at all.

Everything here is pure: frames in, frames and small dataclasses out.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import optimize, special

#: Decision variable -> (decisions column, direction s_j, floor before the log, unit, what it means)
VARIABLES: dict[str, tuple[str, int, float, str, str]] = {
    "thw_nb": ("thw_nb_s", +1, 0.05, "s", "lag gap accepted (time headway of the target lane's follower)"),
    "gap_nf": ("nf_gap_m", +1, 0.5, "m", "lead gap accepted (to the target lane's leader)"),
    "t_nf": ("t_nf_s", +1, 0.05, "s", "TTC to the target lane's leader accepted"),
    "thw_f": ("thw_f_s", -1, 0.05, "s", "time headway to its leader at which it wants out"),
    "t_f": ("t_f_s", -1, 0.05, "s", "TTC to its leader at which it wants out"),
}
#: Parameters read beside the decision variables: name -> (unit, what it means).
DRIVE_PARAMETERS: dict[str, tuple[str, str]] = {
    "thw_follow": ("s", "time headway kept while following a leader"),
    "v_free": ("x limit", "free speed, as a share of the posted limit"),
    "lc_rate": ("/min", "lane-change presses per minute of driving"),
}
#: The behaviour parameters a driver is read by: the critical value of each decision variable
#: and the headway kept while following.
PARAMETERS: tuple[str, ...] = tuple(VARIABLES) + tuple(DRIVE_PARAMETERS)
#: Parameters that measure the room a driver needs (larger = more defensive), for naming styles.
ROOM_PARAMETERS: tuple[str, ...] = ("thw_nb", "gap_nf", "t_nf", "thw_follow")
#: Parameters that read larger = bolder (a faster free speed, more lane changes), for naming styles.
BOLD_PARAMETERS: tuple[str, ...] = ("v_free", "lc_rate")
#: Prefix of a behaviour reading's name (`laneprint analyze --features behaviour:thw_nb+thw_follow`).
BEHAVIOUR = "behaviour:"
#: Standard deviation of the partial-pooling prior of a driver's log critical value.
PRIOR_SD = 1.0
#: Values are capped here before the log (a TTC of an hour says no more than one of 15 min).
_CAP = 1e3
#: Quantile of a driver's following headways read as the headway it keeps (`indicators.following`).
FOLLOW_QUANTILE = 0.25
_FOLLOW_BOOT = 200
_MIN_EPISODES = 3
_MIN_RECORDINGS = 2


def behaviour_params(name: str) -> tuple[str, ...]:
    """('thw_nb', 'thw_follow') of 'behaviour:thw_nb+thw_follow'; ValueError for an unknown parameter."""
    params = tuple(p for p in name[len(BEHAVIOUR) :].split("+") if p)
    unknown = [p for p in params if p not in PARAMETERS]
    if not params or unknown:
        raise ValueError(
            f"unknown behaviour parameter(s) {', '.join(unknown) or '(none)'}: "
            f"use {', '.join(PARAMETERS)} joined by '+'"
        )
    return params


@dataclass(frozen=True)
class DecisionData:
    """The decision states in arrays: log values (NaN = undefined), press labels, groups."""

    z: np.ndarray  # (n, J) log values of the decision variables
    y: np.ndarray  # (n,) 1 at a press, 0 at a not-yet state
    driver: np.ndarray  # (n,) driver ids
    session: np.ndarray  # (n,) session ids
    approach: np.ndarray  # (n,) decision ids (one approach = one press and its not-yet states)
    variables: tuple[str, ...]


def decision_data(decisions: pd.DataFrame, variables: tuple[str, ...] = tuple(VARIABLES)) -> DecisionData:
    """`DecisionData` of a decisions table (`indicators.decisions`, acceptance columns included)."""
    d = decisions[decisions["label"].isin(["change", "keep"])]
    z = np.full((len(d), len(variables)), np.nan)
    for j, var in enumerate(variables):
        col, _, floor, _, _ = VARIABLES[var]
        if col in d:
            x = d[col].to_numpy(dtype=float)
            with np.errstate(invalid="ignore", divide="ignore"):
                z[:, j] = np.where(np.isfinite(x), np.log(np.clip(x, floor, _CAP)), np.nan)
    return DecisionData(
        z=z,
        y=(d["label"] == "change").to_numpy(dtype=float),
        driver=d["driver_id"].astype(str).to_numpy(dtype=object),
        session=d["session_id"].astype(str).to_numpy(dtype=object),
        approach=d["decision_id"].astype(str).to_numpy(dtype=object),
        variables=tuple(variables),
    )


def subset(data: DecisionData, mask: np.ndarray) -> DecisionData:
    """The states of `data` where `mask` holds."""
    return DecisionData(
        data.z[mask], data.y[mask], data.driver[mask], data.session[mask], data.approach[mask], data.variables
    )


@dataclass(frozen=True)
class GapModel:
    """A fitted decision model: one row of log critical values per group (driver or style)."""

    groups: tuple[str, ...]
    mu: np.ndarray  # (G, J) log critical values
    mu_se: np.ndarray  # (G, J) cluster-robust standard errors (the prior's sd where nothing informs)
    sigma: np.ndarray  # (J,)
    m: np.ndarray  # (J,) population means of the log critical values
    hazard: float
    lapse: float
    variables: tuple[str, ...]
    n_presses: np.ndarray  # (G,)
    n_defined: np.ndarray  # (G, J) presses at which each variable is defined

    def probability(self, data: DecisionData, group_of: np.ndarray) -> np.ndarray:
        """P(press) at each state of `data`, the state's driver read by row `group_of[i]` of `mu`."""
        P, _ = _product(data.z, self.mu[group_of], self.sigma, self.variables)
        return self.lapse + (self.hazard - self.lapse) * P

    def log_likelihood(self, data: DecisionData, group_of: np.ndarray) -> np.ndarray:
        """Log-likelihood of each state's label."""
        p = np.clip(self.probability(data, group_of), 1e-12, 1 - 1e-12)
        return np.where(data.y > 0, np.log(p), np.log1p(-p))


def _signs(variables: tuple[str, ...]) -> np.ndarray:
    return np.array([VARIABLES[v][1] for v in variables], dtype=float)


def _product(
    z: np.ndarray, mu: np.ndarray, sigma: np.ndarray, variables: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """(prod_j Phi(u_ij), u) with u = s (z - mu) / sigma; undefined entries contribute 1."""
    u = _signs(variables) * (z - mu) / sigma
    logF = np.where(np.isnan(u), 0.0, special.log_ndtr(np.nan_to_num(u)))
    return np.exp(logF.sum(axis=1)), u


def fit_gap_model(
    data: DecisionData, groups: np.ndarray, prior_sd: float = PRIOR_SD, start: GapModel | None = None
) -> GapModel:
    """Fit one row of critical values per distinct value of `groups` (one per state), with shared
    spreads, hazard and lapse, by penalised maximum likelihood; from `start`'s estimates where it
    has the group (a fit on more data of the same drivers converges in far fewer steps)."""
    names, g = np.unique(groups.astype(str), return_inverse=True)
    G, J = len(names), data.z.shape[1]
    s = _signs(data.variables)
    defined = ~np.isnan(data.z)
    zc = np.nanmedian(np.where(data.y[:, None] > 0, data.z, np.nan), axis=0) if (data.y > 0).any() else np.zeros(J)
    zc = np.where(np.isfinite(zc), zc, 0.0)
    y = data.y

    def unpack(theta: np.ndarray):
        mu = theta[: G * J].reshape(G, J)
        m = theta[G * J : G * J + J]
        log_sigma = theta[G * J + J : G * J + 2 * J]
        a_h, a_l = theta[-2], theta[-1]
        return mu, m, log_sigma, a_h, a_l

    def objective(theta: np.ndarray) -> tuple[float, np.ndarray]:
        mu, m, log_sigma, a_h, a_l = unpack(theta)
        sigma = np.exp(log_sigma)
        h = special.expit(a_h)
        lam = h * special.expit(a_l)
        u = s * (data.z - mu[g]) / sigma
        u0 = np.nan_to_num(u)
        logF = np.where(defined, special.log_ndtr(u0), 0.0)
        P = np.exp(logF.sum(axis=1))
        p = np.clip(lam + (h - lam) * P, 1e-12, 1 - 1e-12)
        ll = np.sum(y * np.log(p) + (1 - y) * np.log1p(-p))
        pen = np.sum((mu - m) ** 2) / (2 * prior_sd**2)
        w = y / p - (1 - y) / (1 - p)  # dLL/dp
        # dP/du = P * phi(u) / Phi(u)
        ratio = np.where(defined, np.exp(-0.5 * u0**2 - 0.5 * np.log(2 * np.pi) - logF), 0.0)
        dll_du = (w * (h - lam) * P)[:, None] * ratio
        d_mu = np.zeros((G, J))
        np.add.at(d_mu, g, dll_du * (-s / sigma))
        d_mu -= (mu - m) / prior_sd**2
        d_m = ((mu - m) / prior_sd**2).sum(axis=0)
        d_logsig = (dll_du * -u0).sum(axis=0)
        dp_dh = P + (1 - P) * special.expit(a_l)  # lam = h * e(a_l)
        d_ah = np.sum(w * dp_dh) * h * (1 - h)
        el = special.expit(a_l)
        d_al = np.sum(w * (1 - P)) * h * el * (1 - el)
        grad = np.concatenate([d_mu.ravel(), d_m, d_logsig, [d_ah, d_al]])
        return -(ll - pen), -grad

    theta0 = np.concatenate([np.tile(zc, G), zc, np.full(J, np.log(0.5)), [special.logit(0.3), special.logit(0.02)]])
    if start is not None and start.variables == data.variables:
        known = {name: i for i, name in enumerate(start.groups)}
        mu0 = np.array([start.mu[known[n]] if n in known else start.m for n in names]).reshape(G, J)
        h0 = min(max(start.hazard, 1e-3), 1 - 1e-3)
        theta0 = np.concatenate(
            [
                mu0.ravel(),
                start.m,
                np.log(np.clip(start.sigma, 0.05, 5.0)),
                [special.logit(h0), special.logit(min(max(start.lapse / h0, 1e-4), 1 - 1e-4))],
            ]
        )
    bounds = [(None, None)] * (G * J + J) + [(np.log(0.05), np.log(5.0))] * J + [(-6, 6), (-8, 4)]
    res = optimize.minimize(objective, theta0, jac=True, method="L-BFGS-B", bounds=bounds, options={"maxiter": 500})
    mu, m, log_sigma, a_h, a_l = unpack(res.x)
    sigma = np.exp(log_sigma)
    h = float(special.expit(a_h))
    lam = float(h * special.expit(a_l))
    presses = np.array([(y[g == k] > 0).sum() for k in range(G)])
    n_def = np.array([(defined[(g == k) & (y > 0)]).sum(axis=0) for k in range(G)]).reshape(G, J)
    se = _robust_se(data, g, G, mu, sigma, h, lam, prior_sd)
    return GapModel(tuple(names), mu, se, sigma, m, h, lam, data.variables, presses, n_def)


def _robust_se(
    data: DecisionData, g: np.ndarray, G: int, mu: np.ndarray, sigma: np.ndarray, h: float, lam: float, prior_sd: float
) -> np.ndarray:
    """Cluster-robust standard errors of each group's log critical values (the other parameters
    held at their estimates): A^-1 B A^-1 with A the Fisher information plus the prior's
    precision, B the outer products of the scores summed per approach."""
    J = mu.shape[1]
    s = _signs(data.variables)
    defined = ~np.isnan(data.z)
    u = s * (data.z - mu[g]) / sigma
    u0 = np.nan_to_num(u)
    logF = np.where(defined, special.log_ndtr(u0), 0.0)
    P = np.exp(logF.sum(axis=1))
    p = np.clip(lam + (h - lam) * P, 1e-9, 1 - 1e-9)
    ratio = np.where(defined, np.exp(-0.5 * u0**2 - 0.5 * np.log(2 * np.pi) - logF), 0.0)
    dp_dmu = ((h - lam) * P)[:, None] * ratio * (-s / sigma)  # (n, J)
    score = ((data.y - p) / (p * (1 - p)))[:, None] * dp_dmu
    fisher_w = 1.0 / (p * (1 - p))
    se = np.full((G, J), prior_sd)
    for k in range(G):
        rows = g == k
        if not rows.any():
            continue
        D = dp_dmu[rows]
        A = (D * fisher_w[rows, None]).T @ D + np.eye(J) / prior_sd**2
        sc = pd.DataFrame(score[rows]).groupby(data.approach[rows]).sum().to_numpy()
        B = sc.T @ sc
        try:
            Ainv = np.linalg.inv(A)
        except np.linalg.LinAlgError:
            continue
        V = Ainv @ B @ Ainv
        # never below what the prior alone would leave unexplained by the data: at least the Fisher SE
        se[k] = np.sqrt(np.maximum(np.diag(V), np.diag(Ainv)))
    return se


def following_parameter(
    following: pd.DataFrame | None, drivers: list[str], seed: int = 0
) -> tuple[pd.Series, pd.Series, pd.Series]:
    """(log headway kept while following, its bootstrap SE, episodes) per driver; NaN with fewer
    than `_MIN_EPISODES` episodes."""
    value = pd.Series(np.nan, index=drivers, dtype=float)
    se = pd.Series(np.nan, index=drivers, dtype=float)
    count = pd.Series(0, index=drivers, dtype=int)
    if following is None or following.empty:
        return value, se, count
    rng = np.random.default_rng(seed)
    for drv, grp in following.groupby(following["driver_id"].astype(str)):
        if drv not in value.index:
            continue
        x = np.log(np.clip(grp["thw_s"].to_numpy(dtype=float), 0.05, _CAP))
        x = x[np.isfinite(x)]
        count[drv] = len(x)
        if len(x) < _MIN_EPISODES:
            continue
        value[drv] = float(np.quantile(x, FOLLOW_QUANTILE))
        boots = np.quantile(x[rng.integers(0, len(x), (_FOLLOW_BOOT, len(x)))], FOLLOW_QUANTILE, axis=1)
        se[drv] = float(max(np.std(boots), 1e-3))
    return value, se, count


def free_speed_parameter(
    decisions: pd.DataFrame, drivers: list[str], seed: int = 0
) -> tuple[pd.Series, pd.Series, pd.Series]:
    """(log free speed over the posted limit, its bootstrap SE over recordings, recordings) per
    driver: the median over the driver's recordings. NaN with fewer than `_MIN_RECORDINGS`
    recordings, and for every driver when a recording has no posted limit."""
    if "ego_v_free_mps" not in decisions or decisions.empty:
        return _no_values(drivers)  # decisions extracted before the free speed was
    per_rec = decisions.groupby("recording_id", sort=True).agg(
        driver_id=("driver_id", "first"), v=("ego_v_free_mps", "first"), limit=("speed_limit_kph", "first")
    )
    limit = per_rec["limit"].to_numpy(dtype=float) / 3.6
    v = per_rec["v"].to_numpy(dtype=float)
    if not np.all(np.isfinite(limit) & (limit > 0)):
        return _no_values(drivers)
    with np.errstate(invalid="ignore", divide="ignore"):
        x = np.log(v / limit)
    per_rec = per_rec.assign(x=x)[np.isfinite(x)]
    return _over_recordings(per_rec, drivers, lambda g, idx: np.median(g["x"].to_numpy(dtype=float)[idx], axis=1), seed)


def change_rate_parameter(
    decisions: pd.DataFrame, drivers: list[str], seed: int = 0
) -> tuple[pd.Series, pd.Series, pd.Series]:
    """(log presses per minute of driving, its bootstrap SE over recordings, recordings) per driver,
    pooled over its recordings. NaN with fewer than `_MIN_RECORDINGS` recordings, and for every
    driver when the decisions carry no drive time (extracted before they did)."""
    if "drive_s" not in decisions or decisions.empty:
        return _no_values(drivers)
    presses = decisions[decisions["label"] == "change"].groupby("recording_id")["decision_id"].nunique()
    per_rec = decisions.groupby("recording_id", sort=True).agg(
        driver_id=("driver_id", "first"), minutes=("drive_s", "first")
    )
    per_rec = per_rec.assign(presses=presses.reindex(per_rec.index).fillna(0), minutes=per_rec["minutes"] / 60.0)
    per_rec = per_rec[np.isfinite(per_rec["minutes"]) & (per_rec["minutes"] > 0)]
    per_rec = per_rec[per_rec.groupby("driver_id")["presses"].transform("sum") > 0]  # a rate of 0 has no log

    def rate(g: pd.DataFrame, idx: np.ndarray) -> np.ndarray:
        n, t = g["presses"].to_numpy(dtype=float), g["minutes"].to_numpy(dtype=float)
        return np.log(np.maximum(n[idx].sum(axis=1), 0.5) / t[idx].sum(axis=1))  # a draw of no press: half of one

    return _over_recordings(per_rec, drivers, rate, seed)


def _no_values(drivers: list[str]) -> tuple[pd.Series, pd.Series, pd.Series]:
    """(value, SE, count) of a drive parameter no driver has."""
    nan = pd.Series(np.nan, index=drivers, dtype=float)
    return nan, nan.copy(), pd.Series(0, index=drivers, dtype=int)


def _over_recordings(
    per_rec: pd.DataFrame,
    drivers: list[str],
    estimate: Callable[[pd.DataFrame, np.ndarray], np.ndarray],
    seed: int,
) -> tuple[pd.Series, pd.Series, pd.Series]:
    """(value, bootstrap SE over recordings, recordings) per driver from one row per recording:
    `estimate(rows, idx)` is the value of the driver's recordings drawn in each row of `idx`
    (draws x recordings). NaN with fewer than `_MIN_RECORDINGS` recordings."""
    value, se, count = _no_values(drivers)
    rng = np.random.default_rng(seed)
    for drv, grp in per_rec.groupby(per_rec["driver_id"].astype(str)):
        if drv not in value.index:
            continue
        m = len(grp)
        count[drv] = m
        if m < _MIN_RECORDINGS:
            continue
        value[drv] = float(estimate(grp, np.arange(m)[None, :])[0])
        se[drv] = float(max(np.std(estimate(grp, rng.integers(0, m, (_FOLLOW_BOOT, m)))), 1e-3))
    return value, se, count


@dataclass(frozen=True)
class Behaviour:
    """Every driver's behaviour parameters (log units) with standard errors."""

    values: pd.DataFrame  # driver x PARAMETERS, log critical values / log headway
    se: pd.DataFrame  # same shape
    presses: pd.Series  # presses per driver
    defined: pd.DataFrame  # driver x PARAMETERS: presses (episodes for thw_follow, recordings for
    # v_free and lc_rate) that inform each
    model: GapModel | None

    def in_units(self) -> pd.DataFrame:
        """The parameters in seconds and metres."""
        return np.exp(self.values)


def driver_behaviour(
    decisions: pd.DataFrame, following: pd.DataFrame | None, drivers: list[str], seed: int = 0
) -> Behaviour:
    """Each driver's critical values (`fit_gap_model` with one group per driver) and the headway
    it keeps while following."""
    cols = list(PARAMETERS)
    values = pd.DataFrame(np.nan, index=pd.Index(drivers, name="driver_id"), columns=cols)
    se = values.copy()
    defined = pd.DataFrame(0, index=values.index, columns=cols)
    presses = pd.Series(0, index=values.index, dtype=int)
    model = None
    data = decision_data(decisions)
    keep = np.isin(data.driver, drivers)
    data = subset(data, keep)
    # a critical gap lies between the gaps taken and the gaps let pass: with no not-yet state in the
    # table nothing places it (a driver with few pools with the others), and the critical values stay NaN
    if (data.y > 0).any() and (data.y == 0).any():
        model = fit_gap_model(data, data.driver)
        for k, drv in enumerate(model.groups):
            values.loc[drv, list(VARIABLES)] = model.mu[k]
            se.loc[drv, list(VARIABLES)] = model.mu_se[k]
            defined.loc[drv, list(VARIABLES)] = model.n_defined[k]
            presses[drv] = int(model.n_presses[k])
    follow, follow_se, episodes = following_parameter(following, drivers, seed)
    values["thw_follow"] = follow
    se["thw_follow"] = follow_se
    defined["thw_follow"] = episodes
    free, free_se, recordings = free_speed_parameter(decisions, drivers, seed)
    values["v_free"] = free
    se["v_free"] = free_se
    defined["v_free"] = recordings
    rate, rate_se, rated = change_rate_parameter(decisions, drivers, seed)
    values["lc_rate"] = rate
    se["lc_rate"] = rate_se
    defined["lc_rate"] = rated
    return Behaviour(values, se, presses, defined, model)
