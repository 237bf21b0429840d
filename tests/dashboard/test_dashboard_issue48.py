"""What a researcher sees (issue 48) without a browser: who made a drive's lane changes and which learner
`auto` kept in the report; the figures' axes on a study with TTCs of minutes."""

from __future__ import annotations

import json

from laneprint.workspace import Workspace


def _drive(ws: Workspace, name: str = "normal-s0") -> dict:
    row = {"speed_limit_kph": 80.0, "lane_changes": 28, "agent_changes": 0, "rule_changes": 28,
           "return_changes": 8, "made_by": {"agent": 0, "rule_held_back": 20, "rule_return": 8, "unattributed": 0}}
    drive = {"run_id": "normal", "lanes": 2, "seed": 0, "sections": [row], "totals": dict(row),
             "who_drove": {"text": "Who changed lane: 28 lane changes: the agent 0, the rule 28 (held back 20, "
                                   "return 8); no lane change was the agent's: the assistant's rule made them all."}}
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
    (name, table), = [x for k, x in sec.items if k == "table"]
    assert name == "drive_normal-s0_made_by" and table["rule: held back"].tolist() == [20, 20]


CHOICE_CONFIG = {"run_id": "auto1", "target": {"kind": "style", "name": "Normal"}, "reward": "timing",
                 "lines_source": "analysis", "seed": 0, "learner": "dqn",
                 "auto": {"margin": 0.01, "folds": 3},
                 "lines": {"t_f": [0.3, -1.0], "t_nf": [0.3, -1.5], "dv_nb": [0.1, -1.0]},
                 "learner_choice": {"learner": "dqn", "scores": {"dqn": 0.805, "trees": 0.773}, "n_train": 360,
                                    "n_holdout": 360, "folds": 3,
                                    "by_side": {"dqn": {"left": 0.82, "right": 0.79},
                                                "trees": {"left": 0.8, "right": float("nan")}},
                                    "stopped": "", "checks": []}}


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
