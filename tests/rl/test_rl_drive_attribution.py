"""Who made each lane change of a drive (the agent, or the assistant's rule and which part of it): counted
per section and in total, said first by `laneprint drive`, in its JSON and by drives reported before."""

from rich.console import Console

from rl.drive.attribution import MADE_BY, made_by, made_by_counts, made_by_text, who_drove
from rl.drive.loop import Decision


def _decision(t: float, source: str, started: bool = True, target: int = 1) -> Decision:
    return Decision(
        t, 0, target, 25.0, None, None, None, {}, started=started, press_t_s=t + 0.2 if started else None, source=source
    )


def test_each_lane_change_is_the_press_of_the_decision_that_asked_for_it():
    decisions = [
        _decision(1.0, "agent"),
        _decision(5.0, "rule"),
        _decision(9.0, "return", target=0),
        _decision(12.0, "agent", started=False),
    ]
    made = [
        {"press_t_s": 1.2, "target_lane": 1},
        {"press_t_s": 5.2, "target_lane": 1},
        {"press_t_s": 9.2, "target_lane": 0},
        {"press_t_s": 20.0, "target_lane": 1},
    ]
    counts = made_by_counts(decisions, made)
    assert list(counts) == list(MADE_BY)
    assert counts == {"agent": 1, "rule_held_back": 1, "rule_return": 1, "unattributed": 1}


def test_who_drove_says_it_in_total_and_per_section():
    rows = [
        {"speed_limit_kph": 80.0, "made_by": {"agent": 0, "rule_held_back": 20, "rule_return": 8, "unattributed": 0}},
        {"speed_limit_kph": 90.0, "made_by": {"agent": 2, "rule_held_back": 0, "rule_return": 0, "unattributed": 0}},
    ]
    total = {"made_by": {k: sum(r["made_by"][k] for r in rows) for k in MADE_BY}}
    who = who_drove(rows, total, rule_on=True)
    assert who["total"]["agent"] == 2 and who["sections"]["80"]["rule_held_back"] == 20
    assert abs(who["agent_share"] - 2 / 30) < 1e-9
    assert who["text"].startswith(
        "Who changed lane: 30 lane changes: the agent 2, the rule 28 (held back 20, return 8)"
    )
    only_rule = who_drove(rows[:1], rows[0], rule_on=True)
    assert "no lane change was the agent's" in only_rule["text"]


def test_a_drive_reported_before_attribution_reads_from_its_counts():
    old = {"lane_changes": 28, "agent_changes": 0, "rule_changes": 28, "return_changes": 8}
    assert made_by(old) == {"agent": 0, "rule_held_back": 20, "rule_return": 8, "unattributed": 0}
    assert made_by_text(old) == "28 lane changes: the agent 0, the rule 28 (held back 20, return 8)"


def test_the_command_says_who_changed_lane_first():
    from rl.drive.cli import render

    row = {
        "speed_limit_kph": 80.0,
        "decisions_asked": 100,
        "change_decisions": 30,
        "lane_changes": 28,
        "left": 14,
        "right": 14,
        "agent_changes": 0,
        "rule_changes": 28,
        "return_changes": 8,
        "not_started": 2,
        "collisions": 0,
        "emergency_brakes": 0,
        "km": 4.0,
        "made_by": {"agent": 0, "rule_held_back": 20, "rule_return": 8, "unattributed": 0},
        "follow": {"held_share": 0.2, "longest_passed_up_s": 3.0},
    }
    result = {
        "run_id": "R",
        "target": {"kind": "style", "name": "Normal"},
        "sumo_version": "1.20",
        "minutes": 3,
        "seed": 0,
        "ego_style": "Normal",
        "decision_every_s": 0.5,
        "sections": [row],
        "totals": {**row, "follow": {"held_share": 0.2, "longest_passed_up_s": 3.0}},
        "who_drove": who_drove([row], row, rule_on=True),
        "held_back": {"note": "no rule"},
        "indicators": {
            "n_decisions": 0,
            "lines": {},
            **{
                k: {"n": 0, "median": None, "line_median": None, "mae": None, "bias": None}
                for k in ("t_f", "t_nf", "dv_nb")
            },
        },
        "files": [],
    }
    console = Console(record=True, width=200)
    render(result, console)
    text = console.export_text()
    assert text.lstrip().startswith("Who changed lane: 28 lane changes: the agent 0, the rule 28")
    assert "0 / 20 / 8" in text
