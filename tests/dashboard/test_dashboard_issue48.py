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
