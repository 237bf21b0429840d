"""Readable plots (issue 48): log ticks written as values, learning curves judged at their end."""

import numpy as np
import pandas as pd

from laneprint.plotting import log_ticks, plateau_judgement


def test_log_ticks_are_values_not_minor_digits():
    t = log_ticks([0.5, 0.62, 0.9, 1.3])
    assert {"0.5", "0.6", "0.7", "0.8", "0.9", "1"} <= set(t["ticktext"]) and t["tickvals"][2] == 0.6
    wide = log_ticks([0.3, 40.0])
    assert wide["ticktext"] == ["0.5", "1", "2", "5", "10", "20", "50"]
    assert len(log_ticks([0.01, 4000])["tickvals"]) <= 9
    assert log_ticks([np.nan, -1]) == {}


def test_following_figures_label_their_log_ticks():
    from clustering.plots import following_headways
    from indicators.plots import following_vs_speed

    f = pd.DataFrame(
        {
            "driver_id": ["D1"] * 4,
            "thw_s": [0.55, 0.7, 0.8, 0.95],
            "ego_v_mps": [20.0] * 4,
            "f_gap_m": [12.0] * 4,
            "duration_s": [10.0] * 4,
        }
    )
    styles = pd.DataFrame({"driver_id": ["D1"], "style": ["Normal"], "cluster": [0]})
    for fig in (following_vs_speed(f, "D1"), following_headways(f, styles)):
        y = fig.to_plotly_json()["layout"]["yaxis"]
        assert y["type"] == "log" and y["tickmode"] == "array" and "0.6" in y["ticktext"]


def test_plateau_judgement():
    rng = np.random.default_rng(0)
    flat = np.r_[np.linspace(0, 1, 500), np.ones(500)] + rng.normal(0, 0.05, 1000)
    assert plateau_judgement(flat)[0] == "plateau"
    rising = np.linspace(0, 1, 1000) + rng.normal(0, 0.05, 1000)
    state, text = plateau_judgement(rising)
    assert state == "rising" and "more episodes" in text
    assert plateau_judgement(np.ones(5))[0] == "short"


def test_training_curves_say_whether_the_reward_levelled_off():
    from rl.plots import training_curves

    n = 400
    m = pd.DataFrame(
        {"episode": np.arange(1, n + 1), "loss": np.linspace(1, 0.1, n), "mean_step_reward": np.linspace(0, 1, n)}
    )
    fig = training_curves(m)
    assert "still rising" in fig.layout.meta["plateau"] and "still rising" in fig.layout.title.text
    raw = [t for t in fig.data if "per episode" in t.name]
    assert raw and all(t.opacity < 1 for t in raw)  # the raw values faint behind the smoothed line
