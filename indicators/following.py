"""Steady car following over the whole drive: the time headway a driver keeps.

At a press a driver is usually still closing in on its leader, and a calm driver
makes few presses: its gap at the presses is read from a handful of snapshots taken
in the middle of an approach. The headway a driver settles at behind a leader shows
all through the drive, press or not, and is the classic reading of a car-following
style (the desired time headway of IDM, the `tau` of Krauss).

Every `follow_step_s` the ego's leader `C_f` is read as at the decision states
(`indicators.decisions.neighbours`). A state is **steady following** when a leader
drives ahead in the ego lane, the ego is not slower than `follow_min_speed_mps`, the
gap is positive, |v_e - v_f| <= `follow_dv_mps`, and the ego is held back: slower than
`follow_below_free` times its free speed (`indicators.speed.free_speed`: a quantile of its speed over the
recording). A car ahead that happens to drive at the ego's own desired speed, however
far, is not followed: without that rule a sporty driver who seldom settles behind
anyone is read by such cars, at 3-5 s. Consecutive steady states behind
the same leader in the same lane make an **episode**; episodes shorter than
`follow_min_s` are dropped (a cut-in or a pass, not a headway settled at). Each
episode is one row: its median speed, gap and time headway (gap / v_e).

The driver's `thw_follow` level is the `FOLLOW_QUANTILE` quantile of its episodes'
headways (`clustering.features`): the short end. A steady state at the same speed
as a far leader is not always following (a car ahead that happens to drive at the
ego's desired speed), and those only ever lengthen the headway; the headway the
driver closes up to and holds is the lower quantile.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from indicators.settings import AnalysisSettings
from indicators.speed import free_speed
from laneprint.schemas import Column, Schema

#: The quantile of a driver's episode headways read as the headway it keeps.
FOLLOW_QUANTILE = 0.25

FOLLOWING = Schema(
    "following",
    "Episodes of steady car following over the whole drive (indicators/following.py): the ego "
    "holding its speed to a leader's in its lane for at least follow_min_s.",
    (
        Column("driver_id", "str", ""),
        Column("recording_id", "str", ""),
        Column("session_id", "str", ""),
        Column("episode_id", "str", "recording_id:f<n>"),
        Column("t_start_s", "float", "first steady state [s]"),
        Column("duration_s", "float", "last - first steady state + follow_step_s [s]"),
        Column("ego_lane", "int", ""),
        Column("f_id", "str", "the leader"),
        Column("ego_v_mps", "float", "median ego speed [m/s]"),
        Column("f_gap_m", "float", "median bumper-to-bumper gap [m]"),
        Column("dv_f_mps", "float", "median v_e - v_f [m/s]"),
        Column("thw_s", "float", "median time headway gap / v_e [s]"),
    ),
)
COLUMNS = [c.name for c in FOLLOWING.columns]


def empty_following() -> pd.DataFrame:
    """A following table with no episodes (the right columns and dtypes)."""
    return pd.DataFrame(
        {
            c.name: pd.Series(dtype="int64" if c.kind == "int" else "float64" if c.kind == "float" else object)
            for c in FOLLOWING.columns
        }
    )


def steady_states(ego: pd.DataFrame, traffic: pd.DataFrame, settings: AnalysisSettings) -> pd.DataFrame:
    """The ego's leader every `follow_step_s` of the drive and whether the state is steady
    following: columns t_s, ego_lane, ego_v_mps, f_gap_m, dv_f_mps, f_id, steady."""
    from indicators.decisions import ego_at, neighbours  # decisions imports this module's table

    ego = ego.sort_values("t_s", kind="mergesort").reset_index(drop=True)
    t = np.arange(float(ego["t_s"].iloc[0]), float(ego["t_s"].iloc[-1]) + 1e-9, settings.follow_step_s)
    e = ego_at(pd.DataFrame({"state": np.arange(len(t)), "t_s": t}), ego)
    cols = neighbours(e, traffic, settings, only_leader=True)
    v = e["ego_v_mps"].to_numpy(dtype=float)
    gap = cols["f_gap_m"]
    dv = v - cols["f_v_mps"]
    free = free_speed(v)
    with np.errstate(invalid="ignore"):
        steady = (
            np.isfinite(gap)
            & (gap > 0)
            & (v >= settings.follow_min_speed_mps)
            & (np.abs(dv) <= settings.follow_dv_mps)
            & (v < settings.follow_below_free * free)
        )
    return pd.DataFrame(
        {
            "t_s": t,
            "ego_lane": e["ego_lane"].to_numpy(dtype=np.int64),
            "ego_v_mps": v,
            "f_gap_m": gap,
            "dv_f_mps": dv,
            "f_id": cols["f_id"],
            "steady": steady,
        }
    )


def following_episodes(
    meta: dict[str, Any], ego: pd.DataFrame, traffic: pd.DataFrame, settings: AnalysisSettings | None = None
) -> pd.DataFrame:
    """Steady-following episodes of one recording (`FOLLOWING` columns), as the module doc says."""
    settings = settings or AnalysisSettings()
    if len(ego) < 2 or len(traffic) == 0:
        return empty_following()
    s = steady_states(ego, traffic, settings)
    steady = s["steady"].to_numpy()
    lead = s["f_id"].to_numpy(dtype=object)
    lane = s["ego_lane"].to_numpy()
    # runs of consecutive steady states behind the same leader in the same lane: [start, stop)
    same = (lead[1:] == lead[:-1]) & (lane[1:] == lane[:-1]) & steady[1:] & steady[:-1]
    starts = np.flatnonzero(steady & ~np.r_[False, same])
    stops = np.flatnonzero(steady & ~np.r_[same, False]) + 1
    t = s["t_s"].to_numpy()
    long_enough = t[stops - 1] - t[starts] + settings.follow_step_s >= settings.follow_min_s - 1e-9
    starts, stops = starts[long_enough], stops[long_enough]
    if len(starts) == 0:
        return empty_following()
    v, gap, dv = (s[c].to_numpy(dtype=float) for c in ("ego_v_mps", "f_gap_m", "dv_f_mps"))
    thw = gap / v

    def median(x: np.ndarray) -> list[float]:
        return [float(np.median(x[a:b])) for a, b in zip(starts, stops)]

    rid = str(meta.get("recording_id", ""))
    ep = pd.DataFrame(
        {
            "driver_id": str(meta.get("driver_id", "")),
            "recording_id": rid,
            "session_id": str(meta.get("session_id", "")),
            "episode_id": [f"{rid}:f{i}" for i in range(len(starts))],
            "t_start_s": t[starts],
            "duration_s": t[stops - 1] - t[starts] + settings.follow_step_s,
            "ego_lane": lane[starts].astype(np.int64),
            "f_id": [str(x) for x in lead[starts]],
            "ego_v_mps": median(v),
            "f_gap_m": median(gap),
            "dv_f_mps": median(dv),
            "thw_s": median(thw),
        }
    )
    return ep[COLUMNS]


def following_levels(following: pd.DataFrame) -> pd.DataFrame:
    """Per driver: its number of episodes and its `thw_follow` level [s] (the `FOLLOW_QUANTILE`
    quantile of its episodes' headways, on the log scale as the clustering reads it)."""
    if following is None or following.empty:
        return pd.DataFrame(
            {
                "driver_id": pd.Series(dtype=object),
                "episodes": pd.Series(dtype="int64"),
                "thw_follow_s": pd.Series(dtype=float),
            }
        )
    g = following.assign(log_thw=np.log(following["thw_s"].astype(float).clip(lower=0.05))).groupby(
        following["driver_id"].astype(str)
    )["log_thw"]
    return (
        pd.DataFrame({"episodes": g.size(), "thw_follow_s": np.exp(g.quantile(FOLLOW_QUANTILE))})
        .rename_axis("driver_id")
        .reset_index()
    )
