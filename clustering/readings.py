"""Which reading of the drivers to trust, chosen by what styles are for: predicting decisions.

A **reading** is a set of behaviour parameters (`clustering.behaviour.PARAMETERS`) the drivers
are clustered on. A reading is good when each style's decision model (`fit_gap_model` with one
row of critical values per style) predicts its members' decisions in sessions it was not
fitted on. For every candidate reading the drivers are clustered once; then, with the sessions
cut into folds (each driver's sessions dealt round-robin), the style models are fitted on the
other folds and score the held-out fold's presses and not-yet states by their log-likelihood.
The reading with the highest held-out log-likelihood is chosen; no reading is favoured by a
hand-set margin. Readings whose score is within `NOISE_SE` standard errors of the best
(paired over approaches) are the **plausible** ones: a driver whose style differs among them
is unsure, and says so.

`reading_confidence` then carries both kinds of doubt into each driver's confidence: the
uncertainty of its own parameters (its estimates drawn from their standard errors, assigned to
the style centres) and that of the reading (the share of plausible readings that agree).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
import pandas as pd

from clustering.behaviour import PARAMETERS, Behaviour, DecisionData, GapModel, fit_gap_model, subset
from clustering.styles import StyleClusterer

#: Held-out folds of each driver's sessions.
FOLDS = 4
#: Readings within this many standard errors of the best held-out score are plausible.
NOISE_SE = 1.0
#: Draws of each driver's parameters from their standard errors, for its confidence.
CONFIDENCE_DRAWS = 400
#: A parameter whose estimate is missing (no state informs it) for more than this share of
#: the drivers is not used in a reading.
MAX_MISSING = 0.5


def candidate_readings(params: tuple[str, ...] = PARAMETERS, max_size: int = 3) -> dict[str, tuple[str, ...]]:
    """Every set of up to `max_size` behaviour parameters, named by its members ('thw_nb+thw_follow')."""
    out = {}
    for size in range(1, max_size + 1):
        for combo in combinations(params, size):
            out["+".join(combo)] = combo
    return out


@dataclass(frozen=True)
class ReadingScore:
    """How well the styles of one reading predict held-out decisions."""

    name: str
    parameters: tuple[str, ...]
    heldout_ll: float  # summed over held-out states
    per_state: float  # mean per held-out state
    se: float  # standard error of the difference to the best reading (paired over approaches)
    plausible: bool
    chosen: bool
    labels: dict[str, str] = field(default_factory=dict)  # driver -> style
    reliability: float = float("nan")  # the least reliable of its parameters (`parameter_reliability`)
    silhouette: float = float("nan")  # of its styles, in its standardised space
    stability: float = float("nan")  # mean share of each driver's redraws (or resamples) left in its style
    unread: tuple[str, ...] = ()  # drivers in `labels` only by imputation (a parameter of the reading missing)

    def reads(self, driver: str) -> bool:
        """Whether the reading places `driver` from its estimates (labelled, and not by imputation)."""
        return driver in self.labels and driver not in self.unread


def session_folds(driver: np.ndarray, session: np.ndarray, n_folds: int = FOLDS) -> np.ndarray:
    """Fold of every row: each driver's sessions, sorted, dealt round-robin into folds."""
    fold = np.zeros(len(driver), dtype=int)
    for drv in np.unique(driver):
        rows = driver == drv
        sessions = sorted(set(session[rows]))
        k = min(n_folds, len(sessions))
        index = {s: i % k for i, s in enumerate(sessions)}
        fold[rows] = [index[s] for s in session[rows]]
    return fold


def following_heldout(
    following: pd.DataFrame | None, labels: dict[str, str], drivers: list[str], n_folds: int = FOLDS
) -> tuple[np.ndarray, np.ndarray]:
    """Held-out log-likelihood of every steady-following episode's log headway under its driver's
    style (a normal with the style's mean and the pooled spread, both from the other folds), and
    the episodes' session ids (the unit of the paired comparison). One entry per episode of
    `drivers`, NaN for drivers without a label."""
    if following is None or following.empty:
        return np.zeros(0), np.zeros(0, dtype=object)
    f = following[following["driver_id"].astype(str).isin(list(drivers))]
    if f.empty:
        return np.zeros(0), np.zeros(0, dtype=object)
    driver = f["driver_id"].astype(str).to_numpy(dtype=object)
    session = f["session_id"].astype(str).to_numpy(dtype=object)
    x = np.log(np.clip(f["thw_s"].to_numpy(dtype=float), 0.05, 1e3))
    style = np.array([labels.get(d, "") for d in driver], dtype=object)
    folds = session_folds(driver, session, n_folds)
    out = np.full(len(x), np.nan)
    for k in np.unique(folds):
        train, test = (folds != k) & (style != ""), (folds == k) & (style != "")
        if train.sum() < 3:
            continue
        means = pd.Series(x[train]).groupby(style[train]).mean()
        resid = x[train] - means.reindex(style[train]).to_numpy()
        sd = max(float(np.std(resid)), 0.05)
        mu = means.reindex(style[test]).to_numpy()
        out[test] = -0.5 * ((x[test] - mu) / sd) ** 2 - np.log(sd) - 0.5 * np.log(2 * np.pi)
    return out, session


@dataclass(frozen=True)
class FoldModels:
    """Per-driver decision models fitted on all folds but one, one per held-out fold."""

    folds: np.ndarray  # fold of every state
    models: dict[int, GapModel]


def fold_models(data: DecisionData, n_folds: int = FOLDS, start: GapModel | None = None) -> FoldModels:
    """Fit the per-driver model once per held-out fold (the expensive part, shared by every reading),
    each from `start` (the fit on every fold)."""
    folds = session_folds(data.driver, data.session, n_folds)
    models = {}
    for f in np.unique(folds):
        train = folds != f
        if (data.y[train] > 0).any():
            models[int(f)] = fit_gap_model(subset(data, train), data.driver[train], start=start)
    return FoldModels(folds, models)


def heldout_loglik(data: DecisionData, labels: dict[str, str], fm: FoldModels) -> np.ndarray:
    """Held-out log-likelihood of every state under its style's model, the driver's own data left out
    twice: the state's session is held out (the models of the other folds), and the style's critical
    values are those of its *other* members, pooled by their precision (the population's for a
    driver alone in its style). So a grouping scores well when each driver decides like the others
    of its style. NaN for states of drivers without a label or a fitted model."""
    out = np.full(len(data.y), np.nan)
    for f, model in fm.models.items():
        test = (fm.folds == f) & np.isin(data.driver, list(labels))
        if not test.any():
            continue
        index = {g: i for i, g in enumerate(model.groups)}
        drivers = [d for d in labels if d in index]
        mu = np.zeros((len(drivers), model.mu.shape[1]))
        for di, d in enumerate(drivers):
            rows = [index[o] for o in drivers if o != d and labels[o] == labels[d]]
            if rows:
                w = 1.0 / np.maximum(model.mu_se[rows], 1e-3) ** 2
                mu[di] = (w * model.mu[rows]).sum(axis=0) / w.sum(axis=0)
            else:
                mu[di] = model.m
        pos = {d: i for i, d in enumerate(drivers)}
        of = np.array([pos.get(d, -1) for d in data.driver[test]])
        ll = np.full(len(of), np.nan)
        ok = of >= 0
        if ok.any():
            pooled = GapModel(
                tuple(drivers),
                mu,
                mu,
                model.sigma,
                model.m,
                model.hazard,
                model.lapse,
                model.variables,
                model.n_presses,
                model.n_defined,
            )
            ll[ok] = pooled.log_likelihood(subset(subset(data, test), ok), of[ok])
        out[np.flatnonzero(test)] = ll
    return out


def cluster_reading(
    behaviour: Behaviour, params: tuple[str, ...], fit_on: list[str], k: int, n_init: int, random_state: int
) -> StyleClusterer:
    """Styles of the drivers `fit_on` read by `params` (k-means on robustly standardised log values),
    named by the centres' mean standardised value (every parameter reads larger = more cautious:
    larger gaps accepted, a leader left further away, a longer headway kept)."""
    X = behaviour.values.loc[fit_on, list(params)]
    return StyleClusterer(k=k, n_init=n_init, random_state=random_state, room=list(params)).fit(X)


def usable_parameters(behaviour: Behaviour, drivers: list[str]) -> tuple[str, ...]:
    """Parameters estimated (informed by the data, and a value given) for most of `drivers`: the headway
    kept while following is counted from one episode but valued only from a few, so
    a driver can have episodes and no value."""
    informed = (behaviour.defined.loc[drivers] > 0) & behaviour.values.loc[drivers].notna()
    return tuple(p for p in PARAMETERS if informed[p].mean() >= 1 - MAX_MISSING)


def parameter_reliability(behaviour: Behaviour, drivers: list[str]) -> pd.Series:
    """Per parameter, the share of its spread between `drivers` that is not estimation noise:
    1 - mean(SE^2) / var(estimates) on the log scale (classical test theory's reliability).
    Near 1: the drivers really differ in it; at or below 0: the differences are noise. NaN for a
    parameter estimated for fewer than 3 of the drivers."""
    out = {}
    for p in PARAMETERS:
        x = behaviour.values.loc[drivers, p].to_numpy(dtype=float)
        se = behaviour.se.loc[drivers, p].to_numpy(dtype=float)
        informed = (behaviour.defined.loc[drivers, p] > 0).to_numpy() & np.isfinite(x) & np.isfinite(se)
        if informed.sum() < 3 or x[informed].var(ddof=1) <= 0:
            out[p] = np.nan
            continue
        out[p] = 1.0 - float(np.mean(se[informed] ** 2)) / float(x[informed].var(ddof=1))
    return pd.Series(out, name="reliability")


def most_reliable(behaviour: Behaviour, drivers: list[str], size: int) -> tuple[str, ...]:
    """The `size` usable parameters of highest reliability (those above 0 only), most reliable first."""
    rel = parameter_reliability(behaviour, drivers)
    usable = set(usable_parameters(behaviour, drivers))
    ranked = [p for p in rel.sort_values(ascending=False).index if p in usable and rel[p] > 0]
    return tuple(ranked[:size])


def choose_reading(
    behaviour: Behaviour,
    data: DecisionData,
    fit_on: list[str],
    k: int,
    n_init: int = 20,
    random_state: int = 0,
    candidates: dict[str, tuple[str, ...]] | None = None,
    following: pd.DataFrame | None = None,
    extra: dict[str, tuple[tuple[str, ...], dict[str, str]]] | None = None,
) -> tuple[str, list[ReadingScore], dict[str, StyleClusterer]]:
    """The reading whose styles best predict held-out behaviour (decisions and, with `following`,
    the headways kept while following), every candidate's score, and the fitted clusterer of each.

    `extra`: groupings made elsewhere (name -> (what they read, driver -> style)), scored alike.
    """
    usable = set(usable_parameters(behaviour, fit_on))
    candidates = candidates or candidate_readings()
    candidates = {n: p for n, p in candidates.items() if set(p) <= usable}
    groupings: dict[str, dict[str, str]] = {}
    fm = fold_models(data, start=behaviour.model)
    scored: dict[str, tuple[np.ndarray, dict[str, str]]] = {}
    clusterers: dict[str, StyleClusterer] = {}
    rows = behaviour.values.index.isin(fit_on)
    for name, params in candidates.items():
        if len(fit_on) <= k:
            break
        clf = cluster_reading(behaviour, params, fit_on, k, n_init, random_state)
        groupings[name] = dict(zip(behaviour.values.index[rows], (clf.names_[i] for i in clf.labels_)))
        clusterers[name] = clf
    for name, (params, labels) in (extra or {}).items():
        candidates[name] = params
        groupings[name] = {d: lab for d, lab in labels.items() if d in set(fit_on)}
    follow_unit = np.zeros(0, dtype=object)
    for name, labels in groupings.items():
        follow_ll, follow_unit = following_heldout(following, labels, fit_on)
        scored[name] = (np.concatenate([heldout_loglik(data, labels, fm), follow_ll]), labels)
    if not scored:
        return "", [], {}
    # compare on the states every reading scored
    both = np.all([np.isfinite(ll) for ll, _ in scored.values()], axis=0)
    totals = {n: float(ll[both].sum()) for n, (ll, _) in scored.items()}
    best = max(totals, key=lambda n: (totals[n], -len(candidates[n])))
    units = np.concatenate([data.approach, follow_unit])
    approach = units[both]
    out = []
    for name, (ll, labels) in scored.items():
        diff = pd.Series(scored[best][0][both] - ll[both]).groupby(approach).sum()
        se = float(np.sqrt(len(diff)) * diff.std(ddof=1)) if len(diff) > 1 else 0.0
        plausible = name == best or (totals[best] - totals[name]) <= NOISE_SE * se
        out.append(
            ReadingScore(
                name,
                candidates[name],
                totals[name],
                totals[name] / max(int(both.sum()), 1),
                se,
                bool(plausible),
                name == best,
                labels,
            )
        )
    out.sort(key=lambda r: -r.heldout_ll)
    return best, out, clusterers


def draw_confidence(
    behaviour: Behaviour,
    drivers: list[str],
    clf: StyleClusterer,
    labels: np.ndarray,
    random_state: int = 0,
    draws: int = CONFIDENCE_DRAWS,
) -> np.ndarray:
    """Share of draws of each driver's parameters (normal around the estimate, its standard error)
    that the clusterer assigns to the driver's own style."""
    rng = np.random.default_rng(random_state)
    cols = clf.feature_names_in_
    mean = behaviour.values.loc[drivers, cols].to_numpy(dtype=float)
    se = behaviour.se.loc[drivers, cols].to_numpy(dtype=float)
    se = np.where(np.isfinite(se), se, 0.0)
    sample = mean[None] + rng.standard_normal((draws,) + mean.shape) * se[None]
    flat = pd.DataFrame(sample.reshape(-1, len(cols)), columns=cols)
    pred = clf.predict(flat).reshape(draws, len(drivers))
    return (pred == np.asarray(labels)[None, :]).mean(axis=0)
