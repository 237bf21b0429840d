"""The run figures stay light for the browser however long the run or large the evaluation."""

import numpy as np
import pandas as pd

from rl.plots import MAX_CURVE_POINTS, MAX_MARKERS, decision_agreement, indicators_at_decisions, training_curves


def n_points(fig) -> int:
    return sum(len(t.x) for t in fig.data if t.x is not None)


def test_long_training_curves_are_thinned_but_keep_their_extremes():
    rng = np.random.default_rng(0)
    n = 100_000
    loss = rng.normal(1.0, 0.1, n)
    loss[77_777] = 9.0
    fig = training_curves(
        pd.DataFrame({"episode": np.arange(1, n + 1), "loss": loss, "mean_step_reward": rng.normal(size=n)}),
        smoothing=0.9,
    )
    assert {t.type for t in fig.data} == {"scatter"}  # SVG lines: no WebGL context per figure
    assert all(len(t.x) <= MAX_CURVE_POINTS for t in fig.data) and len(fig.data) == 4
    raw = fig.data[0]
    assert max(raw.y) == 9.0 and raw.x[0] == 1 and raw.x[-1] == n  # the spike and both ends survive
    short = training_curves(
        pd.DataFrame({"episode": [1, 2, 3], "loss": [3.0, 2.0, 1.0], "mean_step_reward": [0.0, 0.1, 0.2]}),
        smoothing=0.0,
    )
    assert list(short.data[0].y) == [3.0, 2.0, 1.0] and list(short.data[1].y) == [3.0, 2.0, 1.0]


def test_large_evaluations_draw_a_sample_and_count_everything():
    rng = np.random.default_rng(1)
    n = 18_000
    states = pd.DataFrame(
        {
            "v_e_mps": rng.uniform(15, 27, n),
            "t_f_s": rng.uniform(0, 10, n),
            "label": np.where(rng.random(n) < 0.3, "change", "keep"),
            "action_agent": rng.integers(0, 2, n),
        }
    )
    fig = decision_agreement(states, who="agent")
    same = int(((states["action_agent"] == 0) == (states["label"] == "change")).sum())
    assert n_points(fig) <= MAX_MARKERS and {t.type for t in fig.data} == {"scatter"}
    assert [t.name for t in fig.data] == [f"same decision ({same})", f"opposite decision ({n - same})"]
    assert f"{same / n:.1%} the same" in fig.layout.title.text and f"of {n} states drawn" in fig.layout.title.text
    assert n_points(decision_agreement(states.head(100))) == 100  # small: all drawn, nothing said
    assert "drawn" not in decision_agreement(states.head(100)).layout.title.text

    changes = pd.DataFrame(
        {
            "who": np.repeat(["agent", "greedy", "driver"], 3000),
            "v_e_mps": rng.uniform(15, 27, 9000),
            "t_f_s": rng.uniform(0, 9, 9000),
            "t_nf_s": rng.uniform(0, 9, 9000),
            "dv_nb_mps": rng.normal(size=9000),
        }
    )
    fig10 = indicators_at_decisions(changes, {"t_f": [0.1, 1.0], "t_nf": [0.1, 1.0], "dv_nb": [0.0, 0.0]})
    markers = [t for t in fig10.data if t.mode == "markers"]
    assert sum(len(t.x) for t in markers) <= MAX_MARKERS
    assert {t.name for t in markers if t.showlegend} == {"agent (3000)", "greedy (3000)", "driver (3000)"}
