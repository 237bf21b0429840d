"""Decision points of one recording: button presses and the 'not yet' states before them.

A decision is a rising edge of `lc_button`. Its target lane is the lane the ego
occupies after the lane change that follows (within `lane_change_lookahead_s` and
before the next press); when the ego never leaves its lane the press is
`cancelled` and the target comes from `lc_direction` (left = lane + 1). Before each
press, states every `step_s` back over the approach (to the previous lane change
end, the previous press, the recording start, or `max_approach_s`, and, with
`same_leader_approach`, only while the ego-lane leader is the press's leader)
are labelled 'keep'.

At every state the scene is read as: the ego's latest sample at or before the
state's time and, per traffic vehicle, its latest sample at or before it (at most
`traffic_tolerance_s` old), both carried forward to the state's time with their
speeds (no change when the clocks are shared, as in CSV logs). Then
`C_f` = nearest vehicle ahead in the ego lane, `C_nf` / `C_nb` = nearest ahead /
behind (or alongside) in the target lane; gap = |dx| - (len_a + len_b) / 2;
TTC = max(gap, 0) / (v_ego - v_other) when closing, else NaN with status
'not_closing'; no vehicle: NaN with status 'absent'. `dv_nb` = v_ego - v_nb, with
status 'far' (value kept) when the follower's gap exceeds `far_follower_m`. The
indicators of what the driver accepts (gaps, headways, relative speeds, each with a
status) are added by `indicators.acceptance`.

In a lane with a neighbour on each side (the middle lane of three) the driver could
have gone the other way too: `other_lane` is that lane (the mirror of the target
lane), and `other_nf_*` / `other_nb_*` its nearest vehicles ahead / behind, read as
`C_nf` / `C_nb` are (`OTHER_SIDE`). A lane exists when some vehicle of the recording
(ego or traffic) drives in it; elsewhere `other_lane` is -1 and the vehicles absent.

Everything is computed for all states of a recording at once (vectorised).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from indicators.acceptance import DERIVED_COLUMNS, add_acceptance
from indicators.settings import AnalysisSettings
from indicators.speed import free_speed
from indicators.stats import fit_reasons
from laneprint.schemas import DECISIONS, Column, Schema

#: The other side of a middle lane at every state: the lane the driver could have changed
#: to instead of `target_lane`, and its vehicles (what `rl.problem.env.approaches_from_decisions`
#: turns into the side not taken). Tables analysed before these columns lack them.
OTHER_SIDE = Schema(
    "decision_other_side",
    "In a lane with neighbours on both sides, the neighbouring lane opposite the target lane and "
    "its nearest vehicles ahead and behind, read as C_nf / C_nb are.",
    (
        Column(
            "other_lane",
            "int",
            "the ego lane's other neighbour (2 * ego_lane - target_lane); -1 where the ego lane has none",
        ),
        Column("other_nf_present", "bool", "a leader in the other lane"),
        Column("other_nf_x_m", "float", "[m]", nullable=True),
        Column("other_nf_v_mps", "float", "[m/s]", nullable=True),
        Column("other_nf_gap_m", "float", "bumper-to-bumper gap [m]", nullable=True),
        Column("other_nf_id", "str", "", nullable=True),
        Column("other_nb_present", "bool", "a follower (behind or alongside) in the other lane"),
        Column("other_nb_x_m", "float", "[m]", nullable=True),
        Column("other_nb_v_mps", "float", "[m/s]", nullable=True),
        Column("other_nb_gap_m", "float", "bumper-to-bumper gap [m]", nullable=True),
        Column("other_nb_id", "str", "", nullable=True),
    ),
)

#: Columns added to the DECISIONS contract by this stage.
EXTRA_COLUMNS: tuple[str, ...] = (
    "ego_v_free_mps",  # the ego's free speed over its recording [m/s] (`indicators.speed.free_speed`)
    "drive_s",  # how long its recording drove [s]: the exposure of the lane-change rate (`clustering.behaviour`)
    "press_index",
    "lc_direction",
    "lane_change_t_s",
    "f_id",
    "nf_id",
    "nb_id",
    "t_f_reason",
    "t_nf_reason",
    "dv_nb_reason",
) + tuple(OTHER_SIDE.names)
COLUMNS: list[str] = DECISIONS.names + list(EXTRA_COLUMNS) + list(DERIVED_COLUMNS)


def empty_decisions() -> pd.DataFrame:
    """A decisions table with no rows and the right columns/dtypes."""
    kinds = {c.name: c.kind for c in DECISIONS.columns}
    dtypes = {"float": "float64", "int": "int64", "bool": "bool", "str": "object"}
    cols = {name: pd.Series(dtype=dtypes[kind]) for name, kind in kinds.items()}
    cols.update(
        {
            "ego_v_free_mps": pd.Series(dtype="float64"),
            "drive_s": pd.Series(dtype="float64"),
            "press_index": pd.Series(dtype="int64"),
            "lc_direction": pd.Series(dtype="object"),
            "lane_change_t_s": pd.Series(dtype="float64"),
            "f_id": pd.Series(dtype="object"),
            "nf_id": pd.Series(dtype="object"),
            "nb_id": pd.Series(dtype="object"),
        }
    )
    cols.update({f"{ind}_reason": pd.Series(dtype="object") for ind in ("t_f", "t_nf", "dv_nb")})
    cols.update({c.name: pd.Series(dtype=dtypes[c.kind]) for c in OTHER_SIDE.columns})
    cols.update({c: pd.Series(dtype="object" if c.endswith("_status") else "float64") for c in DERIVED_COLUMNS})
    return pd.DataFrame(cols)[COLUMNS]


def _skip(what: str, id_: str, reason: str) -> dict[str, str]:
    return {"what": what, "id": id_, "reason": reason}


def _lane_change_ends(
    ego: pd.DataFrame, t: np.ndarray, lane_events: np.ndarray, settings: AnalysisSettings
) -> np.ndarray:
    """Time each lane change ends: the first sample after the lane flip whose lateral speed is
    below `settled_lateral_mps` (when ego_y is logged), else the flip + `settle_s`."""
    fallback = t[lane_events] + settings.settle_s if len(lane_events) else np.array([])
    if "ego_y_m" not in ego.columns or len(lane_events) == 0:
        return fallback
    y = ego["ego_y_m"].to_numpy(dtype=float)
    if np.isnan(y).any() or len(y) < 3:
        return fallback
    dy = np.gradient(y, t)
    still = np.flatnonzero(np.abs(dy) < settings.settled_lateral_mps)
    k = np.searchsorted(still, lane_events, side="left")
    ends = np.where(k < len(still), t[still[np.minimum(k, len(still) - 1)]], np.inf)
    # a lateral move that never settles within max_settle_s: fall back
    return np.where(ends - t[lane_events] <= settings.max_settle_s, ends, fallback)


def find_presses(ego: pd.DataFrame, settings: AnalysisSettings) -> tuple[pd.DataFrame, list[dict[str, str]]]:
    """One row per rising edge of the button: press time, lane, target lane, cancelled.

    Returns (presses, skipped); a press whose target lane cannot be told is skipped
    with its reason (it keeps its `press_index`, so decision ids stay stable).
    """
    t = ego["t_s"].to_numpy(dtype=float)
    btn = ego["lc_button"].to_numpy(dtype=bool)
    lane = ego["ego_lane"].to_numpy(dtype=np.int64)
    prev = np.r_[False, btn[:-1]]
    press_idx = np.flatnonzero(btn & ~prev)
    lane_events = np.flatnonzero(lane[1:] != lane[:-1]) + 1  # first sample in the new lane
    settled = _lane_change_ends(ego, t, lane_events, settings)
    direction = ego["lc_direction"] if "lc_direction" in ego.columns else pd.Series([None] * len(ego))
    direction = direction.astype(object).where(direction.notna(), None).to_numpy()
    # end of each held span, to read the direction anywhere while the button is held
    release_idx = np.flatnonzero(~btn & prev)

    rows, skipped = [], []
    for i, p in enumerate(press_idx):
        t_press = t[p]
        t_next = t[press_idx[i + 1]] if i + 1 < len(press_idx) else np.inf
        horizon = min(t_press + settings.lane_change_lookahead_s, t_next)
        k = np.searchsorted(lane_events, p, side="right")
        changed = k < len(lane_events) and t[lane_events[k]] <= horizon and t[lane_events[k]] < t_next
        r = np.searchsorted(release_idx, p, side="right")
        end = release_idx[r] if r < len(release_idx) else len(t)
        dirs = [d for d in direction[p:end] if d in ("left", "right")]
        d = dirs[0] if dirs else None
        # the last lane change before the press bounds the approach
        k_before = np.searchsorted(lane_events, p, side="right") - 1
        last_lc = settled[k_before] if k_before >= 0 else -np.inf
        row = {
            "press_index": i,
            "sample": int(p),
            "press_t_s": t_press,
            "ego_lane": int(lane[p]),
            "lc_direction": d,
            "last_lane_change_t_s": last_lc,
            "prev_press_t_s": t[press_idx[i - 1]] if i > 0 else -np.inf,
        }
        if changed:
            j = lane_events[k]
            row.update(target_lane=int(lane[j]), cancelled=False, lane_change_t_s=t[j])
        elif d is not None:
            row.update(target_lane=int(lane[p]) + (1 if d == "left" else -1), cancelled=True, lane_change_t_s=np.nan)
        else:
            skipped.append(
                (
                    "press",
                    i,
                    f"no lane change within {settings.lane_change_lookahead_s:g} s "
                    "of the press and no lc_direction recorded: target lane unknown",
                )
            )
            continue
        if row["target_lane"] < 0:
            skipped.append(("press", i, "target lane would be right of lane 0 (lc_direction 'right' in lane 0)"))
            continue
        rows.append(row)
    cols = [
        "press_index",
        "sample",
        "press_t_s",
        "ego_lane",
        "lc_direction",
        "last_lane_change_t_s",
        "prev_press_t_s",
        "target_lane",
        "cancelled",
        "lane_change_t_s",
    ]
    skipped_rows = [_skip("decision", str(idx), reason) for _, idx, reason in skipped]
    return pd.DataFrame(rows, columns=cols), skipped_rows


def _state_times(presses: pd.DataFrame, t0: float, settings: AnalysisSettings) -> pd.DataFrame:
    """The press itself plus keep states every step_s back over the approach."""
    press_t = presses["press_t_s"].to_numpy()
    start = np.maximum.reduce(
        [
            np.full(len(presses), t0),
            press_t - settings.max_approach_s,
            presses["last_lane_change_t_s"].to_numpy(),
            presses["prev_press_t_s"].to_numpy() + 1e-6,  # after (not at) the previous press
        ]
    )
    n_keep = np.floor((press_t - start) / settings.step_s + 1e-9).astype(int)
    n_keep = np.clip(n_keep, 0, None)
    # states: k = 0 (the press) .. n_keep (earliest keep state)
    reps = n_keep + 1
    which = np.repeat(np.arange(len(presses)), reps)
    k = np.concatenate([np.arange(r) for r in reps]) if len(reps) else np.array([], dtype=int)
    t_state = press_t[which] - k * settings.step_s
    keep_ok = t_state >= start[which] - 1e-9
    out = pd.DataFrame({"p": which, "k": k, "t_s": t_state})
    return out[keep_ok | (k == 0)].reset_index(drop=True)


def _nearest(cands: pd.DataFrame, key: str, ascending: bool) -> pd.DataFrame:
    """Per state, the candidate with the smallest (ascending) or largest dx."""
    c = cands.sort_values(["state", key], ascending=[True, ascending], kind="mergesort")
    return c.drop_duplicates("state", keep="first").set_index("state")


def ego_at(states: pd.DataFrame, ego: pd.DataFrame) -> pd.DataFrame:
    """`states` (columns `state`, `t_s`, ...) joined with the ego's latest sample at or before
    each state's time, its position carried forward to that time with its speed; in `state` order."""
    e = pd.merge_asof(
        states.sort_values("t_s"),
        ego.rename(columns={"t_s": "ego_t_s"}),
        left_on="t_s",
        right_on="ego_t_s",
        direction="backward",
    )
    e = e.sort_values("state").reset_index(drop=True)
    e["ego_x_m"] = e["ego_x_m"] + e["ego_v_mps"] * (e["t_s"] - e["ego_t_s"])
    return e


def latest_samples(
    states: np.ndarray, t_states: np.ndarray, tr: pd.DataFrame, n_vehicles: int, tolerance_s: float
) -> pd.DataFrame:
    """Every (state, vehicle) pair with that vehicle's latest sample at or before the state's time
    and at most `tolerance_s` old: columns state, t_s, vehicle_id, veh_t_s and `tr`'s x_m, v_mps,
    lane, length_m; pairs in time order of the states (stable), vehicles in code order.

    `tr` holds integer `vehicle_id` codes 0..n_vehicles-1, sorted by `t_s` (stable). This is
    `pd.merge_asof(by="vehicle_id", direction="backward", tolerance=tolerance_s)` of the states x
    vehicles grid, done as one `searchsorted` of the states' times per vehicle: the same pairs, the
    same sample among equal times (the last), faster on a long drive's grid."""
    order = np.argsort(t_states, kind="mergesort")
    q_t_sorted = t_states[order]
    q_state = np.repeat(states[order], n_vehicles)
    q_t = np.repeat(q_t_sorted, n_vehicles)
    q_code = np.tile(np.arange(n_vehicles, dtype=np.int64), len(states))
    code = tr["vehicle_id"].to_numpy(dtype=np.int64)
    t = tr["t_s"].to_numpy(dtype=float)
    by_vehicle = np.argsort(code, kind="mergesort")  # stable: each vehicle's samples stay in time order
    bounds = np.searchsorted(code[by_vehicle], np.arange(n_vehicles + 1))
    at = np.full((len(states), n_vehicles), -1, dtype=np.int64)  # row of tr per (state in time order, vehicle)
    for c in range(n_vehicles):
        rows = by_vehicle[bounds[c] : bounds[c + 1]]
        i = np.searchsorted(t[rows], q_t_sorted, side="right") - 1  # the last sample at or before (raw times)
        at[:, c] = np.where(i >= 0, rows[np.maximum(i, 0)], -1)
    at_flat = at.ravel()
    hit = at_flat >= 0
    row = np.where(hit, at_flat, 0)
    hit &= (q_t - t[row]) <= tolerance_s
    row = row[hit]
    return pd.DataFrame(
        {
            "state": q_state[hit],
            "t_s": q_t[hit],
            "vehicle_id": q_code[hit],
            "veh_t_s": t[row],
            "x_m": tr["x_m"].to_numpy(dtype=float)[row],
            "v_mps": tr["v_mps"].to_numpy(dtype=float)[row],
            "lane": tr["lane"].to_numpy(dtype=np.int64)[row],
            "length_m": tr["length_m"].to_numpy(dtype=float)[row],
        }
    )


def neighbours(
    e: pd.DataFrame, traffic: pd.DataFrame, settings: AnalysisSettings, only_leader: bool = False
) -> dict[str, np.ndarray]:
    """`C_f`, `C_nf`, `C_nb` at each state of `e` (an `ego_at` frame with `state` = 0..n-1 and a
    `target_lane` column): ``<role>_x_m``, ``<role>_v_mps``, ``<role>_gap_m`` (NaN when absent)
    and ``<role>_id`` (None), read as the module doc says. With an `other_lane` column also the
    roles ``other_nf`` / ``other_nb``, the same reading of that lane (absent where it is -1).
    `only_leader`: `C_f` alone (no `target_lane` needed)."""
    n = len(e)
    roles = (
        ("f",) if only_leader else ("f", "nf", "nb") + (("other_nf", "other_nb") if "other_lane" in e.columns else ())
    )
    cols: dict[str, Any] = {}
    for role in roles:
        cols[f"{role}_x_m"] = np.full(n, np.nan)
        cols[f"{role}_v_mps"] = np.full(n, np.nan)
        cols[f"{role}_gap_m"] = np.full(n, np.nan)
        cols[f"{role}_id"] = np.full(n, None, dtype=object)

    if len(traffic):
        # only the samples that can be the latest one before a state (within the tolerance)
        t_tr = traffic["t_s"].to_numpy(dtype=float)
        st_sorted = np.sort(e["t_s"].to_numpy(dtype=float))
        nxt = np.searchsorted(st_sorted, t_tr, side="left")
        near = nxt < len(st_sorted)
        near[near] = st_sorted[nxt[near]] - t_tr[near] <= settings.traffic_tolerance_s
        sub = traffic[near]
        # merge on integer codes: ids may come as any string dtype (object, arrow, python)
        codes, vids = pd.factorize(sub["vehicle_id"])
        tr = pd.DataFrame(
            {
                "t_s": t_tr[near],
                "x_m": sub["x_m"].to_numpy(dtype=float),
                "v_mps": sub["v_mps"].to_numpy(dtype=float),
                "lane": sub["lane"].to_numpy(dtype=np.int64),
                "length_m": sub["length_m"].to_numpy(dtype=float),
                "vehicle_id": codes.astype(np.int64),
            }
        )
        if len(tr) > 1 and np.any(np.diff(tr["t_s"].to_numpy()) < 0):
            tr = tr.sort_values("t_s", kind="mergesort")
        vid_names = np.asarray([str(v) for v in vids], dtype=object)
        m = latest_samples(
            e["state"].to_numpy(), e["t_s"].to_numpy(dtype=float), tr, len(vids), settings.traffic_tolerance_s
        )
        m["x_m"] = m["x_m"] + m["v_mps"] * (m["t_s"] - m["veh_t_s"])
        st = m["state"].to_numpy()
        m["dx"] = m["x_m"].to_numpy() - e["ego_x_m"].to_numpy()[st]
        m["gap"] = np.abs(m["dx"].to_numpy()) - (m["length_m"].to_numpy() + e["ego_length_m"].to_numpy()[st]) / 2
        lane_v = m["lane"].to_numpy()
        picks = {"f": _nearest(m[(lane_v == e["ego_lane"].to_numpy()[st]) & (m["dx"].to_numpy() > 0)], "dx", True)}
        if not only_leader:
            picks["nf"] = _nearest(
                m[(lane_v == e["target_lane"].to_numpy()[st]) & (m["dx"].to_numpy() > 0)], "dx", True
            )
            picks["nb"] = _nearest(
                m[(lane_v == e["target_lane"].to_numpy()[st]) & (m["dx"].to_numpy() <= 0)], "dx", False
            )
        if "other_lane" in e.columns and not only_leader:  # -1 matches no vehicle's lane
            other = lane_v == e["other_lane"].to_numpy()[st]
            picks["other_nf"] = _nearest(m[other & (m["dx"].to_numpy() > 0)], "dx", True)
            picks["other_nb"] = _nearest(m[other & (m["dx"].to_numpy() <= 0)], "dx", False)
        for role, pk in picks.items():
            idx = pk.index.to_numpy()
            cols[f"{role}_x_m"][idx] = pk["x_m"].to_numpy()
            cols[f"{role}_v_mps"][idx] = pk["v_mps"].to_numpy()
            cols[f"{role}_gap_m"][idx] = pk["gap"].to_numpy()
            cols[f"{role}_id"][idx] = vid_names[pk["vehicle_id"].to_numpy(dtype=np.int64)]
    return cols


def extract_decisions(
    meta: dict[str, Any], ego: pd.DataFrame, traffic: pd.DataFrame, settings: AnalysisSettings | None = None
) -> tuple[pd.DataFrame, list[dict[str, str]]]:
    """Decision points of one recording (DECISIONS columns + extras) and what was skipped.

    `meta` is the recording's RECORDINGS row (driver_id, recording_id, session_id,
    speed_limit_kph); `ego`/`traffic` are its EGO/TRAFFIC tables.
    """
    settings = settings or AnalysisSettings()
    rid = str(meta.get("recording_id", ""))
    if len(ego) == 0:
        return empty_decisions(), [_skip("recording", rid, "no ego samples")]
    ego = ego.sort_values("t_s", kind="mergesort").reset_index(drop=True)
    presses, skipped = find_presses(ego, settings)
    for s in skipped:
        s["id"] = f"{rid}:{s['id']}"
    if len(presses) == 0:
        if not skipped:
            skipped.append(_skip("recording", rid, "no lane-change button presses"))
        return empty_decisions(), skipped

    states = _state_times(presses, float(ego["t_s"].iloc[0]), settings)
    states["state"] = np.arange(len(states))
    e = ego_at(states, ego)
    p = presses.iloc[e["p"].to_numpy()].reset_index(drop=True)
    in_lane = (e["ego_lane"].to_numpy() == p["ego_lane"].to_numpy()) | (e["k"].to_numpy() == 0)
    e, p = e[in_lane].reset_index(drop=True), p[in_lane].reset_index(drop=True)
    e["state"] = np.arange(len(e))
    e["target_lane"] = p["target_lane"].to_numpy()
    e["other_lane"] = other_lanes(e["ego_lane"].to_numpy(), e["target_lane"].to_numpy(), n_lanes(ego, traffic))

    cols = neighbours(e, traffic, settings)

    v_e = e["ego_v_mps"].to_numpy(dtype=float)
    out = pd.DataFrame(
        {
            "driver_id": str(meta.get("driver_id", "")),
            "recording_id": rid,
            "session_id": str(meta.get("session_id", "")),
            "decision_id": [f"{rid}:{i}" for i in p["press_index"]],
            "t_s": e["t_s"].to_numpy(dtype=float),
            "press_t_s": p["press_t_s"].to_numpy(dtype=float),
            "label": np.where(e["k"].to_numpy() == 0, "change", "keep"),
            "speed_limit_kph": _float_or_nan(meta.get("speed_limit_kph")),
            "ego_v_mps": v_e,
            "ego_v_free_mps": free_speed(ego["ego_v_mps"].to_numpy(dtype=float)),
            "drive_s": float(ego["t_s"].iloc[-1] - ego["t_s"].iloc[0]),
            "ego_x_m": e["ego_x_m"].to_numpy(dtype=float),
            "ego_lane": e["ego_lane"].to_numpy(dtype=np.int64),
            "target_lane": p["target_lane"].to_numpy(dtype=np.int64),
            "cancelled": p["cancelled"].to_numpy(dtype=bool),
        }
    )
    for role in ("f", "nf"):
        present = ~np.isnan(cols[f"{role}_x_m"])
        closing = v_e - cols[f"{role}_v_mps"]
        with np.errstate(invalid="ignore", divide="ignore"):
            ttc = np.where(present & (closing > 0), np.maximum(cols[f"{role}_gap_m"], 0.0) / closing, np.nan)
        out[f"{role}_present"] = present
        out[f"{role}_x_m"] = cols[f"{role}_x_m"]
        out[f"{role}_v_mps"] = cols[f"{role}_v_mps"]
        out[f"{role}_gap_m"] = cols[f"{role}_gap_m"]
        out[f"t_{role}_s"] = ttc
        out[f"t_{role}_status"] = np.where(~present, "absent", np.where(closing > 0, "ok", "not_closing"))
    nb_present = ~np.isnan(cols["nb_x_m"])
    out["nb_present"] = nb_present
    out["nb_x_m"] = cols["nb_x_m"]
    out["nb_v_mps"] = cols["nb_v_mps"]
    out["nb_gap_m"] = cols["nb_gap_m"]
    out["dv_nb_mps"] = np.where(nb_present, v_e - cols["nb_v_mps"], np.nan)
    with np.errstate(invalid="ignore"):
        far = cols["nb_gap_m"] > settings.far_follower_m
    out["dv_nb_status"] = np.where(~nb_present, "absent", np.where(far, "far", "ok"))
    out["press_index"] = p["press_index"].to_numpy(dtype=np.int64)
    out["lc_direction"] = p["lc_direction"].to_numpy(dtype=object)
    out["lane_change_t_s"] = p["lane_change_t_s"].to_numpy(dtype=float)
    for role in ("f", "nf", "nb"):
        out[f"{role}_id"] = cols[f"{role}_id"]
    out["other_lane"] = e["other_lane"].to_numpy(dtype=np.int64)
    for role in ("other_nf", "other_nb"):
        out[f"{role}_present"] = ~np.isnan(cols[f"{role}_x_m"])
        for q in ("x_m", "v_mps", "gap_m", "id"):
            out[f"{role}_{q}"] = cols[f"{role}_{q}"]
    out = add_acceptance(out, settings)
    reasons = fit_reasons(out, settings)
    for ind in ("t_f", "t_nf", "dv_nb"):
        out[f"{ind}_reason"] = reasons[ind]
    if settings.same_leader_approach:
        out = _same_leader_run(out)
    out = out.sort_values(["press_index", "t_s"], kind="mergesort").reset_index(drop=True)
    return out[COLUMNS], skipped


def n_lanes(ego: pd.DataFrame, traffic: pd.DataFrame) -> int:
    """Lanes of a recording's road: one more than the highest lane any of its vehicles drives in."""
    top = int(ego["ego_lane"].max()) if len(ego) else 0
    if len(traffic):
        top = max(top, int(traffic["lane"].max()))
    return top + 1


def other_lanes(ego_lane: np.ndarray, target_lane: np.ndarray, lanes: int) -> np.ndarray:
    """Per state, the ego lane's neighbour opposite the target lane, or -1 where there is none."""
    other = 2 * np.asarray(ego_lane, np.int64) - np.asarray(target_lane, np.int64)
    ok = (other >= 0) & (other < lanes) & (other != ego_lane)
    return np.where(ok, other, -1)


def _same_leader_run(states: pd.DataFrame) -> pd.DataFrame:
    """Keep each press and the unbroken run of keep states before it whose ego-lane
    leader is the press's leader (all of them when the press has no leader)."""
    press_leader = states.loc[states["label"] == "change"].set_index("press_index")["f_id"]
    leader = states["press_index"].map(press_leader)
    same = (states["f_id"] == leader) | leader.isna() | (states["label"] == "change")
    newest_first = states.sort_values(["press_index", "t_s"], ascending=[True, False], kind="mergesort")
    unbroken = same.loc[newest_first.index].astype(int).groupby(newest_first["press_index"]).cumprod()
    return states.loc[unbroken.index[unbroken.to_numpy() == 1]]


def _float_or_nan(x: Any) -> float:
    try:
        return float(x) if x is not None else np.nan
    except (TypeError, ValueError):
        return np.nan
