"""What issue 23 item 10's speed-ups must keep: figures drawn only when opened, the same refusal from
cached tables as from the files, marker symbols as Plotly numbers that still mean open / filled. The
speed itself is measured by `benchmarks/dashboard.py` (medians, side by side), not here."""

import json

import numpy as np
import pandas as pd
from streamlit.testing.v1 import AppTest

from dashboard_support import page_path
from laneprint.plotting import symbol_codes


def charts(at: AppTest) -> list[dict]:
    return [json.loads(el.proto.spec) for el in at.get("plotly_chart")]


def test_run_comparison_curves_draw_once_opened(use_sample):
    at = AppTest.from_file(page_path("results"), default_timeout=60).run()
    assert not at.exception
    titles = [c["layout"].get("yaxis", {}).get("title", {}).get("text") for c in charts(at)]
    assert "loss [reward²]" not in titles  # closed: nothing drawn
    assert "Loss and reward curves of the two runs" in [e.label for e in at.expander]
    at.session_state["cmp_curves_open"] = True  # what opening the expander does
    at.run()
    assert not at.exception
    drawn = [
        c
        for c in charts(at)
        if c["layout"].get("yaxis", {}).get("title", {}).get("text") in ("loss [reward²]", "reward per step [1]")
    ]
    assert len(drawn) == 2 and all(len(c["data"]) == 2 for c in drawn)  # both runs on each


def test_training_page_caches_counts_not_the_decisions_and_agrees_with_the_command_line(use_sample):
    from dashboard import loaders, training
    from dashboard.jobs import TrainRequest
    from rl.cli import learning_checks
    from rl.problem.env import EnvConfig, formulation_config
    from rl.runs import Target
    from rl.settings import DQNSettings

    ws = use_sample
    cached = loaders.training_inputs.__wrapped__(str(ws.root), ())
    assert (
        "decisions" not in cached
        and len(cached["decision_counts"]) == ws.read_table("analysis", "decisions")["driver_id"].nunique()
    )
    req = TrainRequest("style", "Normal", 300, 0)
    verdict, why = training.learning_check(ws, req, tables=cached)
    assert (verdict, why) == training.learning_check(ws, req)
    env = formulation_config(EnvConfig().lines, None, None, None, "analysis")
    [(_, cli)] = learning_checks(
        ws, [Target("style", "Normal")], env, DQNSettings(episodes=300, episodes_per_approach=0.0)
    )
    assert verdict == "refuse" and cli.verdict == "never" and f"about {cli.expected:,.0f} transitions" in why


def test_symbol_numbers_keep_open_and_filled():
    assert symbol_codes(["circle", "circle-open", "triangle-up-open", "triangle-down", "diamond"]) == [
        0,
        100,
        105,
        6,
        2,
    ]


def test_fig11_marks_states_beyond_the_axis_open():
    from rl.plots import decision_agreement

    rng = np.random.default_rng(0)
    n = 300
    states = pd.DataFrame(
        {
            "label": np.where(np.arange(n) % 10 == 0, "change", "keep"),
            "action_agent": 1,
            "v_e_mps": rng.uniform(15, 27, n),
            "t_f_s": rng.uniform(2, 30, n),
        }
    )
    states.loc[[3, 4], "t_f_s"] = [5000.0, 20000.0]
    fig = decision_agreement(states)
    symbols = np.concatenate([np.asarray(t.marker.symbol) for t in fig.data])
    values = np.concatenate([np.asarray(t.customdata, dtype=float) for t in fig.data])
    assert set(symbols[values > 1000]) <= {105, 100} and (symbols[values > 1000] >= 100).all()
    assert (symbols[values < 100] < 100).all()  # on the axis: filled
