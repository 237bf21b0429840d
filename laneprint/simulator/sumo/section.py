"""One SUMO run: a driver in one section, logged at every step.

The ego is a SUMO vehicle of the driver's type: Krauss follows, LC2013 decides
every lane change (nothing is scripted), unless an `EgoControl` makes them (the
closed loop of `laneprint drive`, `rl/drive/loop.py`). At every step the ego's state, the
background vehicles within `scene_range_m` and the driver inputs are logged;
afterwards each lane change is found in the lateral trace and the lane-change
button is pressed at its start: the first sample at which the ego has left its
lane centre (SUMO moves it sideways from the step it commits), held for
`button_hold_s`, with the direction. The lane index flips half way through.

On sublanes (the `sublane` family: SL2015, `--lateral-resolution`) the ego is
seldom at its lane centre (it wanders with lcSigma, shifts within its lane, moves
to the lane edge and waits), and SUMO's lane index is the lane its centre is in.
There a lane change is a flip of that index, and its press is found from SUMO's
lanechange-output (`changeStarted`) and the lateral trace: `sublane_change_starts`.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Protocol

import numpy as np
import pandas as pd

from laneprint.simulator.sumo.backend import SumoSession
from laneprint.simulator.sumo.scenario import EGO_TYPE, ROUTE
from laneprint.simulator.sumo.settings import SumoSettings
from laneprint.simulator.sumo.traffic import TrafficBubble, VehicleState

EGO_ID = "ego"
_POS, _SPEED, _LANE, _LAT, _LEN, _ACC, _SPEED_LAT = 0x56, 0x40, 0x52, 0xB8, 0x44, 0x72, 0x32  # traci.constants VAR_*
_VARS = [_POS, _SPEED, _LANE, _LAT, _LEN]
_AT_CENTRE_M = 1e-6  # [m] lateral offset below which the ego is at its lane's centre
_FINISH_S = 10.0  # [s] at most this long past the section's end to finish a lane change
_SETTLED_SPEED_LAT_MPS = 0.3  # [m/s] sublanes: below this lateral speed, and within _SETTLED_LAT_M of
_SETTLED_LAT_M = 1.0  # [m] its lane's centre, the ego is not changing lane (its lateral wander is slower)
_REST_MPS, _REST_S = 0.2, 1.0  # sublanes: the ego holds its lateral position when it has moved slower than
# _REST_MPS [m/s] for _REST_S [s] (lcSigma's wander is slower)
_RETREAT_M = 0.5  # [m] sublanes: a lateral move back by this much ends an approach to a lane change


@dataclass
class SectionLog:
    """Frames of one run, its lane changes, and what SUMO reported."""

    ego: pd.DataFrame  # laneprint.schemas.EGO
    traffic: pd.DataFrame  # laneprint.schemas.TRAFFIC
    lane_changes: list[dict[str, Any]] = field(default_factory=list)
    n_collisions: int = 0  # steps x colliding vehicles reported by SUMO
    n_vehicles: int = 0  # background vehicles in the log
    sumo_version: str = ""
    api: str = ""  # "libsumo" or "traci"
    sumo_seed: int = 0  # SUMO's --seed of the run
    n_emergency_brakes: int = 0  # steps x vehicles braking harder than their decel, reported by SUMO


class EgoControl(Protocol):
    """Something that drives the ego's lane changes in place of LC2013 (see `rl.drive.loop`)."""

    def start(self, api: Any) -> None:
        """Called once the ego is in the simulation."""

    def step(self, api: Any, t: float, ego: VehicleState, lateral_m: float, others: dict[str, VehicleState]) -> None:
        """Called after every step with the ego, its offset from its lane centre and the other vehicles."""


def sumo_args(net: Path, routes: Path, lc_out: Path, settings: SumoSettings, seed: int) -> list[str]:
    """Command-line options of one run."""
    # sublanes (SL2015) or a lane change of fixed duration (LC2013): SUMO takes one of the two
    lateral = (
        ["--lateral-resolution", f"{settings.lateral_resolution_m:g}"]
        if settings.lateral_resolution_m > 0
        else ["--lanechange.duration", f"{settings.lane_change_s:g}"]
    )
    return [
        "-n",
        str(net),
        "-r",
        str(routes),
        "--step-length",
        f"{settings.step_s:g}",
        *lateral,
        "--seed",
        str(seed),
        "--begin",
        "0",
        "--no-step-log",
        "true",
        "--no-warnings",
        "true",
        "--duration-log.disable",
        "true",
        "--collision.action",
        "warn",
        "--lanechange-output",
        str(lc_out),
        *(["--lanechange-output.started", "true"] if settings.lateral_resolution_m > 0 else []),
    ]


def lane_change_starts(y: np.ndarray, lane: np.ndarray, width: float) -> list[tuple[int, str, int]]:
    """(sample, direction, from lane) of every lane change: the first sample off the lane centre."""
    off = np.abs(y - lane * width) > _AT_CENTRE_M
    starts = np.flatnonzero(off[1:] & ~off[:-1]) + 1
    return [(int(k), "left" if y[k] > y[k - 1] else "right", int(lane[k - 1])) for k in starts]


def sublane_change_starts(
    y: np.ndarray, lane: np.ndarray, sim_t: np.ndarray, events: list[tuple[str, float, str, float]], step_s: float
) -> list[tuple[int, str, int]]:
    """(sample, direction, from lane) of every lane change on sublanes (SL2015), as `lane_change_starts`.

    A lane change is a lane flip of the log (the ego's centre has crossed into the new lane). Its press is
    the sample after the step at which SUMO started the manoeuvre that crossed: the first `changeStarted`
    of SUMO's lanechange-output (`events`: tag, time, reason, manoeuvre distance [m], + = left) towards
    the new lane on the ego's final approach to the crossing, with none the other way after it. The final
    approach begins after the previous flip, after the ego last held its lateral position (`_REST_S`
    slower than `_REST_MPS`), and where it last turned back by `_RETREAT_M` or more. So a move to the
    lane edge that waited there or turned back is not the press (SUMO starts a manoeuvre while the
    target lane is blocked; LC2013 commits only once it is free), and a manoeuvre SUMO restarts on the
    way with another reason keeps its first start. Without such an event the press is the sample at
    which the final approach began to move towards the new lane."""
    out: list[tuple[int, str, int]] = []
    flips = np.flatnonzero(lane[1:] != lane[:-1]) + 1
    vy = np.r_[0.0, np.diff(y)] / step_s
    slow = np.r_[0, np.cumsum(np.abs(vy) < _REST_MPS)]
    rest_n = max(1, int(round(_REST_S / step_s)))
    rested = np.zeros(len(y), dtype=bool)  # slower than _REST_MPS over the rest_n samples up to each one
    rested[rest_n - 1 :] = (slow[rest_n:] - slow[:-rest_n]) == rest_n
    started = [
        (int(np.argmin(np.abs(sim_t - (tt + step_s)))), dist)  # SUMO stamps an event with its step's start
        for tag, tt, _, dist in events
        if tag == "changeStarted"
    ]
    prev_f = -1
    for f in (int(x) for x in flips):
        d = 1 if lane[f] > lane[f - 1] else -1
        lo = prev_f + 1
        calm = np.flatnonzero(rested[lo:f])
        start = lo + int(calm[-1]) if len(calm) else lo
        approach = start + _no_retreat_from(d * y[start : f + 1])
        first: Optional[int] = None
        for k, dist in started:
            if k < approach - 1 or k > f:
                continue
            if dist * d > 0:
                first = k if first is None else first
            elif k < f:  # a manoeuvre the other way before the crossing step: the one that crossed came later
                first = None
        if first is None:
            moving = np.flatnonzero(d * vy[approach : f + 1] > _REST_MPS)
            first = approach + int(moving[0]) if len(moving) else f
        # pressed in the lane it leaves, and released between two presses
        k = max(min(first, f - 1), lo, out[-1][0] + 2 if out else 0)
        out.append((k, "left" if d > 0 else "right", int(lane[f - 1])))
        prev_f = f
    return out


def _no_retreat_from(u: np.ndarray) -> int:
    """The first index from which `u` (lateral position towards the target) never falls `_RETREAT_M` below
    its running maximum up to its end."""

    def retreat(k: int) -> float:
        return float(np.max(np.maximum.accumulate(u[k:]) - u[k:]))

    lo, hi = 0, len(u) - 1  # retreat(k) does not grow with k; retreat(len(u) - 1) == 0
    while lo < hi:
        mid = (lo + hi) // 2
        if retreat(mid) < _RETREAT_M:
            hi = mid
        else:
            lo = mid + 1
    return lo


def _ego_events(lc_out: Path) -> list[tuple[str, float, str, float]]:
    """(tag, simulation time, SUMO's reason, manoeuvre distance [m] or 0) of the ego's lanechange-output
    events in order: `change` (the lane flip) and, on sublanes, `changeStarted` (a manoeuvre begins)."""
    if not lc_out.is_file():
        return []
    out = []
    for _, el in ET.iterparse(lc_out):
        if el.tag in ("change", "changeStarted") and el.get("id") == EGO_ID:
            dist = el.get("maneuverDistance")
            out.append(
                (
                    el.tag,
                    float(el.get("time", "nan")),
                    el.get("reason", ""),
                    float(dist) if dist not in (None, "None") else 0.0,
                )
            )
        el.clear()
    return out


def _inputs(v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Throttle and brake (0-1) from the ego's acceleration: brake only below -0.3 m/s^2."""
    braking = a < -0.3
    throttle = np.where(braking, 0.0, np.clip(0.1 + 0.008 * v + 0.15 * a, 0.0, 1.0))
    brake = np.where(braking, np.clip(-a / 8.0, 0.0, 1.0), 0.0)
    return throttle, brake


def run_section(
    settings: SumoSettings,
    net: Path,
    routes: Path,
    limit_kph: float,
    seed: int,
    rng: np.random.Generator,
    workdir: Path,
    control: Optional[EgoControl] = None,
) -> SectionLog:
    """Run one section (SUMO seed `seed`, traffic choices from `rng`) and log it; scratch files in `workdir`.

    With `control`, it makes the ego's lane changes (called after every step, before the traffic moves on).
    """
    s = settings
    lc_out = workdir / f"lanechanges-{seed}.xml"
    n_steps = int(round(s.duration_s / s.step_s))
    ego_rows: list[tuple[float, float, float, float, int, float]] = []
    traffic_rows: list[tuple[float, str, float, float, float, int, float]] = []
    sim_t: list[float] = []
    collisions = emergency = 0
    with SumoSession(sumo_args(net, routes, lc_out, s, seed)) as sim:
        veh = sim.api.vehicle
        veh.add(
            EGO_ID, ROUTE, EGO_TYPE, depart="now", departLane="0", departPos=f"{s.ego_start_m:g}", departSpeed="desired"
        )
        veh.subscribe(EGO_ID, _VARS + [_ACC, _SPEED_LAT])
        bubble = TrafficBubble(sim.api, s, limit_kph / 3.6, rng, _VARS)
        if control is not None:
            control.start(sim.api)
        sim.step()
        bubble.fill(veh.getAllSubscriptionResults()[EGO_ID][_POS] - s.ego_length_m / 2)
        for i in range(n_steps + int(_FINISH_S / s.step_s)):
            sim.step()
            t = round(i * s.step_s, 6)
            res = veh.getAllSubscriptionResults()
            states = _log_step(res, t, s, ego_rows, traffic_rows)
            sim_t.append(sim.api.simulation.getTime())
            collisions += sim.api.simulation.getCollidingVehiclesNumber()
            emergency += sim.api.simulation.getEmergencyStoppingVehiclesNumber()
            _, ex, ey, ev, lane, _ = ego_rows[-1]
            if i + 1 >= n_steps and _settled(s, ey - lane * s.lane_width_m, res[EGO_ID][_SPEED_LAT]):
                break  # the section is over and no lane change is under way
            if control is not None and i + 1 < n_steps:
                control.step(sim.api, t, VehicleState(ex, ev, lane, s.ego_length_m), ey - lane * s.lane_width_m, states)
            bubble.update(t, ex, ev, states)
        version, api = sim.version, sim.api_name
    log = _assemble(s, ego_rows, np.asarray(sim_t), traffic_rows, _ego_events(lc_out), collisions, version, api)
    log.sumo_seed, log.n_emergency_brakes = seed, emergency
    return log


def _settled(s: SumoSettings, lateral_m: float, speed_lat_mps: float) -> bool:
    """No lane change under way: at the lane centre (LC2013), or slow sideways near it (sublanes, where the
    ego wanders about its centre)."""
    if s.lateral_resolution_m > 0:
        return abs(speed_lat_mps) < _SETTLED_SPEED_LAT_MPS and abs(lateral_m) < _SETTLED_LAT_M
    return abs(lateral_m) <= _AT_CENTRE_M


def _log_step(
    res: dict[str, dict[int, Any]], t: float, s: SumoSettings, ego_rows: list, traffic_rows: list
) -> dict[str, VehicleState]:
    """Append the ego's state and the traffic within range at `t`; every background vehicle's state."""
    e = res.get(EGO_ID)
    if e is None:
        raise RuntimeError("the ego left the simulation (road too short?)")
    ex = e[_POS] - e[_LEN] / 2  # SUMO's position is the front bumper
    ego_rows.append((t, ex, e[_LANE] * s.lane_width_m + e[_LAT], e[_SPEED], int(e[_LANE]), e[_ACC]))
    states = {}
    for vid, r in res.items():
        if vid == EGO_ID:
            continue
        st = VehicleState(r[_POS] - r[_LEN] / 2, r[_SPEED], int(r[_LANE]), r[_LEN], r[_LAT])
        states[vid] = st
        if abs(st.x - ex) <= s.scene_range_m:
            traffic_rows.append((t, vid, st.x, st.lane * s.lane_width_m + r[_LAT], st.v, st.lane, st.length))
    return states


def _assemble(
    s: SumoSettings,
    ego_rows: list,
    sim_t: np.ndarray,
    traffic_rows: list,
    events: list[tuple[str, float, str, float]],
    collisions: int,
    version: str,
    api: str,
) -> SectionLog:
    t, x, y, v, lane, a = (np.asarray(c) for c in zip(*ego_rows))
    lane = lane.astype(np.int64)
    n = len(t)
    hold = max(1, int(round(s.button_hold_s / s.step_s)))
    button = np.zeros(n, dtype=bool)
    direction = np.full(n, None, dtype=object)
    changes = []
    reasons = [(tt, r) for tag, tt, r, _ in events if tag == "change"]
    starts = (
        sublane_change_starts(y, lane, sim_t, events, s.step_s)
        if s.lateral_resolution_m > 0
        else lane_change_starts(y, lane, s.lane_width_m)
    )
    for j, (k, d, from_lane) in enumerate(starts):
        end = starts[j + 1][0] if j + 1 < len(starts) else n
        release = min(k + hold, end - 1 if j + 1 < len(starts) else end)  # released before the next press
        button[k : max(release, k + 1)] = True
        direction[k : max(release, k + 1)] = d
        flips = np.flatnonzero(lane[k:end] != from_lane)
        flip = k + int(flips[0]) if len(flips) else None
        # SUMO stamps a change with the time the step that made it began: one step before the flip sample
        reason = next(
            (r for tt, r in reasons if flip is not None and abs(tt + s.step_s - sim_t[flip]) < s.step_s / 2), ""
        )
        changes.append(
            {
                "sample": k,
                "press_t_s": float(t[k]),
                "direction": d,
                "from_lane": from_lane,
                "target_lane": from_lane + (1 if d == "left" else -1),
                "changed": flip is not None,
                "lane_flip_t_s": float(t[flip]) if flip is not None else None,
                "v_e_mps": float(v[k]),
                "sumo_reason": reason,
            }
        )
    throttle, brake = _inputs(v, a)
    ego = pd.DataFrame(
        {
            "t_s": t,
            "ego_x_m": x,
            "ego_y_m": y,
            "ego_v_mps": v,
            "ego_lane": lane,
            "ego_length_m": np.full(n, s.ego_length_m),
            "steer_rad": np.full(n, np.nan),
            "throttle": throttle,
            "brake": brake,
            "lc_button": button,
            "lc_direction": direction,
        }
    )
    cols = ["t_s", "vehicle_id", "x_m", "y_m", "v_mps", "lane", "length_m"]
    traffic = pd.DataFrame(traffic_rows, columns=cols)
    traffic["lane"] = traffic["lane"].astype(np.int64)
    return SectionLog(ego, traffic, changes, collisions, int(traffic["vehicle_id"].nunique()), version, api)
