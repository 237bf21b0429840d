"""Heavy tails (issue 18 item 4, issue 23 items 2-6, 12): axes set by the bulk, formulas with proper
signs, figures that say what they cannot draw, training that cannot learn refused, the report."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from dashboard import figures, training, views
from laneprint.plotting import line_formula, range_set_by_few, tail_range


def heavy(n: int = 300, seed: int = 0) -> np.ndarray:
    """TTCs of 2-30 s with 3 % of them at 1,000-20,000 s (a leader that hardly closes)."""
    rng = np.random.default_rng(seed)
    v = rng.uniform(2, 30, n)
    v[rng.choice(n, size=max(1, n * 3 // 100), replace=False)] = rng.uniform(1000, 20000, max(1, n * 3 // 100))
    return v


def test_tail_range_is_set_by_the_bulk():
    v = heavy()
    lo, hi = tail_range(v)
    assert hi < 40 and lo > -3 and not range_set_by_few(v, (lo, hi))
    full = (v.min(), v.max())
    assert range_set_by_few(v, full)  # the check can fail: the plain range is set by the 3 %
    # few points: one TTC of 2500 s among 19 is 5 % of them, but far beyond the fence
    few = np.r_[np.linspace(5, 30, 19), 2500.0]
    assert tail_range(few)[1] < 40
    normal = np.random.default_rng(1).normal(size=2000)
    assert (np.abs(normal) > max(map(abs, tail_range(normal)))).mean() <= 0.01  # no tail: (almost) nothing cut


def test_formulas_print_their_signs():
    assert line_formula("t_f", 0.85, -6.92) == "t_f = 0.850 v_e − 6.92"
    assert line_formula("dv_nb", -0.1, 3.0) == "dv_nb = −0.100 v_e + 3.00"


def _drivers_decisions() -> tuple[pd.DataFrame, pd.DataFrame]:
    from indicators.stats import fit_lines
    from tests.support.synthetic_decisions import make_decision_table

    dec, _ = make_decision_table(3, 60, seed=4, keep_per_press=1)
    press = dec.index[(dec["driver_id"] == "D0000") & (dec["label"] == "change")]
    fits = fit_lines(dec)
    dec.loc[press[:3], "t_f_s"] = [2500.0, 20000.0, 900.0]  # used values far out
    return dec, fits


def test_indicator_vs_speed_tails_and_flags():
    from indicators.plots import indicator_vs_speed

    dec, fits = _drivers_decisions()
    fits = fits.copy()
    fits["flag"] = ""
    row = (fits["driver_id"] == "D0000") & (fits["indicator"] == "t_f")
    fits.loc[row, "flag"] = "R² 0.08 < 0.10; slope interval [-4.10, 3.53] spans 0"
    fig = indicator_vs_speed(dec, fits, "D0000", "t_f")
    values = dec.loc[(dec["driver_id"] == "D0000") & (dec["label"] == "change"), "t_f_s"]
    assert fig.layout.yaxis.range[1] < 100 and not range_set_by_few(values, fig.layout.yaxis.range)
    off = next(t for t in fig.data if t.name.startswith("used, off the axis"))
    assert off.name == "used, off the axis (3)" and sorted(off.customdata) == [900.0, 2500.0, 20000.0]
    title = fig.layout.title.text
    assert (" − " in title or " + " in title) and "+ -" not in title
    assert "flagged: R² 0.08 < 0.10" in title and "[s]" in title
    assert next(t for t in fig.data if t.name == "OLS line").line.dash == "dot"


def test_run_figures_tails_legend_and_headline():
    from rl.plots import decision_agreement, indicators_at_decisions

    rng = np.random.default_rng(2)
    n = 400
    changes = pd.DataFrame(
        {
            "who": np.repeat(["agent", "greedy", "driver"], [40, 160, 200]),
            "v_e_mps": rng.uniform(15, 27, n),
            "t_f_s": heavy(n, 3),
            "t_nf_s": heavy(n, 4),
            "dv_nb_mps": rng.normal(size=n),
        }
    )
    changes.loc[changes["who"] == "agent", ["t_f_s", "t_nf_s", "dv_nb_mps"]] = np.nan
    fig = indicators_at_decisions(changes, {"t_f": [0.4, -3.0], "t_nf": [0.2, 0.4], "dv_nb": [1.0, -9.0]})
    for axis, col in (("yaxis", "t_f_s"), ("yaxis2", "t_nf_s")):
        rng_ = fig.layout[axis].range
        assert rng_[1] < 100 and not range_set_by_few(changes[col], rng_), (axis, rng_)
    legend = {t.name for t in fig.data if t.showlegend}
    assert "agent (40), none with a defined indicator" in legend and "greedy (160)" in legend
    assert "off the axis" in fig.layout.annotations[0].text

    states = pd.DataFrame(
        {
            "v_e_mps": rng.uniform(15, 27, 1000),
            "t_f_s": heavy(1000, 5),
            "label": np.where(np.arange(1000) < 40, "change", "keep"),
            "action_agent": 1,
        }
    )
    fig11 = decision_agreement(states, who="agent")  # never changes: 96 % 'the same'
    title = fig11.layout.title.text
    assert title.startswith("Decisions of the agent vs the drivers (Fig. 11) — balanced accuracy 50.0%")
    assert "changed at 0.0% of 40 presses" in title and "96.0% the same" in title
    assert fig11.layout.yaxis.range[1] < 100 and not range_set_by_few(states["t_f_s"], fig11.layout.yaxis.range)
    compact = figures.compact(fig11).layout.title.text
    assert "drivers(" not in compact.replace("<br>", "")  # no words glued where a line was broken


def test_cluster_scatter_heavy_feature():
    from clustering.plots import cluster_scatter

    n = 120
    rng = np.random.default_rng(6)
    styles = pd.DataFrame(
        {
            "driver_id": [f"D{i:03d}" for i in range(n)],
            "style": "Normal",
            "cluster": 0,
            "confidence": 1.0,
            "n_decisions": 30,
            "is_typical": np.arange(n) == 0,
            "t_f_at_80kph_s": heavy(n, 7),
            "t_nf_at_80kph_s": rng.uniform(1, 9, n),
            "gap_f_at_80kph_m": rng.uniform(10, 60, n),
        }
    )
    fig = cluster_scatter(styles)
    assert fig.layout.xaxis.range[1] < 100 and not range_set_by_few(styles["t_f_at_80kph_s"], fig.layout.xaxis.range)
    assert "3 drivers beyond the axes" in fig.layout.title.text
    fig = cluster_scatter(styles, indicators=["gap_f", "t_nf"])
    assert fig.layout.xaxis.title.text == "gap_f at 80 km/h [m]"


def test_runs_curves_join_the_episodes_without_loss():
    loss = np.full(2000, np.nan)
    loss[::5] = 1.0
    fig = figures.runs_curves(
        {"long": pd.DataFrame({"episode": np.arange(1, 2001), "loss": loss})}, "loss", smoothing=0.0
    )
    assert not np.isnan(np.asarray(fig.data[0].y, dtype=float)).any() and len(fig.data[0].y) == 400
    assert fig.layout.yaxis.title.text == "loss [reward²]" and fig.layout.xaxis.title.text == "episode [-]"


def test_training_curves_say_why_there_is_no_loss():
    from rl.plots import training_curves

    m = pd.DataFrame(
        {"episode": np.arange(1, 301), "loss": np.nan, "mean_step_reward": 0.1, "env_steps": np.arange(1, 301) * 5}
    )
    fig = training_curves(m, learning_starts=2000)
    note = fig.layout.annotations[-1].text
    assert "learning starts after 2,000 transitions" in note and "1,500" in note
    assert "never learnt" in views.never_learnt(m, {"dqn": {"learning_starts": 2000}})
    assert views.never_learnt(m.assign(loss=1.0), {}) == ""


def test_training_that_cannot_learn_is_refused(use_sample):
    from dashboard.jobs import TrainRequest

    ws = use_sample
    verdict, why = training.learning_check(ws, TrainRequest("style", "Normal", 5, 0))
    assert verdict == "refuse" and "learning starts after 2,000" in why and "at least about" in why
    assert training.learning_check(ws, TrainRequest("style", "Normal", 100_000, 0)) == ("", "")


def test_plural_and_hints():
    assert views.plural(1, "driver") == "1 driver" and views.plural(3, "press", "presses") == "3 presses"
    assert views.cli_hint("ingest", "/w s", "sample_logs/") == "laneprint ingest sample_logs/ --workspace '/w s'"


@pytest.mark.slow
def test_report_command(sample_ws, tmp_path):
    out = tmp_path / "study.html"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "laneprint.app.cli",
            "report",
            "--workspace",
            str(sample_ws.root),
            "--out",
            str(out),
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    info = json.loads(res.stdout)
    text = out.read_text()
    assert info["figures"] >= 8 and text.count('class="plotly-graph-div"') == info["figures"]
    assert "<script src=" not in text and "cdn." not in text.split("</script>", 1)[1]  # nothing fetched
    assert (tmp_path / "study_files" / "fits.csv").exists() and (tmp_path / "study_files" / "recordings.csv").exists()
    assert (tmp_path / "study_files" / "headway_kept_in_steady_following.json").exists()  # the drive-long reading
    bad = subprocess.run(
        [sys.executable, "-m", "laneprint.app.cli", "report", "--workspace", str(tmp_path / "none")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 1 and bad.stderr.startswith("error: no workspace") and "Traceback" not in bad.stderr
