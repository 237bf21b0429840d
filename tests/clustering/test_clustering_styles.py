"""Style clustering: recovery of known styles, naming by defensiveness, confidence, k choice."""

import numpy as np
import pandas as pd
import pytest
from sklearn.metrics import adjusted_rand_score

from clustering.pipeline import analyze_tables
from clustering.styles import StyleClusterer, style_names
from indicators.settings import AnalysisSettings
from tests.support.synthetic_decisions import make_decision_table


@pytest.fixture(scope="module")
def synthetic():
    df, truth = make_decision_table(12, 30, seed=4)
    return df, truth, analyze_tables(df, AnalysisSettings(features="ttc"))  # indicator features, tested here


def test_the_default_consensus_recovers_them_too(synthetic):
    df, truth, _ = synthetic
    st = analyze_tables(df, AnalysisSettings(n_bootstrap=0))["styles"]
    assert (st["style"] == [truth[d] for d in st["driver_id"]]).all()
    assert st["confidence"].between(0, 1).all()


def test_styles_recovered_and_named_by_defensiveness(synthetic):
    _, truth, out = synthetic
    st = out["styles"]
    assert adjusted_rand_score([truth[d] for d in st["driver_id"]], st["style"]) == 1.0
    assert (st["style"] == [truth[d] for d in st["driver_id"]]).all()  # names, not only the partition
    means = st.groupby("style")["t_f_at_80kph_s"].mean()
    assert means["Defensive"] > means["Normal"] > means["Aggressive"]
    assert st["confidence"].between(0, 1).all() and st["margin"].between(0, 1).all()
    assert st.groupby("style")["is_typical"].sum().to_dict() == {"Aggressive": 1, "Defensive": 1, "Normal": 1}


def test_reference_lines_per_style_and_driver(synthetic):
    _, _, out = synthetic
    refs = out["reference_lines"]
    refs = refs[refs["direction"] == "both"]  # lines of every press (per-direction lines: tests/indicators)
    typ = refs[(refs["scope"] == "style") & (refs["kind"] == "typical")]
    assert sorted(typ["name"].unique()) == ["Aggressive", "Defensive", "Normal"]
    assert len(typ) == 9 and len(refs[refs["kind"] == "pooled"]) == 9 and len(refs[refs["kind"] == "paper"]) == 9
    assert len(refs[refs["scope"] == "driver"]) == 12 * 3
    st = out["styles"]
    d_typ = st[(st["style"] == "Defensive") & st["is_typical"]]["driver_id"].iloc[0]
    line = typ[(typ["name"] == "Defensive") & (typ["indicator"] == "t_f")].iloc[0]
    fit = out["fits"].set_index(["driver_id", "indicator"]).loc[(d_typ, "t_f")]
    assert line["A"] == fit["A"] and line["source"] == f"typical driver {d_typ}"


def test_clusterer_is_deterministic_and_sklearn_like():
    rng = np.random.default_rng(0)
    X = pd.DataFrame(np.r_[rng.normal(0, 0.1, (5, 2)), rng.normal(3, 0.1, (5, 2))], columns=["a_s", "b_s"])
    a = StyleClusterer(k=2, random_state=1).fit(X)
    b = StyleClusterer(k=2, random_state=1).fit(X)
    assert a is not None and (a.labels_ == b.labels_).all() and np.allclose(a.confidence_, b.confidence_)
    assert list(a.labels_) == [1] * 5 + [0] * 5  # larger values = more defensive = cluster 0
    assert a.names_ == ["Defensive", "Aggressive"]
    assert list(a.predict(X)) == list(a.labels_)


def test_choose_k_by_silhouette_and_bic():
    rng = np.random.default_rng(2)
    centres = [0.0, 4.0, 8.0, 12.0]
    X = pd.DataFrame(np.concatenate([rng.normal(c, 0.2, (6, 2)) for c in centres]), columns=["a_s", "b_s"])
    sil = StyleClusterer(choose_k="silhouette", k_range=(2, 6)).fit(X)
    assert sil.k_ == 4 and set(sil.k_scores_) == {2, 3, 4, 5, 6}
    bic = StyleClusterer(choose_k="bic", k_range=(2, 6)).fit(X)
    assert bic.k_ == 4
    assert sil.names_ == ["Defensive", "Normal 1", "Normal 2", "Aggressive"]


def test_style_names():
    assert style_names(3) == ["Defensive", "Normal", "Aggressive"]
    assert style_names(2) == ["Defensive", "Aggressive"]
    assert style_names(5)[1:4] == ["Normal 1", "Normal 2", "Normal 3"]


@pytest.mark.slow
def test_choose_k_through_settings(synthetic):
    df, _, _ = synthetic
    out = analyze_tables(df, AnalysisSettings(features="ttc", choose_k="silhouette", k_range=(2, 5), n_bootstrap=0))
    assert len(out["k_scores"]) == 4
    assert out["styles"]["cluster"].max() + 1 == out["k_scores"].loc[out["k_scores"]["score"].idxmax(), "k"]


@pytest.mark.slow
def test_the_consensus_chooses_k_too(synthetic):
    """`choose_k` with the default features: the consensus at each k, the best separated kept."""
    df, truth, _ = synthetic
    out = analyze_tables(df, AnalysisSettings(choose_k="silhouette", k_range=(2, 5), n_bootstrap=0))
    assert sorted(out["k_scores"]["k"]) == [2, 3, 4, 5]
    best = int(out["k_scores"].loc[out["k_scores"]["score"].idxmax(), "k"])
    assert out["styles"]["style"].nunique() == best == 3
    st = out["styles"]
    assert adjusted_rand_score([truth[d] for d in st["driver_id"]], st["style"]) == 1.0


@pytest.mark.slow
def test_bic_picks_three_styles_on_few_drivers(synthetic):
    df, truth, _ = synthetic
    out = analyze_tables(df, AnalysisSettings(choose_k="bic", n_bootstrap=0))
    st = out["styles"]
    assert st["cluster"].max() + 1 == 3
    assert adjusted_rand_score([truth[d] for d in st["driver_id"]], st["style"]) == 1.0
