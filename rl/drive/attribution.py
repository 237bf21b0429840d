"""Who made each lane change of a drive: the agent, or the assistant's rule and which part of it.

In `laneprint drive` the agent is asked every 0.5 s and its change is requested unless the assistant
around it holds it back (`rl.drive.loop.AgentControl.assist`). Two parts of the assistant's held-back rule
(`rl.drive.heldback`) request lane changes of their own: **held back** (a slower leader has held the ego
back for the target drivers' patience and a neighbouring lane is faster, with a gap they accept) and
**return** (an overtaking is over: back into the lane it left). Each decision says who asked for it
(`Decision.source`); each lane change in the log is the press of one started decision. A lane change no
decision asked for (SUMO's own, which the drive's lane-change mode should never allow) is counted apart.

Light on purpose (no torch, no SUMO): the command line's summary, the dashboard and the report read it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rl.drive.loop import Decision

#: who can make one of the drive's lane changes, in the order a summary names them: the agent, or the
#: assistant's rule by one of its two parts that request changes (`rl.drive.loop.AgentControl.assist`); the
#: rule's other parts (veto, floors, follower headway, dwell, undo check) only hold the agent's changes back
MADE_BY: dict[str, str] = {
    "agent": "the agent",
    "rule_held_back": "the rule, held back (a slower leader followed for its patience)",
    "rule_return": "the rule, return (an overtaking completed: back into the lane it left)",
    "unattributed": "no decision of the drive (SUMO's own: not requested)",
}
_SOURCE_KEY = {"agent": "agent", "rule": "rule_held_back", "return": "rule_return"}


def made_by_counts(decisions: list[Decision], made: list[dict[str, Any]]) -> dict[str, int]:
    """Who made each lane change `made` (the log's changes): the started decision whose press it is (its
    `source`), else 'unattributed'; every key of `MADE_BY`, in its order."""
    by_press = {(x.press_t_s, x.target_lane): x.source for x in decisions if x.started}
    out = dict.fromkeys(MADE_BY, 0)
    for c in made:
        out[_SOURCE_KEY.get(str(by_press.get((c["press_t_s"], c["target_lane"]))), "unattributed")] += 1
    return out


def made_by(row: dict[str, Any]) -> dict[str, int]:
    """A section's or total's `made_by` counts; from `agent_changes`, `rule_changes` and `return_changes`
    for a drive reported before lane changes were attributed one by one."""
    if isinstance(row.get("made_by"), dict):
        return {k: int(row["made_by"].get(k, 0)) for k in MADE_BY}
    agent, rule, back = (int(row.get(k) or 0) for k in ("agent_changes", "rule_changes", "return_changes"))
    return {
        "agent": agent,
        "rule_held_back": rule - back,
        "rule_return": back,
        "unattributed": max(0, int(row.get("lane_changes") or 0) - agent - rule),
    }


def made_by_text(row: dict[str, Any]) -> str:
    """'28 lane changes: the agent 0, the rule 28 (held back 20, return 8)' for a section or the total."""
    m = made_by(row)
    rule = m["rule_held_back"] + m["rule_return"]
    text = (
        f"{sum(m.values())} lane change{'' if sum(m.values()) == 1 else 's'}: the agent {m['agent']}, "
        f"the rule {rule} (held back {m['rule_held_back']}, return {m['rule_return']})"
    )
    return text + (f", not requested {m['unattributed']}" if m["unattributed"] else "")


def who_drove(rows: list[dict[str, Any]], total: dict[str, Any], rule_on: bool) -> dict[str, Any]:
    """Who made the drive's lane changes, in total and per section, with the agent's share and a sentence
    saying it (the first thing `laneprint drive` prints)."""
    m = made_by(total)
    n = sum(m.values())
    share = m["agent"] / n if n else None
    if not n:
        verdict = "no lane change was made"
    elif m["agent"] == n:
        verdict = "every lane change was the agent's"
    elif m["agent"] == 0:
        verdict = "no lane change was the agent's: the assistant's rule made them all"
    else:
        verdict = f"the agent made {share:.0%} of the lane changes, the assistant's rule the rest"
    return {
        "total": m,
        "agent_share": share,
        "rule_on": rule_on,
        "sections": {f"{r['speed_limit_kph']:g}": made_by(r) for r in rows},
        "text": f"Who changed lane: {made_by_text(total)}; {verdict}.",
    }
