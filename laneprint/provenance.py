"""Which analysis a result was made from, and whether it is still the current one.

A run (train or personalise), a cross-validation and the report record
`analysis_fingerprint` (`laneprint.workspace.analysis_fingerprint`: a hash of the analysis's
styles and reference lines, written into `analysis/meta.json` when the analysis is saved).
`analysis_mark` compares a result's fingerprint with the workspace's current one; `runs`, the
Results page and the report show its label beside the result.
"""

from __future__ import annotations

from typing import Any

CURRENT = "current"
EARLIER = "earlier"
UNKNOWN = "unknown"

LABELS = {
    CURRENT: "made with the current analysis",
    EARLIER: "made with an earlier analysis: re-run",
    UNKNOWN: "analysis unknown",
}


def analysis_mark(recorded: str | None, current: str | None) -> dict[str, Any]:
    """`{"analysis": 'current' | 'earlier' | 'unknown', "analysis_label": ..., "analysis_fingerprint":
    recorded, "current_analysis_fingerprint": current}`. A result without a fingerprint (made before
    results recorded one) is 'unknown'; one whose fingerprint differs from the current analysis's (or
    when there is no analysis any more) is 'earlier'."""
    if not recorded:
        state = UNKNOWN
    elif recorded == current:
        state = CURRENT
    else:
        state = EARLIER
    return {
        "analysis": state,
        "analysis_label": LABELS[state],
        "analysis_fingerprint": recorded or None,
        "current_analysis_fingerprint": current,
    }


def stale(mark: dict[str, Any]) -> bool:
    """True when the result is marked as made with another analysis than the current one."""
    return mark.get("analysis") == EARLIER
