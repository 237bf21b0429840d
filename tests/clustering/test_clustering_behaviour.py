"""Behaviour parameters (critical gaps by penalised maximum likelihood) and the held-out choice."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy import optimize

from clustering import behaviour as B
from clustering import choice as C
from clustering import readings as R


def gap_world(critical: dict[str, float], approaches: int = 40, seed: int = 0) -> pd.DataFrame:
    """Decision states of drivers who press at the first state whose lag headway exceeds their
    critical value times lognormal noise (0.15 in log units); 4 sessions each."""
    rng = np.random.default_rng(seed)
    rows = []
    for drv, crit in critical.items():
        for a in range(approaches):
            session = f"{drv}_S{a % 4}"
            for _k in range(40):
                thw = float(np.exp(rng.normal(np.log(1.5), 0.8)))
                press = thw > crit * np.exp(rng.normal(0, 0.15))
                rows.append(
                    {
                        "driver_id": drv,
                        "session_id": session,
                        "decision_id": f"{drv}:{a}",
                        "label": "change" if press else "keep",
                        "thw_nb_s": thw,
                    }
                )
                if press:
                    break
    return pd.DataFrame(rows)


def test_gradient_matches_finite_differences(monkeypatch):
    d = gap_world({"A": 0.6, "B": 2.0}, approaches=10)
    data = B.decision_data(d, ("thw_nb", "thw_f"))
    seen = {}
    real = optimize.minimize

    def spy(fun, x0, **kw):
        seen["f"], seen["x0"] = fun, x0
        return real(fun, x0, **kw)

    monkeypatch.setattr(B.optimize, "minimize", spy)
    B.fit_gap_model(data, data.driver)
    f = seen["f"]
    x = seen["x0"] + np.random.default_rng(1).normal(0, 0.3, len(seen["x0"]))
    _, grad = f(x)
    num = np.array([(f(x + e)[0] - f(x - e)[0]) / 2e-6 for e in np.eye(len(x)) * 1e-6])
    assert np.allclose(grad, num, atol=1e-4 * max(1.0, np.abs(num).max()))


def test_critical_values_recovered_with_standard_errors():
    truth = {"calm": 2.5, "mid": 1.2, "sporty": 0.5}
    b = B.driver_behaviour(gap_world(truth, approaches=60), None, list(truth))
    got = b.in_units()["thw_nb"]
    for drv, crit in truth.items():
        assert got[drv] == pytest.approx(crit, rel=0.25)
    assert (b.se["thw_nb"] > 0).all() and (b.se["thw_nb"] < 0.3).all()
    assert b.defined.loc["calm", "thw_nb"] == 60 and b.defined.loc["calm", "t_f"] == 0


def test_few_presses_give_wide_errors_and_are_pooled():
    d = gap_world({"many": 0.5, "few": 0.5, "other": 2.5}, approaches=60)
    d = d[~d["decision_id"].isin([f"few:{a}" for a in range(3, 60)])]
    b = B.driver_behaviour(d, None, ["many", "few", "other"])
    assert b.presses["few"] == 3
    assert b.se.loc["few", "thw_nb"] > 2 * b.se.loc["many", "thw_nb"]


def test_critical_values_need_gaps_let_pass():
    """A table of presses only (no not-yet state) does not place a critical gap: the values stay NaN."""
    d = gap_world({"calm": 2.5, "sporty": 0.5}, approaches=40)
    b = B.driver_behaviour(d[d["label"] == "change"], None, ["calm", "sporty"])
    assert b.values[list(B.VARIABLES)].isna().all().all() and (b.presses == 0).all()
    assert B.driver_behaviour(d, None, ["calm", "sporty"]).in_units().loc["calm", "thw_nb"] == pytest.approx(
        2.5, rel=0.25
    )


@pytest.mark.slow
def test_heldout_choice_prefers_the_parameter_that_tells_styles_apart():
    truth = (
        {f"a{i}": 0.5 * (1 + 0.05 * i) for i in range(3)}
        | {f"n{i}": 1.2 * (1 + 0.05 * i) for i in range(3)}
        | {f"d{i}": 2.6 * (1 + 0.05 * i) for i in range(3)}
    )
    d = gap_world(truth, approaches=24, seed=3)
    # a second variable that says nothing about the drivers: the leader's headway, pure noise
    d["thw_f_s"] = np.exp(np.random.default_rng(4).normal(0, 0.5, len(d)))
    drivers = sorted(truth)
    b = B.driver_behaviour(d, None, drivers)
    data = B.decision_data(d)
    best, scores, _ = R.choose_reading(
        b, data, drivers, 3, n_init=5, candidates={"thw_nb": ("thw_nb",), "thw_f": ("thw_f",)}
    )
    assert best == "thw_nb"
    chosen = next(s for s in scores if s.chosen)
    assert {chosen.labels[x] for x in ("d0", "d1", "d2")} == {"Defensive"}
    assert {chosen.labels[x] for x in ("a0", "a1", "a2")} == {"Aggressive"}


def test_session_folds_deal_each_drivers_sessions():
    driver = np.array(["A"] * 4 + ["B"] * 2, dtype=object)
    session = np.array(["s1", "s2", "s3", "s4", "t1", "t2"], dtype=object)
    assert R.session_folds(driver, session, 4).tolist() == [0, 1, 2, 3, 0, 1]


def test_succession_caps_confidence_of_few_presses():
    assert C.succession(3) == pytest.approx(0.8)
    assert C.succession(8) == pytest.approx(0.9)
    why = C.unsure_reasons("x", 3, 1.0, 1.0, [], None, ())  # type: ignore[arg-type]
    assert "only 3 presses" in why


def test_behaviour_params_parse_and_refuse():
    assert B.behaviour_params("behaviour:thw_nb+thw_follow") == ("thw_nb", "thw_follow")
    with pytest.raises(ValueError, match="unknown behaviour parameter"):
        B.behaviour_params("behaviour:nonsense")


def _three_styles_with_a_noise_variable(seed: int = 3):
    truth = (
        {f"a{i}": 0.5 * (1 + 0.05 * i) for i in range(3)}
        | {f"n{i}": 1.2 * (1 + 0.05 * i) for i in range(3)}
        | {f"d{i}": 2.6 * (1 + 0.05 * i) for i in range(3)}
    )
    d = gap_world(truth, approaches=24, seed=seed)
    d["thw_f_s"] = np.exp(np.random.default_rng(4).normal(0, 0.5, len(d)))  # says nothing about the drivers
    drivers = sorted(truth)
    return d, drivers, B.driver_behaviour(d, None, drivers)


def test_reliability_tells_a_trait_from_noise():
    _, drivers, b = _three_styles_with_a_noise_variable()
    rel = R.parameter_reliability(b, drivers)
    assert rel["thw_nb"] > 0.9
    assert not rel["thw_f"] > 0.5  # the drivers differ in it by estimation noise (or it is not estimated)
    assert R.most_reliable(b, drivers, 2)[0] == "thw_nb"


def test_a_parameter_counted_but_valued_for_few_drivers_is_not_usable():
    from dataclasses import replace

    _, drivers, b = _three_styles_with_a_noise_variable()
    values, defined = b.values.copy(), b.defined.copy()
    defined["thw_follow"] = 2  # every driver has following episodes ...
    values["thw_follow"] = np.nan  # ... but too few to read a headway from, for all but two
    values.loc[drivers[:2], "thw_follow"] = 0.0
    usable = R.usable_parameters(replace(b, values=values, defined=defined), drivers)
    assert "thw_follow" not in usable and "thw_nb" in usable


def test_separated_reads_the_styles_by_the_parameter_that_separates_them(monkeypatch):
    from indicators.settings import AnalysisSettings

    d, drivers, b = _three_styles_with_a_noise_variable()
    monkeypatch.setattr(C, "choose_features", lambda *a, **k: ("", []))  # no indicator set in this world
    points = pd.DataFrame()
    n_dec = pd.Series(24, index=drivers)
    choice = C.choose_separated(points, drivers, drivers, n_dec, b, AnalysisSettings(features="separated", n_init=5))
    assert choice.name.startswith("behaviour:") and "thw_nb" in choice.parameters
    chosen = next(s for s in choice.scores if s.chosen)
    assert {chosen.labels[x] for x in ("d0", "d1", "d2")} == {"Defensive"}
    assert {chosen.labels[x] for x in ("a0", "a1", "a2")} == {"Aggressive"}
    assert sum(s.plausible for s in choice.scores) == min(C.PLAUSIBLE_READINGS, len(choice.scores))
    ranked = [s.silhouette * s.stability for s in choice.scores]
    assert ranked == sorted(ranked, reverse=True)


def free_speed_decisions(free: dict[str, list[float]], limit_kph: float | None = 100.0) -> pd.DataFrame:
    """One decision state per recording: the driver's free speed there [m/s] and the posted limit."""
    return pd.DataFrame(
        [
            {
                "driver_id": d,
                "recording_id": f"{d}-{i}",
                "session_id": f"{d}_S{i}",
                "decision_id": f"{d}-{i}:0",
                "label": "change",
                "speed_limit_kph": limit_kph,
                "ego_v_free_mps": v,
            }
            for d, vs in free.items()
            for i, v in enumerate(vs)
        ]
    )


def test_free_speed_is_the_median_share_of_the_limit_over_recordings():
    limit = 100 / 3.6
    d = free_speed_decisions(
        {"calm": [0.9 * limit, 0.95 * limit, 0.92 * limit], "fast": [1.1 * limit, 1.2 * limit], "once": [1.0 * limit]}
    )
    value, se, recordings = B.free_speed_parameter(d, ["calm", "fast", "once", "absent"])
    assert np.exp(value["calm"]) == pytest.approx(0.92) and np.exp(value["fast"]) == pytest.approx(
        np.sqrt(1.1 * 1.2)
    )  # median of logs
    assert 0 < se["calm"] < 0.1 and recordings.to_dict() == {"calm": 3, "fast": 2, "once": 1, "absent": 0}
    assert np.isnan(value["once"]) and np.isnan(value["absent"])  # one recording says nothing of a spread


def test_free_speed_needs_every_recordings_limit():
    d = free_speed_decisions({"a": [25.0, 26.0], "b": [30.0, 31.0]}, limit_kph=None)
    assert B.free_speed_parameter(d, ["a", "b"])[0].isna().all()
    old = free_speed_decisions({"a": [25.0, 26.0]}).drop(columns="ego_v_free_mps")  # extracted before it existed
    assert B.free_speed_parameter(old, ["a"])[0].isna().all()


@pytest.mark.parametrize(
    "param, values",
    [("v_free", [0.9, 0.91, 1.0, 1.01, 1.1, 1.11]), ("lc_rate", [0.5, 0.55, 2.0, 2.1, 6.0, 6.3])],
)
def test_larger_drive_parameters_read_bolder(param, values):
    """A faster free speed and more lane changes name a driver bolder (`BOLD_PARAMETERS`)."""
    from clustering.styles import StyleClusterer

    X = pd.DataFrame({param: np.log(values)}, index=list("abcdef"))
    clf = StyleClusterer(k=3, random_state=0, room=[param]).fit(X)
    names = dict(zip(X.index, (clf.names_[i] for i in clf.labels_)))
    assert names["a"] == names["b"] == "Defensive" and names["e"] == names["f"] == "Aggressive"


def rate_decisions(presses: dict[str, list[int]], minutes: float = 5.0) -> pd.DataFrame:
    """Per recording, `presses` presses (each with one not-yet state before it) in `minutes` of driving."""
    rows = []
    for d, counts in presses.items():
        for i, n in enumerate(counts):
            for j in range(n):
                for label in ("keep", "change"):
                    rows.append(
                        {
                            "driver_id": d,
                            "recording_id": f"{d}-{i}",
                            "session_id": f"{d}_S{i}",
                            "decision_id": f"{d}-{i}:{j}",
                            "label": label,
                            "drive_s": 60.0 * minutes,
                        }
                    )
    return pd.DataFrame(rows)


def test_lane_change_rate_is_presses_per_minute_pooled_over_recordings():
    d = rate_decisions({"calm": [2, 3, 5], "sporty": [20, 30], "once": [10]})
    value, se, recordings = B.change_rate_parameter(d, ["calm", "sporty", "once", "absent"])
    assert np.exp(value["calm"]) == pytest.approx(10 / 15) and np.exp(value["sporty"]) == pytest.approx(50 / 10)
    assert se["calm"] > 0 and recordings.to_dict() == {"calm": 3, "sporty": 2, "once": 1, "absent": 0}
    assert np.isnan(value["once"]) and np.isnan(value["absent"])  # one recording says nothing of a spread
    old = d.drop(columns="drive_s")  # extracted before the decisions carried the drive time
    assert B.change_rate_parameter(old, ["calm"])[0].isna().all()
