"""A new driver's style from its first K decisions, with how sure that is.

The styles are clustered again on the other drivers alone (the stored analysis's
settings: its feature set, k, seeds), so the new driver places no centre. Its
features come from its K presses as the analysis computes every driver's
(`clustering.features.driver_features`); only the feature speeds its presses
cover (within `SPEED_TOLERANCE_KPH`) are compared, since a line read outside its
own speeds says little. Two measures of uncertainty: the clusterer's posterior
over the compared columns, and a bootstrap over the K decisions (each resample
recomputes the features and assigns them): the share of resamples that give each
style. The bootstrap share of the assigned style is the reported confidence, as
the analysis reports its bootstrap stability.

When the analysis reads styles by the headway drivers keep in steady car following
(`thw_follow`, `indicators.following`), the population's features take its drives'
episodes and the new driver's take the episodes it had driven by its K-th press
(`episodes_by`); the bootstrap resamples its presses and its episodes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from clustering.features import driver_features, transform_features
from clustering.selection import clustering_rows
from clustering.styles import StyleClusterer
from indicators.settings import AnalysisSettings
from indicators.stats import FEATURE_UNITS, TRAIT_UNITS, indicator_points
from laneprint.errors import UserError

#: A feature speed counts as covered when a press was made within this of it [km/h].
SPEED_TOLERANCE_KPH = 5.0


@dataclass
class Population:
    """The other drivers' styles: the clusterer fitted on them and each style's members."""

    clusterer: StyleClusterer
    members: dict[str, list[str]]  # style -> drivers, most defensive style first
    settings: AnalysisSettings


@dataclass(frozen=True)
class StyleEstimate:
    """The style of a driver from a few decisions."""

    style: str  # nearest centre over the compared columns
    confidence: float  # bootstrap share of `style` (the posterior when n_bootstrap = 0)
    posterior: dict[str, float]  # the clusterer's posterior per style
    bootstrap: dict[str, float]  # share of bootstrap resamples per style
    n_decisions: int
    n_bootstrap: int
    compared: list[str] = field(default_factory=list)  # the feature columns compared

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def episodes_by(following: pd.DataFrame | None, rows: pd.DataFrame) -> pd.DataFrame | None:
    """The episodes of `rows`' driver that ended by its last press in each session of `rows`
    (what it had driven by its K-th decision)."""
    if following is None or following.empty or rows.empty:
        return None
    last = rows.groupby(rows["session_id"].astype(str))["press_t_s"].max()
    f = following[following["driver_id"].astype(str).isin(set(rows["driver_id"].astype(str)))]
    ends = f["t_start_s"].to_numpy(dtype=float) + f["duration_s"].to_numpy(dtype=float)
    by = f["session_id"].astype(str).map(last).to_numpy(dtype=float)
    with np.errstate(invalid="ignore"):
        return f[ends <= by]


def fit_population(
    decisions: pd.DataFrame, drivers: list[str], settings: AnalysisSettings, following: pd.DataFrame | None = None
) -> Population:
    """Cluster `drivers` (the population) as the analysis would, with its settings (and its
    drives' steady-following episodes, `following`, for the `thw_follow` feature)."""
    # a new driver's few decisions read indicators; a drive-level parameter (the free speed) is not one
    settings = settings.with_(feature_indicators=tuple(i for i in settings.feature_indicators if i in FEATURE_UNITS))
    dec = decisions[decisions["driver_id"].astype(str).isin(drivers)]
    if following is not None:
        following = following[following["driver_id"].astype(str).isin(drivers)]
    points = indicator_points(dec, settings, following)
    feats, _ = driver_features(points, drivers, settings)
    presses = dec[dec["label"] == "change"].groupby(dec["driver_id"].astype(str))["decision_id"].nunique()
    rows = clustering_rows(feats, presses.reindex(drivers, fill_value=0), settings)
    if len(rows) == 0:
        raise UserError("no other driver has clustering features: the population has no styles")
    Xt = transform_features(feats, settings)
    clf = StyleClusterer(
        k=settings.k,
        choose_k=settings.choose_k,
        k_range=(settings.k_range[0], settings.k_range[1]),
        n_init=settings.n_init,
        random_state=settings.random_state,
    ).fit(Xt.loc[rows])
    usable = feats.index[feats.notna().any(axis=1)]
    labels = clf.predict(Xt.loc[usable])
    members = {name: [str(d) for d, lab in zip(usable, labels) if lab == i] for i, name in enumerate(clf.names_)}
    return Population(clf, members, settings)


def _compared_columns(pop: Population, press_v_mps: np.ndarray) -> list[int]:
    """Indices of the feature columns at speeds the presses cover (the nearest speed when none)."""
    speeds = np.asarray(pop.settings.feature_speeds_kph, dtype=float)
    v_kph = press_v_mps[np.isfinite(press_v_mps)] * 3.6
    if len(v_kph) == 0:
        return list(range(len(pop.clusterer.feature_names_in_)))
    lo, hi = v_kph.min() - SPEED_TOLERANCE_KPH, v_kph.max() + SPEED_TOLERANCE_KPH
    keep = [j for j, s in enumerate(speeds) if lo <= s <= hi]
    if not keep:
        keep = [int(np.argmin(np.abs(speeds - np.median(v_kph))))]
    n = len(speeds)
    return [ii * n + j for ii in range(len(pop.settings.feature_indicators)) for j in keep]


def _posteriors(pop: Population, Xt: pd.DataFrame, cols: list[int]) -> np.ndarray:
    """Posterior over the styles of each row, from the compared columns only."""
    clf = pop.clusterer
    Z = clf.transform(Xt)[:, cols]
    d2 = ((Z[:, None, :] - clf.cluster_centers_[None, :, cols]) ** 2).sum(axis=2)
    logp = -d2 / (2 * clf.sigma2_)
    logp -= logp.max(axis=1, keepdims=True)
    post = np.exp(logp)
    return post / post.sum(axis=1, keepdims=True)


def estimate_style(
    pop: Population, rows: pd.DataFrame, n_bootstrap: int = 200, seed: int = 0, following: pd.DataFrame | None = None
) -> StyleEstimate:
    """The style of the driver whose decisions are `rows` (press and not-yet rows of K decisions);
    `following`: the analysis's episodes (only the driver's, up to its K-th press, are used)."""
    settings = pop.settings
    episodes = episodes_by(following, rows)
    points = indicator_points(
        rows.assign(driver_id="new"), settings, None if episodes is None else episodes.assign(driver_id="new")
    )
    is_press = ~points["indicator"].isin(list(TRAIT_UNITS))  # the rest are following episodes
    dec_ids = np.array(sorted(points.loc[is_press, "decision_id"].unique()), dtype=object)
    ep_ids = np.array(sorted(points.loc[~is_press, "decision_id"].unique()), dtype=object)
    if len(dec_ids) == 0:
        raise UserError("no presses among the decisions given: no style can be assigned")
    feats, _ = driver_features(points, ["new"], settings)
    if feats.isna().all(axis=None):
        raise UserError(
            "the decisions given have no defined value of "
            + "/".join(settings.feature_indicators)
            + ": no style can be assigned"
        )
    press_v = points[is_press].drop_duplicates("decision_id")["v"].to_numpy(dtype=float)
    cols = _compared_columns(pop, press_v)
    names = pop.clusterer.names_
    post = _posteriors(pop, transform_features(feats, settings), cols)[0]
    style = names[int(np.argmax(post))]
    shares = dict.fromkeys(names, 0.0)
    if n_bootstrap > 0:
        rng = np.random.default_rng([seed, 21])
        by_dec = points.set_index("decision_id")
        draws = rng.integers(0, len(dec_ids), (n_bootstrap, len(dec_ids)))
        ep_draws = rng.integers(0, max(len(ep_ids), 1), (n_bootstrap, len(ep_ids)))
        parts = []
        for b, draw in enumerate(draws):
            part = by_dec.loc[np.concatenate([dec_ids[draw], ep_ids[ep_draws[b]]])].reset_index()
            part["driver_id"] = f"b{b}"
            parts.append(part)
        boot_ids = [f"b{b}" for b in range(n_bootstrap)]
        bfeats, _ = driver_features(pd.concat(parts, ignore_index=True), boot_ids, settings)
        picks = _posteriors(pop, transform_features(bfeats, settings), cols).argmax(axis=1)
        counts = np.bincount(picks, minlength=len(names)) / n_bootstrap
        shares = {n: float(c) for n, c in zip(names, counts)}
    return StyleEstimate(
        style=style,
        confidence=shares[style] if n_bootstrap > 0 else float(post.max()),
        posterior={n: float(p) for n, p in zip(names, post)},
        bootstrap=shares,
        n_decisions=len(dec_ids),
        n_bootstrap=n_bootstrap,
        compared=[pop.clusterer.feature_names_in_[c] for c in cols],
    )
