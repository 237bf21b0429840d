"""Styles by the consensus of the best readings, not by the one best.

Picking the single best separated reading (`--features separated`) is fragile: on a study of
nine drivers one parameter alone (the headway kept while following, say) can split the drivers
cleanly and still wrongly, while the styles, which differ in many parameters at once, show up
in most of the good readings. Here `CONSENSUS_READINGS` of the separated readings
(`clustering.choice.ranked_readings`) vote (`votes`): two drivers are together as often as the
voters put them together, weighted by each voter's say (the co-association matrix of ensemble
clustering, Fred & Jain 2005), and the drivers are cut into k groups by average linkage on it
(`LINKAGE`). No reading gets a say it has not earned:

- a reading that puts one driver alone in a style (a style of fewer than `MIN_STYLE_SIZE` drivers)
  has split off an outlier, not found a style, and does not vote (unless no reading is left);
- a reading says nothing of a driver it could not estimate (one of its parameters missing, where
  the clusterer imputes the median and so calls the driver Normal): such a driver is among the
  reading's `unread` ones, and the reading's vote on every pair with it is left out;
- a reading counts as much as the *other* parameters agree with it (`agreement`). A style shows in
  many parameters at once, while a parameter that splits the drivers by a trait of its own (a lead
  gap some drivers keep whatever their style) or misplaces one driver agrees with few others. Without
  this, several readings of one parameter (`t_f`, `t_f+v_free`, `t_f+lc_rate`) outvote the rest with
  one opinion. Each reading's say is its silhouette x stability times its agreement
  (`AGREEMENT`), and the voters are the readings with the most say.

Each group is named by the voters: the style name they give its members, weighted by their say.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.spatial.distance import squareform
from sklearn.metrics import adjusted_rand_score

from clustering.behaviour import BEHAVIOUR
from clustering.readings import ReadingScore
from clustering.styles import style_names

#: How many readings vote (those with the most say, `votes`), with no floor, cut by average linkage: chosen one
#: world out among the variants that read the shipped study right (`benchmarks/consensus.py`).
CONSENSUS_READINGS = 5
#: A reading whose smallest style has fewer drivers than this does not vote (it split off an outlier).
MIN_STYLE_SIZE = 2
#: A reading whose say is under this share of the largest one's does not vote (0: the `CONSENSUS_READINGS` with
#: the most say all vote; a floor keeps readings of parameters the data hardly inform from outvoting a clear one
#: when more vote).
VOTE_FLOOR = 0.0
#: The linkage the drivers are cut by (scipy's names).
LINKAGE = "average"
#: How the other parameters' agreement with a reading weighs its say (`agreement`): 'mean' over the one-parameter
#: readings of the other parameters, 'top3' over the three that agree most, 'none' (every reading agrees fully,
#: the say is silhouette x stability alone, as before). Chosen one world out (`benchmarks/consensus.py`).
AGREEMENT = "top3"


def votes(
    ranked: Sequence[ReadingScore], n: int = CONSENSUS_READINGS, how: str = AGREEMENT
) -> tuple[list[ReadingScore], list[float]]:
    """The readings that vote and the say of each: among the readings of `ranked` with no style of fewer
    than `MIN_STYLE_SIZE` drivers (all of `ranked` if none is left), the `n` with the
    most say (silhouette x stability x `agreement`), that score at least `VOTE_FLOOR` times the best of them."""
    if not ranked:
        return [], []
    pool = without_outlier_splits(ranked)
    say = {r.name: weight(r) * agreement(r, ranked, how) for r in pool}
    if not any(say.values()):  # no reading agrees with another: silhouette x stability alone
        say = {r.name: weight(r) for r in pool}
    pool = sorted(pool, key=lambda r: -say[r.name])  # stable: ties keep the ranking's order
    floor = VOTE_FLOOR * say[pool[0].name]
    voting = [r for r in pool[:n] if say[r.name] >= floor]
    return voting, [say[r.name] for r in voting]


def agreement(reading: ReadingScore, ranked: Sequence[ReadingScore], how: str = AGREEMENT) -> float:
    """How much the other parameters agree with `reading`: the ARI (at least 0) of its styles with those of
    every one-parameter behaviour reading of `ranked` that shares no parameter with it, on the drivers both
    read, averaged ('mean') or over the three that agree most ('top3'); 1 with `how` 'none' or with no such
    reading to compare."""
    if how == "none":
        return 1.0
    others = [
        r
        for r in ranked
        if r.name.startswith(BEHAVIOUR) and len(r.parameters) == 1 and not set(r.parameters) & set(reading.parameters)
    ]
    aris = [a for a in (_ari_on_both(reading, r) for r in others) if np.isfinite(a)]
    if not aris:
        return 1.0
    clipped = np.clip(np.asarray(aris, dtype=float), 0.0, None)
    if how == "top3":
        return float(np.sort(clipped)[::-1][:3].mean())
    if how == "mean":
        return float(clipped.mean())
    raise ValueError(f"unknown agreement {how!r}: 'mean', 'top3' or 'none'")


def _ari_on_both(a: ReadingScore, b: ReadingScore) -> float:
    """ARI of two readings' styles on the drivers both read (NaN under three such drivers)."""
    both = [d for d in a.labels if a.reads(d) and b.reads(d)]
    if len(both) < 3:
        return float("nan")
    return float(adjusted_rand_score([a.labels[d] for d in both], [b.labels[d] for d in both]))


def without_outlier_splits(ranked: Sequence[ReadingScore]) -> list[ReadingScore]:
    """The readings of `ranked` with no style of fewer than `MIN_STYLE_SIZE` drivers (all of them if none is left)."""
    return [r for r in ranked if smallest_style(r) >= MIN_STYLE_SIZE] or list(ranked)


def smallest_style(reading: ReadingScore) -> int:
    """How many drivers the reading's smallest style holds (0 for a reading of no driver)."""
    return min(Counter(reading.labels.values()).values()) if reading.labels else 0


def weight(reading: ReadingScore) -> float:
    """A reading's vote: its silhouette x stability (stability 1 where unmeasured), at least 0."""
    stab = reading.stability if np.isfinite(reading.stability) else 1.0
    return max(float(reading.silhouette) * stab, 0.0) if np.isfinite(reading.silhouette) else 0.0


def co_association(
    readings: Sequence[ReadingScore],
    drivers: list[str],
    weights: Sequence[float] | None = None,
    skip_unread: bool = True,
) -> np.ndarray:
    """Weighted share of the readings (among those that read both) that put each pair of
    `drivers` in the same style (1 on the diagonal); each reading weighs its `weight` unless
    `weights` are given. A reading does not read its `unread` drivers unless `skip_unread` is False."""
    n = len(drivers)
    together, seen = np.zeros((n, n)), np.zeros((n, n))
    for r, w in zip(readings, weights if weights is not None else [weight(r) for r in readings]):
        rows = np.array([i for i, d in enumerate(drivers) if (r.reads(d) if skip_unread else d in r.labels)], dtype=int)
        if w <= 0 or len(rows) == 0:
            continue
        lab = np.array([r.labels[drivers[i]] for i in rows], dtype=object)
        together[np.ix_(rows, rows)] += w * (lab[:, None] == lab[None, :])
        seen[np.ix_(rows, rows)] += w
    out = np.divide(together, seen, out=np.zeros_like(together), where=seen > 0)
    np.fill_diagonal(out, 1.0)
    return out


def consensus_groups(
    readings: Sequence[ReadingScore],
    drivers: list[str],
    k: int,
    method: str = LINKAGE,
    weights: Sequence[float] | None = None,
    skip_unread: bool = True,
) -> np.ndarray:
    """Group (0 .. k-1, unnamed) of every driver: `method` linkage on 1 - co-association, cut at k."""
    if len(drivers) <= k:
        return np.arange(len(drivers))
    distance = 1.0 - co_association(readings, drivers, weights, skip_unread)
    tree = linkage(squareform(distance, checks=False), method=method)
    return fcluster(tree, k, criterion="maxclust") - 1


def vote_defensiveness(
    readings: Sequence[ReadingScore],
    drivers: list[str],
    groups: np.ndarray,
    weights: Sequence[float] | None = None,
) -> np.ndarray:
    """Per group, how defensive the readings call its members: the mean of the names' rank (Defensive
    highest) weighted by each reading's `weight` (or `weights`), for ordering and naming the groups."""
    n_groups = int(groups.max()) + 1
    score, total = np.zeros(n_groups), np.zeros(n_groups)
    for r, w in zip(readings, weights if weights is not None else [weight(r) for r in readings]):
        names = style_names(len(set(r.labels.values()))) if r.labels else []
        for d, g in zip(drivers, groups):
            if r.reads(d) and r.labels[d] in names:
                score[g] += w * -names.index(r.labels[d]) / max(len(names) - 1, 1)
                total[g] += w
    return np.divide(score, total, out=np.zeros_like(score), where=total > 0)
