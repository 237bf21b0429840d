"""A driver's decisions in time order: the first K, and the sessions held out after them.

The decisions table has no wall-clock time across recordings (each recording's
clock starts at 0), so sessions are ordered by their session id (the study names
them by the section driven, ``D01_S60`` .. ``D01_S90``; a dashboard upload is the
session it is given), then by the press time within a session.
"""

from __future__ import annotations

import pandas as pd

from laneprint.errors import SettingError, UserError


def driver_rows(decisions: pd.DataFrame, driver: str) -> pd.DataFrame:
    """All rows of one driver; a one-line error when the analysis has none."""
    rows = decisions[decisions["driver_id"].astype(str) == str(driver)]
    if rows.empty:
        known = sorted(decisions["driver_id"].astype(str).unique())
        shown = ", ".join(known[:12]) + (" ..." if len(known) > 12 else "")
        raise UserError(f"no driver {driver!r} in the analysis (drivers: {shown or 'none'})")
    return rows


def decision_order(rows: pd.DataFrame) -> list[str]:
    """Decision ids of `rows`' presses in time order (session id, then press time)."""
    presses = rows[rows["label"] == "change"]
    order = presses.sort_values(["session_id", "press_t_s", "decision_id"], kind="stable")
    return list(dict.fromkeys(order["decision_id"].astype(str)))


def session_order(rows: pd.DataFrame) -> list[str]:
    """Recording ids of `rows` in time order (by session id)."""
    first = rows.groupby("recording_id", sort=False)["session_id"].first().astype(str)
    return list(first.sort_values(kind="stable").index.astype(str))


def first_decisions(rows: pd.DataFrame, k: int | None) -> pd.DataFrame:
    """The rows (press and not-yet states) of the first `k` decisions of `rows` (None: all of them)."""
    order = decision_order(rows)
    if k is not None:
        if k < 1:
            raise SettingError(f"{{0}} must be at least 1, got {k}", "decisions")
        if k > len(order):
            raise SettingError(f"{{0}} {k}: the driver has {len(order)} decisions", "decisions")
        order = order[:k]
    return rows[rows["decision_id"].astype(str).isin(set(order))]


def holdout_split(rows: pd.DataFrame, test_sessions: int = 1) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(earlier sessions, the last `test_sessions` sessions) of one driver's rows."""
    sessions = session_order(rows)
    if len(sessions) <= test_sessions:
        raise UserError(f"{len(sessions)} session(s): nothing left to learn from after holding out {test_sessions}")
    held = set(sessions[-test_sessions:])
    is_held = rows["recording_id"].astype(str).isin(held)
    return rows[~is_held], rows[is_held]
