"""The styles as the analysis reports them: the reading chosen on held-out behaviour, each
driver's honest confidence and the reason it is unsure, and each style in words.

Two kinds of reading compete on the same held-out criterion (`clustering.readings`):

- **behaviour readings** (`behaviour:<params>`): clusters of the drivers' critical values and
  following headway (`clustering.behaviour`), estimated from presses and not-yet states;
- **indicator readings** (the named sets 'ttc', 'following', 'acceptance', 'all'): clusters of
  each driver's indicator lines at the presses (`clustering.features`), the earlier way.

`--features heldout` takes whichever predicts held-out behaviour best; `--features behaviour`
only the behaviour readings; a set name or `behaviour:<params>` that reading alone.
`--features consensus`, the default, reads the styles the readings of either kind with
the most say agree on (separated, stable, and agreed with by the other parameters: `clustering.consensus`); `--features separated` takes the one
best of them (no margin for any); `--features reliable` the two behaviour parameters the drivers
differ in most reliably; 'auto' the choice among indicator sets by silhouette x stability
(`clustering.selection`). The default was chosen one world out on the zoo of worlds
(`benchmarks/analysis.py --zoo`, `benchmarks/consensus.py`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from sklearn.metrics import silhouette_score

from clustering.consensus import (
    CONSENSUS_READINGS,
    MIN_STYLE_SIZE,
    consensus_groups,
    smallest_style,
    vote_defensiveness,
    votes,
    weight,
)
from clustering.behaviour import BEHAVIOUR, PARAMETERS, VARIABLES, Behaviour, behaviour_params, decision_data, subset
from clustering.features import driver_features, transform_features
from clustering.readings import (
    ReadingScore,
    candidate_readings,
    choose_reading,
    cluster_reading,
    draw_confidence,
    most_reliable,
    parameter_reliability,
    usable_parameters,
)
from clustering.selection import MAX_IMPUTED, choose_features, clustering_rows
from clustering.styles import StyleClusterer
from indicators.settings import AUTO_CANDIDATES, INDICATOR_SETS, AnalysisSettings

#: `features` values that choose on held-out behaviour: 'heldout' among every reading,
#: 'behaviour' among the behaviour readings only.
HELDOUT_CHOICES: tuple[str, ...] = ("heldout", "behaviour")
#: `features` value that reads the drivers by their most reliable behaviour parameters.
RELIABLE = "reliable"
#: `features` value that takes the best separated and most stable reading of all, indicator sets
#: and behaviour readings alike, with no margin for any.
SEPARATED = "separated"
#: `features` value that reads the drivers by the consensus of the best separated readings.
CONSENSUS = "consensus"
#: With 'separated', this many of the best readings are plausible (a driver they read otherwise is unsure).
PLAUSIBLE_READINGS = 3
#: Largest number of behaviour parameters in one candidate reading.
MAX_READING_SIZE = 2
#: A driver with fewer presses than this is unsure whatever its estimates say.
FEW_PRESSES = 8


def is_behaviour(name: str) -> bool:
    return name.startswith(BEHAVIOUR)


def reads_behaviour(name: str) -> bool:
    """Whether a chosen reading's styles live in behaviour parameters (a behaviour reading or the consensus)."""
    return is_behaviour(name) or name == CONSENSUS


@dataclass
class Choice:
    """The reading chosen and what the choice saw."""

    name: str
    parameters: tuple[str, ...]
    scores: list[ReadingScore]
    clusterer: StyleClusterer | None  # the chosen behaviour reading's (None for an indicator reading)


def indicator_labels(
    points: pd.DataFrame, drivers: list[str], n_dec: pd.Series, settings: AnalysisSettings, name: str
) -> dict[str, str] | None:
    """Styles of the drivers that place the centres, read by indicator set `name` (None: not readable)."""
    s = settings.with_(feature_indicators=INDICATOR_SETS[name])
    feats, _ = driver_features(points, drivers, s)
    rows = clustering_rows(feats, n_dec, s)
    if len(rows) <= s.k or float(feats.loc[rows].isna().to_numpy().mean()) > MAX_IMPUTED:
        return None
    clf = StyleClusterer(k=s.k, n_init=s.n_init, random_state=s.random_state).fit(
        transform_features(feats, s).loc[rows]
    )
    return {str(d): clf.names_[i] for d, i in zip(rows, clf.labels_)}


def choose(
    decisions: pd.DataFrame,
    following: pd.DataFrame | None,
    points: pd.DataFrame,
    drivers: list[str],
    n_dec: pd.Series,
    behaviour: Behaviour,
    settings: AnalysisSettings,
) -> Choice:
    """The reading of `settings.features` (chosen on held-out behaviour for 'auto' / 'behaviour')."""
    fit_on = [d for d in drivers if n_dec.get(d, 0) >= settings.min_cluster_decisions] or [
        d for d in drivers if n_dec.get(d, 0) > 0
    ]
    spec = settings.features
    if spec == RELIABLE:
        return choose_reliable(behaviour, fit_on, settings)
    if spec == CONSENSUS:
        return choose_consensus(points, drivers, fit_on, n_dec, behaviour, settings)
    if spec == SEPARATED:
        return choose_separated(points, drivers, fit_on, n_dec, behaviour, settings)
    data = decision_data(decisions)
    data = subset(data, np.isin(data.driver, fit_on))
    if spec in HELDOUT_CHOICES:
        readings = {BEHAVIOUR + n: p for n, p in candidate_readings(max_size=MAX_READING_SIZE).items()}
        extra = {}
        if spec == "heldout":
            for name in AUTO_CANDIDATES:
                labels = indicator_labels(points, drivers, n_dec, settings, name)
                if labels is not None:
                    extra[name] = (INDICATOR_SETS[name], labels)
    elif is_behaviour(spec):
        readings, extra = {spec: behaviour_params(spec)}, {}
    else:
        raise ValueError(f"{spec!r} is not a held-out choice")
    best, scores, clusterers = choose_reading(
        behaviour, data, fit_on, settings.k, settings.n_init, settings.random_state, readings, following, extra
    )
    if not best:
        return Choice("", (), [], None)
    chosen = next(s for s in scores if s.name == best)
    return Choice(best, chosen.parameters, scores, clusterers.get(best))


def choose_reliable(behaviour: Behaviour, fit_on: list[str], settings: AnalysisSettings) -> Choice:
    """The drivers read by the `MAX_READING_SIZE` behaviour parameters in which they differ most
    reliably (`parameter_reliability`); each of those parameters alone is a plausible reading
    too, so a driver they place in different styles is unsure."""
    params = most_reliable(behaviour, fit_on, MAX_READING_SIZE)
    if not params or len(fit_on) <= settings.k:
        return Choice("", (), [], None)
    rel = parameter_reliability(behaviour, fit_on)
    name = BEHAVIOUR + "+".join(params)
    readings = {name: params} | ({BEHAVIOUR + p: (p,) for p in params} if len(params) > 1 else {})
    scores, clusterers = [], {}
    for n, ps in readings.items():
        clf = cluster_reading(behaviour, ps, fit_on, settings.k, settings.n_init, settings.random_state)
        labels = {d: clf.names_[i] for d, i in zip(fit_on, clf.labels_)}
        clusterers[n] = clf
        scores.append(
            ReadingScore(n, ps, np.nan, np.nan, np.nan, True, n == name, labels, float(min(rel[p] for p in ps)))
        )
    return Choice(name, params, scores, clusterers[name])


def ranked_readings(
    points: pd.DataFrame,
    drivers: list[str],
    fit_on: list[str],
    n_dec: pd.Series,
    behaviour: Behaviour,
    settings: AnalysisSettings,
) -> tuple[list[ReadingScore], dict[str, StyleClusterer]]:
    """Every reading, best separated and most stable first: the indicator sets 'auto' weighs (those
    that read the decisions) and the behaviour readings of up to `MAX_READING_SIZE` parameters,
    each scored by silhouette x stability (stability: the share of draws of each driver's
    estimates, from their standard errors, left in its style), with no margin for any; and the
    clusterer of each behaviour reading."""
    scores: list[ReadingScore] = []
    clusterers: dict[str, StyleClusterer] = {}
    if len(fit_on) > settings.k:
        usable = set(usable_parameters(behaviour, fit_on))
        for n, ps in candidate_readings(max_size=MAX_READING_SIZE).items():
            if not set(ps) <= usable:
                continue
            clf = cluster_reading(behaviour, ps, fit_on, settings.k, settings.n_init, settings.random_state)
            if len(set(clf.labels_.tolist())) < 2:
                continue
            sil = float(silhouette_score(clf.transform(behaviour.values.loc[fit_on, list(ps)]), clf.labels_))
            stab = float(draw_confidence(behaviour, fit_on, clf, clf.labels_, settings.random_state).mean())
            labels = {d: clf.names_[i] for d, i in zip(fit_on, clf.labels_)}
            missing = behaviour.values.loc[fit_on, list(ps)].isna().any(axis=1)
            clusterers[BEHAVIOUR + n] = clf
            scores.append(
                ReadingScore(
                    BEHAVIOUR + n,
                    ps,
                    np.nan,
                    np.nan,
                    np.nan,
                    False,
                    False,
                    labels,
                    silhouette=sil,
                    stability=stab,
                    unread=tuple(missing.index[missing.to_numpy()]),
                )
            )
    _, set_scores = choose_features(points, drivers, n_dec, settings)
    for sc in set_scores:
        if sc.presses_read < settings.min_fit_points or not np.isfinite(sc.score):
            continue
        read = indicator_labels(points, drivers, n_dec, settings, sc.name)
        if read is not None:
            scores.append(
                ReadingScore(
                    sc.name,
                    INDICATOR_SETS[sc.name],
                    np.nan,
                    np.nan,
                    np.nan,
                    False,
                    False,
                    read,
                    silhouette=sc.silhouette,
                    stability=sc.stability,
                )
            )
    scores.sort(key=lambda r: -(r.silhouette * np.nan_to_num(r.stability, nan=1.0)))
    return scores, clusterers


def choose_separated(
    points: pd.DataFrame,
    drivers: list[str],
    fit_on: list[str],
    n_dec: pd.Series,
    behaviour: Behaviour,
    settings: AnalysisSettings,
) -> Choice:
    """The best separated and most stable reading (`ranked_readings`); the `PLAUSIBLE_READINGS`
    best are plausible."""
    scores, clusterers = ranked_readings(points, drivers, fit_on, n_dec, behaviour, settings)
    if not scores:
        return Choice("", (), [], None)
    scores = [replace(r, plausible=i < PLAUSIBLE_READINGS, chosen=i == 0) for i, r in enumerate(scores)]
    best = scores[0]
    return Choice(best.name, best.parameters, scores, clusterers.get(best.name))


def choose_consensus(
    points: pd.DataFrame,
    drivers: list[str],
    fit_on: list[str],
    n_dec: pd.Series,
    behaviour: Behaviour,
    settings: AnalysisSettings,
) -> Choice:
    """The styles the `CONSENSUS_READINGS` readings with the most say agree on (`clustering.consensus.votes`:
    silhouette x stability x the other parameters' agreement).

    The voters are the plausible readings. The styles' centres sit in the space of the behaviour
    parameters the voters read (every usable one if only indicator sets voted), where drivers
    with too few presses to place a centre are assigned and each driver's estimates are drawn
    for its confidence; with no usable behaviour parameter (a table without not-yet states) the
    drivers are read as by `choose_separated`. With `settings.choose_k` ('silhouette' or 'bic' alike), the readings are
    made at every k of `settings.k_range` and the k whose readings are best separated and most stable
    (`k_score`) is kept; its scores per k are the clusterer's `k_scores_`."""
    if not usable_parameters(behaviour, fit_on):
        return choose_separated(points, drivers, fit_on, n_dec, behaviour, settings)
    if settings.choose_k:
        lo, hi = settings.k_range
        ks = list(range(max(lo, 2), min(hi, len(fit_on) - 1) + 1)) or [settings.k]
    else:
        ks = [settings.k]
    best: tuple[float, int, list[ReadingScore], np.ndarray] | None = None
    k_scores: dict[int, float] = {}
    for k in ks:
        scores, _ = ranked_readings(points, drivers, fit_on, n_dec, behaviour, settings.with_(k=k))
        if not scores:
            continue
        voting, say = votes(scores)
        groups = consensus_groups(voting, fit_on, k, weights=say)
        k_scores[k] = k_score(scores)
        if best is None or k_scores[k] > best[0]:
            best = (k_scores[k], k, scores, groups)
    if best is None:
        return Choice("", (), [], None)
    _, k, scores, groups = best
    voting, say = votes(scores)
    params = tuple(dict.fromkeys(p for r in voting if is_behaviour(r.name) for p in r.parameters)) or usable_parameters(
        behaviour, fit_on
    )
    clf = StyleClusterer(k=k, random_state=settings.random_state, room=list(params))
    clf.fit_partition(behaviour.values.loc[fit_on, list(params)], groups)
    clf.k_scores_ = k_scores if settings.choose_k else {}
    ids = sorted(set(groups.tolist()))
    defensive = vote_defensiveness(voting, fit_on, groups, say)
    clf.order_by(defensive[np.asarray(ids)[clf.order_]])  # named as the voters name their members
    labels = {d: clf.names_[i] for d, i in zip(fit_on, clf.labels_)}
    voted = {r.name for r in voting}
    scores = [replace(r, plausible=r.name in voted) for r in scores]
    sil = (
        float(silhouette_score(clf.transform(behaviour.values.loc[fit_on, list(params)]), clf.labels_))
        if 1 < len(set(clf.labels_.tolist())) < len(fit_on)
        else np.nan
    )
    stab = float(draw_confidence(behaviour, fit_on, clf, clf.labels_, settings.random_state).mean())
    chosen = ReadingScore(
        CONSENSUS, params, np.nan, np.nan, np.nan, False, True, labels, silhouette=sil, stability=stab
    )
    return Choice(CONSENSUS, params, [chosen, *scores], clf)


def k_score(ranked: list[ReadingScore]) -> float:
    """How well k styles show in the readings made at k: the mean silhouette x stability of the
    `CONSENSUS_READINGS` best, a reading that puts one driver alone in a style scoring 0 (it split off
    an outlier: at a k above the styles' count every reading can do so, and that is no style)."""
    best = ranked[:CONSENSUS_READINGS]
    return float(np.mean([weight(r) if smallest_style(r) >= MIN_STYLE_SIZE else 0.0 for r in best]))


def silhouette_alternatives(
    points: pd.DataFrame, drivers: list[str], n_dec: pd.Series, settings: AnalysisSettings, feature_sets: pd.DataFrame
) -> Choice:
    """The indicator sets 'auto' could as well have chosen (a score within `auto_margin` of the
    chosen set's) as a `Choice`, so that a driver they read otherwise is reported unsure."""
    scored = feature_sets[np.isfinite(feature_sets["score"].astype(float))]
    if scored.empty or not scored["chosen"].any():
        return Choice("", (), [], None)
    chosen = scored[scored["chosen"]].iloc[0]
    top = float(chosen["score"])
    scores = []
    for r in scored.itertuples():
        if r.name not in INDICATOR_SETS:
            continue
        plausible = bool(r.chosen) or (top > 0 and float(r.score) * settings.auto_margin >= top)
        labels = indicator_labels(points, drivers, n_dec, settings, r.name) if plausible else None
        if plausible and labels is None:
            continue
        scores.append(
            ReadingScore(
                r.name, INDICATOR_SETS[r.name], np.nan, np.nan, np.nan, plausible, bool(r.chosen), labels or {}
            )
        )
    return Choice(str(chosen["name"]), INDICATOR_SETS.get(str(chosen["name"]), ()), scores, None)


def behaviour_columns(params: tuple[str, ...] = PARAMETERS) -> list[str]:
    """Styles-table columns of behaviour parameters, e.g. 'crit_thw_nb_s', 'kept_thw_follow_s'."""
    return [column(p) for p in params]


def column(param: str) -> str:
    if param == "thw_follow":
        return "kept_thw_follow_s"
    if param == "v_free":
        return "drive_v_free_share"
    if param == "lc_rate":
        return "drive_lc_rate_permin"
    return f"crit_{param}_{'m' if VARIABLES[param][3] == 'm' else 's'}"


def assign(
    choice: Choice, behaviour: Behaviour, drivers: list[str], n_dec: pd.Series, settings: AnalysisSettings
) -> tuple[pd.Series, pd.Series, pd.Series]:
    """(style, data confidence, defensiveness) of every driver under a chosen behaviour reading
    ('unassigned' / 0 for drivers with no presses)."""
    clf = choice.clusterer
    style = pd.Series("unassigned", index=drivers, dtype=object)
    conf = pd.Series(0.0, index=drivers)
    defn = pd.Series(np.nan, index=drivers)
    rows = [d for d in drivers if n_dec.get(d, 0) > 0]
    if clf is None or not rows:
        return style, conf, defn
    X = behaviour.values.loc[rows, clf.feature_names_in_]
    labels = clf.predict(X)
    chosen = next((s for s in choice.scores if s.chosen), None)
    if chosen is not None:  # drivers that placed the centres keep the style the choice gave them
        labels = np.array(
            [clf.names_.index(chosen.labels[d]) if d in chosen.labels else lab for d, lab in zip(rows, labels)]
        )
    style[rows] = [clf.names_[i] for i in labels]
    conf[rows] = draw_confidence(behaviour, rows, clf, labels, settings.random_state)
    defn[rows] = clf.defensiveness(X)
    return style, conf, defn


def reading_agreement(choice: Choice, styles: pd.Series) -> tuple[pd.Series, dict[str, list[str]]]:
    """Per driver: the share of plausible readings that give it its style, and the readings that
    read it otherwise (with the style they give); a reading that could not estimate the driver
    (`ReadingScore.unread`) has no say on it."""
    plausible = [s for s in choice.scores if s.plausible]
    share = pd.Series(1.0, index=styles.index)
    other: dict[str, list[str]] = {d: [] for d in styles.index}
    if len(plausible) <= 1:
        return share, other
    for d in styles.index:
        votes = [s for s in plausible if s.reads(d)]
        if not votes:
            continue
        agree = [s for s in votes if s.labels[d] == styles[d]]
        share[d] = len(agree) / len(votes)
        other[d] = [f"{s.labels[d]} by {s.name}" for s in votes if s.labels[d] != styles[d]]
    return share, other


def succession(n_presses: int) -> float:
    """The most a style read from `n_presses` presses can be trusted: Laplace's rule of succession,
    (n + 1) / (n + 2): 0.8 at 3 presses, 0.9 at 8, 0.95 at 18."""
    return (n_presses + 1) / (n_presses + 2)


def unsure_reasons(
    d: str,
    n_presses: int,
    data_conf: float,
    agreement: float,
    others: list[str],
    behaviour: Behaviour,
    params: tuple[str, ...],
) -> str:
    """Why driver `d`'s style is not sure, in one line ('' when it is)."""
    why = []
    if n_presses < FEW_PRESSES:
        why.append(f"only {n_presses} presses (confidence at most {succession(n_presses):.2f})")
    if data_conf < 0.9 and params and d in behaviour.se.index:
        wide = [p for p in params if np.isfinite(behaviour.se.loc[d, p]) and behaviour.se.loc[d, p] > 0.3]
        what = ", ".join(f"{p} x/÷ {np.exp(behaviour.se.loc[d, p]):.1f}" for p in wide)
        why.append(
            f"its own estimates leave it in its style in {100 * data_conf:.0f} % of draws"
            + (f" ({what})" if what else "")
        )
    if agreement < 1.0 and others:
        shown = "; ".join(others[:3]) + (f"; {len(others) - 3} more" if len(others) > 3 else "")
        why.append(f"readings as plausible disagree: {shown}")
    return "; ".join(why)


_WORDS = {
    "thw_nb": "accepts lag gaps down to {v:.2g} s headway",
    "gap_nf": "lead gaps down to {v:.3g} m",
    "t_nf": "a TTC to the new leader down to {v:.2g} s",
    "thw_f": "wants out when its leader is {v:.2g} s ahead",
    "t_f": "wants out at a TTC to its leader of {v:.2g} s",
    "thw_follow": "follows at {v:.2g} s",
    "v_free": "drives free at {v:.0%} of the limit",
    "lc_rate": "asks for a lane change {v:.2g} times a minute",
}


def describe_styles(styles: pd.DataFrame, behaviour: Behaviour) -> dict[str, str]:
    """Per style, what sets it apart, in words with units: the members' median critical values and
    following headway (`_WORDS`), the parameters that differ most between styles first."""
    assigned = styles[styles["style"] != "unassigned"]
    if assigned.empty:
        return {}
    vals = behaviour.values.loc[assigned["driver_id"]]
    informed = behaviour.defined.loc[assigned["driver_id"]] > 0
    vals = vals.where(informed)
    by_style = vals.groupby(assigned["style"].to_numpy()).median()
    spread = (by_style.max() - by_style.min()) / vals.std().replace(0, np.nan)
    order = [p for p in spread.sort_values(ascending=False).index if np.isfinite(spread[p])]
    out = {}
    for st, row in by_style.iterrows():
        parts = [_WORDS[p].format(v=float(np.exp(row[p]))) for p in order[:4] if np.isfinite(row[p])]
        out[str(st)] = "; ".join(parts)
    return out
