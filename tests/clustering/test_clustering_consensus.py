"""The consensus of several readings (`clustering.consensus`, `--features consensus`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from clustering import choice as C
from clustering import consensus as K
from clustering.readings import ReadingScore
from clustering.styles import StyleClusterer
from indicators.settings import AnalysisSettings

DRIVERS = ["d0", "d1", "n0", "n1", "a0", "a1"]
RIGHT = {"d0": "Defensive", "d1": "Defensive", "n0": "Normal", "n1": "Normal", "a0": "Aggressive", "a1": "Aggressive"}


def reading(name: str, labels: dict[str, str], silhouette: float) -> ReadingScore:
    return ReadingScore(
        name, (name,), np.nan, np.nan, np.nan, False, False, labels, silhouette=silhouette, stability=1.0
    )


def test_co_association_weighs_each_reading_by_its_score():
    split = {**RIGHT, "n0": "Defensive"}  # puts n0 with the defensive drivers
    co = K.co_association([reading("a", RIGHT, 0.6), reading("b", split, 0.2)], DRIVERS)
    i, j = DRIVERS.index("n0"), DRIVERS.index("d0")
    assert np.isclose(co[i, j], 0.2 / 0.8)
    assert np.isclose(co[i, DRIVERS.index("n1")], 0.6 / 0.8)
    assert np.allclose(np.diag(co), 1.0) and np.allclose(co, co.T)


def test_the_readings_outvote_the_single_best():
    """The best separated reading is wrong; the next ones, together heavier, are right."""
    wrong = {**RIGHT, "n0": "Defensive", "n1": "Defensive", "d0": "Normal", "d1": "Normal"}
    voters = [reading("one", wrong, 0.9), reading("two", RIGHT, 0.6), reading("three", RIGHT, 0.5)]
    groups = K.consensus_groups(voters, DRIVERS, 3)
    assert len(set(groups)) == 3
    for a, b in (("d0", "d1"), ("n0", "n1"), ("a0", "a1")):
        assert groups[DRIVERS.index(a)] == groups[DRIVERS.index(b)]
    votes = K.vote_defensiveness(voters, DRIVERS, groups)
    assert votes[groups[DRIVERS.index("a0")]] == votes.min()  # the aggressive pair is named so by every voter
    assert votes[groups[DRIVERS.index("d0")]] > votes[groups[DRIVERS.index("a0")]]


def test_fit_partition_keeps_the_given_groups_and_orders_by_room():
    X = pd.DataFrame({"thw_nb": [3.0, 2.9, 1.5, 1.6, 0.5, 0.6]}, index=DRIVERS)
    groups = np.array([2, 2, 0, 0, 1, 0])  # a1 placed with the middle drivers by the partition
    clf = StyleClusterer(k=3, room=["thw_nb"]).fit_partition(X, groups)
    names = [clf.names_[i] for i in clf.labels_]
    assert names[:2] == ["Defensive", "Defensive"] and names[4] == "Aggressive"
    assert names[5] == names[2] == "Normal"  # kept with its group although nearer another centre
    assert list(clf.predict(X.loc[["a1"]])) != [clf.labels_[5]]


def test_choose_consensus_names_the_styles_and_reports_its_voters(monkeypatch):
    from test_clustering_behaviour import _three_styles_with_a_noise_variable  # this folder is on the path

    _, drivers, b = _three_styles_with_a_noise_variable()
    monkeypatch.setattr(C, "choose_features", lambda *a, **k: ("", []))  # no indicator set in this world
    n_dec = pd.Series(24, index=drivers)
    choice = C.choose_consensus(
        pd.DataFrame(), drivers, drivers, n_dec, b, AnalysisSettings(features="consensus", n_init=5)
    )
    assert choice.name == C.CONSENSUS and C.reads_behaviour(choice.name)
    chosen = [s for s in choice.scores if s.chosen]
    assert len(chosen) == 1 and chosen[0].name == C.CONSENSUS
    assert sum(s.plausible for s in choice.scores) == len(K.votes(choice.scores[1:])[0])
    labels = chosen[0].labels
    assert {labels[x] for x in ("d0", "d1", "d2")} == {"Defensive"}
    assert {labels[x] for x in ("a0", "a1", "a2")} == {"Aggressive"}
    style, conf, _ = C.assign(choice, b, drivers, n_dec, AnalysisSettings())
    assert (style == pd.Series(labels)).all() and ((conf >= 0) & (conf <= 1)).all()


def test_readings_far_below_the_best_do_not_vote_with_a_floor(monkeypatch):
    """With a vote floor, three weak readings that agree (parameters the data hardly inform) do not
    outvote a clear one; without it (the default) the `CONSENSUS_READINGS` best vote."""
    wrong = {**RIGHT, "n0": "Defensive", "n1": "Defensive", "d0": "Normal", "d1": "Normal"}
    ranked = [reading("clear", RIGHT, 0.8), *(reading(f"weak{i}", wrong, 0.3) for i in range(3))]
    assert len(K.votes(ranked)[0]) == min(len(ranked), K.CONSENSUS_READINGS)
    monkeypatch.setattr(K, "VOTE_FLOOR", 0.5)
    assert [r.name for r in K.votes(ranked)[0]] == ["clear"]
    groups = K.consensus_groups(K.votes(ranked)[0], DRIVERS, 3)
    assert groups[DRIVERS.index("n0")] == groups[DRIVERS.index("n1")] != groups[DRIVERS.index("d0")]


def test_a_reading_that_splits_off_one_driver_does_not_vote():
    """A reading whose smallest style is one driver split off an outlier: it does not vote, unless every
    reading does so."""
    outlier = {**RIGHT, "d0": "Defensive", "d1": "Normal", "n0": "Normal", "n1": "Normal"}  # d0 alone
    ranked = [
        reading("outlier", outlier, 0.9),
        *(reading(f"right{i}", RIGHT, 0.5) for i in range(K.CONSENSUS_READINGS)),
    ]
    assert K.smallest_style(ranked[0]) == 1 and K.smallest_style(ranked[1]) == 2
    assert "outlier" not in [r.name for r in K.votes(ranked)[0]]
    assert len(K.votes(ranked)[0]) == K.CONSENSUS_READINGS
    assert [r.name for r in K.votes(ranked[:1])[0]] == ["outlier"]  # none without an outlier split: those there vote


def test_a_reading_has_no_say_on_a_driver_it_could_not_estimate():
    """A driver missing a reading's parameter is labelled by imputation (the median: Normal); that reading's
    votes on every pair with it are left out, in the groups and in the driver's agreement."""
    imputed = {**RIGHT, "a0": "Normal"}
    voting = [
        replace(reading("imputes", imputed, 0.9), unread=("a0",)),
        reading("right", RIGHT, 0.3),
    ]
    co = K.co_association(voting, DRIVERS)
    a0, a1, n0 = (DRIVERS.index(d) for d in ("a0", "a1", "n0"))
    assert np.isclose(co[a0, a1], 1.0) and np.isclose(co[a0, n0], 0.0)
    assert np.isclose(K.co_association(voting, DRIVERS, skip_unread=False)[a0, n0], 0.9 / 1.2)
    groups = K.consensus_groups(voting, DRIVERS, 3)
    assert groups[a0] == groups[a1] != groups[n0]
    choice = C.Choice(C.CONSENSUS, (), [replace(r, plausible=True) for r in voting], None)
    share, others = C.reading_agreement(choice, pd.Series(RIGHT))
    assert share["a0"] == 1.0 and others["a0"] == []


def test_behaviour_readings_mark_the_drivers_they_impute(monkeypatch):
    from test_clustering_behaviour import _three_styles_with_a_noise_variable  # this folder is on the path

    _, drivers, b = _three_styles_with_a_noise_variable()
    values = b.values.copy()
    values.loc["a0", "thw_nb"] = np.nan
    monkeypatch.setattr(C, "choose_features", lambda *a, **k: ("", []))
    scores, _ = C.ranked_readings(
        pd.DataFrame(),
        drivers,
        drivers,
        pd.Series(24, index=drivers),
        replace(b, values=values),
        AnalysisSettings(n_init=5),
    )
    with_thw_nb = [r for r in scores if "thw_nb" in r.parameters]
    assert with_thw_nb and all(r.unread == ("a0",) for r in with_thw_nb)
    assert all(r.unread == () for r in scores if "thw_nb" not in r.parameters)


def test_copies_of_one_parameter_do_not_outvote_the_others():
    """Four readings of `t_f` misplace a2; the other parameters, each read once and less well separated, place
    it right. Counted by silhouette alone the copies outvote them; weighed by how much the other parameters
    agree with each reading (`agreement`), they do not."""
    drivers = [f"{s}{i}" for s in "dna" for i in range(3)]
    right = {d: {"d": "Defensive", "n": "Normal", "a": "Aggressive"}[d[0]] for d in drivers}
    misplaced = {**right, "a2": "Normal"}

    def behaviour_reading(params: str, labels: dict[str, str], silhouette: float) -> ReadingScore:
        return replace(reading(C.BEHAVIOUR + params, labels, silhouette), parameters=tuple(params.split("+")))

    ranked = [
        behaviour_reading("t_f", misplaced, 0.9),
        *(behaviour_reading(f"t_f+{p}", misplaced, 0.85) for p in ("v_free", "lc_rate", "gap_nf")),
        *(behaviour_reading(p, right, 0.7) for p in ("v_free", "lc_rate", "thw_f")),
    ]
    assert K.agreement(ranked[0], ranked) < K.agreement(ranked[4], ranked) == K.agreement(ranked[6], ranked)
    assert K.agreement(ranked[0], ranked, how="none") == 1.0

    def a2_with(how: str) -> str:
        voting, say = K.votes(ranked, how=how)
        groups = K.consensus_groups(voting, drivers, 3, weights=say)
        same = [d for d in drivers if d != "a2" and groups[drivers.index(d)] == groups[drivers.index("a2")]]
        return right[same[0]]

    assert {r.name for r in K.votes(ranked)[0]} & {C.BEHAVIOUR + p for p in ("v_free", "lc_rate", "thw_f")}
    assert a2_with("none") == "Normal"  # the four copies of t_f are the four best: they alone vote
    assert a2_with("mean") == a2_with("top3") == "Aggressive"
