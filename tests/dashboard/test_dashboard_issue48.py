"""What a researcher sees (issue 48) without a browser: who made a drive's lane changes and which learner
`auto` kept in the report; the figures' axes on a study with TTCs of minutes."""

from __future__ import annotations

import json

import numpy as np
import pytest

from laneprint.workspace import Workspace


def _drive(ws: Workspace, name: str = "normal-s0") -> dict:
    row = {
        "speed_limit_kph": 80.0,
        "lane_changes": 28,
        "agent_changes": 0,
        "rule_changes": 28,
        "return_changes": 8,
        "made_by": {"agent": 0, "rule_held_back": 20, "rule_return": 8, "unattributed": 0},
    }
    drive = {
        "run_id": "normal",
        "lanes": 2,
        "seed": 0,
        "sections": [row],
        "totals": dict(row),
        "who_drove": {
            "text": "Who changed lane: 28 lane changes: the agent 0, the rule 28 (held back 20, "
            "return 8); no lane change was the agent's: the assistant's rule made them all."
        },
    }
    folder = ws.root / "drives" / name
    folder.mkdir(parents=True)
    (folder / "drive.json").write_text(json.dumps(drive))
    return drive


def test_report_says_who_made_each_lane_change_of_a_drive(tmp_path):
    from dashboard.report import _drives

    ws = Workspace(tmp_path / "ws").ensure()
    assert _drives(ws) == []
    _drive(ws)
    (sec,) = _drives(ws)
    texts = [x for k, x in sec.items if k == "p"]
    assert any("held back" in t and "acts" not in t and "return" in t for t in texts)
    assert any("the agent 0, the rule 28 (held back 20, return 8)" in t for t in texts)
    ((name, table),) = [x for k, x in sec.items if k == "table"]
    assert name == "drive_normal-s0_made_by" and table["rule: held back"].tolist() == [20, 20]


CHOICE_CONFIG = {
    "run_id": "auto1",
    "target": {"kind": "style", "name": "Normal"},
    "reward": "timing",
    "lines_source": "analysis",
    "seed": 0,
    "learner": "dqn",
    "auto": {"margin": 0.01, "folds": 3},
    "lines": {"t_f": [0.3, -1.0], "t_nf": [0.3, -1.5], "dv_nb": [0.1, -1.0]},
    "learner_choice": {
        "learner": "dqn",
        "scores": {"dqn": 0.805, "trees": 0.773},
        "n_train": 360,
        "n_holdout": 360,
        "folds": 3,
        "by_side": {"dqn": {"left": 0.82, "right": 0.79}, "trees": {"left": 0.8, "right": float("nan")}},
        "stopped": "",
        "checks": [],
    },
}


def test_learner_text_names_the_learner_kept_and_its_scores():
    from dashboard import views

    text = views.learner_text(CHOICE_CONFIG)
    assert text.startswith("Learner: DQN, kept by `auto`")
    assert "DQN 80.5 %, trees 77.3 %" in text and "3 inner folds" in text and "more than 1 points" in text
    assert "trees left 80.0 %, right not scored" in text
    assert views.learner_text({"learner": "trees"}) == "Learner: trees (asked for)."
    assert views.learner_text({}) == "Learner: DQN (asked for)."


def test_results_page_and_report_show_the_learner_kept(empty_ws):
    from streamlit.testing.v1 import AppTest

    from dashboard.report import _runs
    from dashboard_support import page_path, write_fake_run
    from laneprint.workspace import atomic_write_json

    ws = empty_ws.ensure()
    folder = write_fake_run(ws, "auto1")
    atomic_write_json(folder / "config.json", CHOICE_CONFIG)
    at = AppTest.from_file(page_path("results"), default_timeout=60).run()
    assert not at.exception, [e.value for e in at.exception]
    assert any("kept by `auto`" in c.value and "DQN 80.5 %, trees 77.3 %" in c.value for c in at.caption)
    sec = next(s for s in _runs(ws) if s.title == "Run auto1")
    assert any(k == "p" and "DQN 80.5 %, trees 77.3 %" in x for k, x in sec.items)


# --- every axis set by the bulk, asserted from the figures' JSON on a study with TTCs of minutes --------------


def _numbers(v) -> np.ndarray | None:
    if v is None:
        return None
    a = np.asarray(v, dtype=object).ravel()
    if not len(a) or not all(
        isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_)) for x in a
    ):
        return None
    return a.astype(float)


def axes_of(fig) -> list[tuple[str, np.ndarray, list | None]]:
    """(axis, its points' true values, its range) of every axis with marker points: a point drawn at an axis's
    edge carries its true value (customdata for y, the trace's meta 'x' for x); a log axis in log10 units."""
    found: dict[str, list] = {}
    for tr in fig.data:
        if tr.type not in ("scatter", "scattergl") or "markers" not in (tr.mode or ""):
            continue
        for letter in "xy":
            drawn = getattr(tr, letter)
            vals = _numbers(drawn)
            true = (
                _numbers(tr.customdata)
                if letter == "y"
                else _numbers((tr.meta or {}).get("x") if isinstance(tr.meta, dict) else None)
            )
            if true is not None and drawn is not None and len(true) == len(drawn):
                vals = true
            if vals is not None:
                found.setdefault(f"{letter}axis{(getattr(tr, f'{letter}axis') or letter)[1:]}", []).append(vals)
    out = []
    for name, parts in found.items():
        vals = np.concatenate(parts)
        vals = vals[np.isfinite(vals)]
        ax = fig.layout[name]
        if ax.type == "log":
            vals = np.log10(vals[vals > 0])
        out.append((name, vals, list(ax.range) if ax.range else None))
    return out


def bad_axes(figures: list[tuple[str, object]]) -> tuple[int, list]:
    """(axes checked, those whose range covers under 95 % of their points or is set by under 1 % of them)."""
    from laneprint.plotting import range_set_by_few

    checked, bad = 0, []
    for name, fig in figures:
        for axis, vals, rng in axes_of(fig):
            if len(vals) < 10:
                continue
            checked += 1
            lo, hi = rng if rng else (vals.min(), vals.max())  # no range: Plotly's autorange spans every point
            cover = float(((vals >= min(lo, hi) - 1e-9) & (vals <= max(lo, hi) + 1e-9)).mean())
            if cover < 0.95 or range_set_by_few(vals, (lo, hi), share=0.01, pad=0.08 if rng else 0.0):
                bad.append((name, axis, rng, len(vals), round(cover, 3), np.percentile(vals, [1, 50, 99]).round(2)))
    return checked, bad


def with_ttcs_of_minutes(ws: Workspace, share: float = 0.04) -> None:
    """`share` of every TTC in the analysis and in the runs' evaluation tables set to 1-10 minutes (a leader
    that hardly closes), as in the study a new user tried."""
    import pandas as pd

    from clustering.pipeline import analyze_tables

    rng = np.random.default_rng(1)
    dec = ws.read_table("analysis", "decisions")
    for col in ("t_f_s", "t_nf_s"):
        rows = dec.index[np.isfinite(dec[col])]
        pick = rng.choice(rows, size=max(2, int(len(rows) * share)), replace=False)
        dec.loc[pick, col] = rng.uniform(60, 600, len(pick))
    ws.write_tables("analysis", analyze_tables(dec), ws.read_meta("analysis"))
    for run in ws.runs_dir.iterdir():
        for name in ("eval_changes", "eval_states"):
            path = run / f"{name}.parquet"
            if path.exists():
                t = pd.read_parquet(path)
                for col in ("t_f_s", "t_nf_s"):
                    if col in t:
                        rows = np.flatnonzero(np.isfinite(t[col].to_numpy(dtype=float)))
                        pick = rng.choice(rows, size=max(2, int(len(rows) * share)), replace=False)
                        t.loc[t.index[pick], col] = rng.uniform(60, 600, len(pick))
                t.to_parquet(path)


def study_figures(ws: Workspace) -> list[tuple[str, object]]:
    """Every figure the report draws (the pages' own functions) and each run's Figs. 10 and 11 and curves."""
    from dashboard.report import build_report

    sections, _ = build_report(ws)
    return [item for sec in sections for kind, item in sec.items if kind == "figure"]


@pytest.mark.slow  # a study of its own and the report's figures: ~6 s
def test_every_axis_is_set_by_the_bulk_on_a_study_with_ttcs_of_minutes(sample_ws, tmp_path):
    import shutil

    for heavier in (False, True):  # the shipped study (t_f to ~3 min), then 4 % of every TTC at 1-10 min
        ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / f"ws{int(heavier)}"))
        if heavier:
            with_ttcs_of_minutes(ws)
        dec = ws.read_table("analysis", "decisions")
        assert np.nanmax(dec["t_f_s"]) > 120  # TTCs of minutes
        figures = study_figures(ws)
        checked, bad = bad_axes(figures)
        assert checked >= 15 and not bad, (heavier, bad)
        # a driver's dozen presses with a TTC of minutes among them: all on a log axis, the bulk not flattened
        logs = [f for name, f in figures if name.startswith("driver_") and f.layout.yaxis.type == "log"]
        assert logs and all("log axis" in f.layout.title.text for f in logs)


def test_a_log_axis_only_where_covering_the_points_would_flatten_the_bulk():
    from laneprint.plotting import needs_log_axis

    seconds = np.linspace(2.0, 4.0, 11)
    assert needs_log_axis(np.r_[seconds, 153.0])  # one of 12: covering 95 % means covering it
    assert not needs_log_axis(seconds) and not needs_log_axis(np.r_[seconds, -1.0, 153.0])  # negative: no log
    many = np.r_[np.linspace(2.0, 4.0, 200), 153.0]  # one of 201 may stay off the axis, at its edge
    assert not needs_log_axis(many)
