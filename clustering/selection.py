"""Which indicators to read drivers by: feature sets compared on the data at hand.

For each candidate set (`indicators.settings.INDICATOR_SETS`), the drivers are
clustered on that set's features and the styles are scored by

- **separation**: the mean silhouette of the drivers in the standardised feature
  space (-1 .. 1; 0 when k is 1 or every driver is its own style), and
- **stability**: the mean, over drivers, of the share of bootstrap resamples of the
  driver's own decisions that leave it in its style (`clustering.confidence`;
  1/k = a coin toss, 1 = its decisions leave no doubt).

The score is their product (a set must be both separated and stable; either one alone
is easy to win: one feature of pure noise can separate well, a single uninformative
style is perfectly stable). A set with more than `MAX_IMPUTED` of its drivers'
features undefined (imputed) is not scored; above `bootstrap_max_drivers` drivers the
score is the silhouette alone (the bootstrap would cost minutes). 'auto' picks the highest score; ties go to the earlier set
in `AUTO_CANDIDATES` (the study's TTCs first).

'auto' leaves out a set that does not read the drivers' decisions: one whose sparsest press
indicator is defined at fewer presses of the median driver than a fit takes
(`min_fit_points`; the TTCs where leaders are seldom closing). Such a driver's value rests on
one or two presses, and the set's silhouette can be as high as a real reading's by chance:
measured on SUMO acceptance study 602, `ttc` (t_nf at 2 presses of the median driver) scored
0.496 against `following`'s 0.507, kept by the margin it gave ARI -0.03 against 1.0. Such a set
is still measured and shown (`presses_read`), and `--features NAME` takes it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd
from sklearn.metrics import silhouette_score

from clustering.confidence import bootstrap_stability
from clustering.features import driver_features, transform_features
from clustering.styles import StyleClusterer
from indicators.settings import AUTO_CANDIDATES, CHOSEN_BY_DATA, INDICATOR_SETS, AnalysisSettings
from indicators.stats import FEATURE_UNITS, TRAIT_UNITS
from laneprint.errors import SettingError

#: A set whose drivers' features are mostly undefined (imputed) is not a reading of them: not scored.
MAX_IMPUTED = 0.5
#: Bootstrap resamples for a set's stability: a coarse share is enough to compare sets.
SELECTION_BOOTSTRAP = 30


@dataclass(frozen=True)
class FeatureSetScore:
    """How well one feature set separates the drivers into stable styles."""

    name: str
    indicators: tuple[str, ...]
    k: int
    silhouette: float
    stability: float
    score: float
    imputed: float  # share of the drivers' features with no defined value (imputed)
    presses_read: float = np.inf  # the median driver's defined values of the set's sparsest press indicator

    def to_dict(self) -> dict:
        d = asdict(self)
        d["indicators"] = list(self.indicators)
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in d.items()}


def resolve_features(spec: str) -> tuple[str, tuple[str, ...]]:
    """(name, indicators) of a `--features` value: a set name or a comma-separated list of
    indicators ('auto' is resolved by `choose_features`). Raises `UserError` when unknown."""
    if spec in INDICATOR_SETS:
        return spec, INDICATOR_SETS[spec]
    if spec in CHOSEN_BY_DATA:
        return spec, ()
    if spec.startswith("behaviour:"):
        from clustering.behaviour import behaviour_params

        try:
            return spec, behaviour_params(spec)
        except ValueError as exc:
            raise SettingError(f"{{0}} {spec!r}: {exc}", "features") from None
    names = tuple(s.strip() for s in spec.split(",") if s.strip())
    unknown = [n for n in names if n not in FEATURE_UNITS]
    if not names or unknown:
        raise SettingError(
            f"{{0}} {spec!r}: use auto, heldout, behaviour, behaviour:<parameters>, "
            f"{', '.join(INDICATOR_SETS)} or a comma-separated list of indicators "
            f"({', '.join(FEATURE_UNITS)})",
            "features",
        )
    return ",".join(names), names


def clustering_rows(feats: pd.DataFrame, n_dec: pd.Series, settings: AnalysisSettings) -> pd.Index:
    """The drivers that place the cluster centres: some feature defined and enough presses
    (whoever has features when nobody has enough presses)."""
    usable = feats.notna().any(axis=1)
    enough = n_dec.reindex(feats.index).fillna(0) >= settings.min_cluster_decisions
    rows = feats.index[usable & enough]
    return rows if len(rows) else feats.index[usable]


def presses_read(points: pd.DataFrame, drivers: list[str], indicators: tuple[str, ...]) -> float:
    """At how many presses the median driver has a defined value of the sparsest of `indicators`
    (indicators not read at presses, thw_follow, do not count; inf when none is)."""
    counts = [
        float(
            points[(points["indicator"] == ind) & points["used"]]
            .groupby("driver_id")
            .size()
            .reindex(drivers, fill_value=0)
            .median()
        )
        for ind in indicators
        if ind not in TRAIT_UNITS
    ]
    return min(counts, default=np.inf)


def score_feature_set(
    points: pd.DataFrame,
    drivers: list[str],
    n_dec: pd.Series,
    settings: AnalysisSettings,
    name: str,
    indicators: tuple[str, ...],
) -> FeatureSetScore:
    """Cluster the drivers on `indicators` and measure separation and stability."""
    s = settings.with_(feature_indicators=tuple(indicators))
    feats, _ = driver_features(points, drivers, s)
    rows = clustering_rows(feats, n_dec, s)
    imputed = float(feats.loc[rows].isna().to_numpy().mean()) if len(rows) else 1.0
    read = presses_read(points, drivers, tuple(indicators))
    if len(rows) < 2 or imputed > MAX_IMPUTED:
        return FeatureSetScore(name, tuple(indicators), len(rows), np.nan, np.nan, -np.inf, imputed, read)
    Xt = transform_features(feats, s).loc[rows]
    clf = StyleClusterer(
        k=s.k, choose_k=s.choose_k, k_range=s.k_range, n_init=s.n_init, random_state=s.random_state
    ).fit(Xt)
    labels = clf.labels_
    n_labels = len(set(labels.tolist()))
    sil = float(silhouette_score(clf.transform(Xt), labels)) if 2 <= n_labels <= len(rows) - 1 else 0.0
    if len(rows) > s.bootstrap_max_drivers:  # as the styles' own confidence: too costly, separation alone
        return FeatureSetScore(name, tuple(indicators), clf.k_, sil, np.nan, sil, imputed, read)
    boot = s.with_(n_bootstrap=SELECTION_BOOTSTRAP)
    stab = float(np.mean(bootstrap_stability(points, list(rows), labels, clf, boot)))
    return FeatureSetScore(name, tuple(indicators), clf.k_, sil, stab, sil * stab, imputed, read)


def choose_features(
    points: pd.DataFrame,
    drivers: list[str],
    n_dec: pd.Series,
    settings: AnalysisSettings,
    candidates: tuple[str, ...] = AUTO_CANDIDATES,
) -> tuple[str, list[FeatureSetScore]]:
    """The candidate set with the best score among those that read the decisions (`presses_read` at
    least `min_fit_points`; all of them when none does), and every candidate's score (in
    `candidates` order)."""
    scores = [score_feature_set(points, drivers, n_dec, settings, c, INDICATOR_SETS[c]) for c in candidates]
    eligible = [i for i, sc in enumerate(scores) if sc.presses_read >= settings.min_fit_points] or list(
        range(len(scores))
    )
    best = max(eligible, key=lambda i: (scores[i].score, -i))
    first = scores[0].score
    if (
        best
        and 0 in eligible
        and np.isfinite(first)
        and first > 0
        and scores[best].score < settings.auto_margin * first
    ):
        best = 0  # not clearly better than the study's own reading: keep it
    return scores[best].name, scores
