"""One SUMO run: a driver in one section, logged at every step.

The ego is a SUMO vehicle of the driver's type: Krauss follows, LC2013 decides
every lane change (nothing is scripted), unless an `EgoControl` makes them (the
closed loop of `laneprint drive`, `rl/drive/loop.py`). At every step the ego's state, the
background vehicles within `scene_range_m` and the driver inputs are logged;
afterwards each lane change is found in the lateral trace and the lane-change
button is pressed at its start: the first sample at which the ego has left its
lane centre (SUMO moves it sideways from the step it commits), held for
`button_hold_s`, with the direction. The lane index flips half way through.
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
_POS, _SPEED, _LANE, _LAT, _LEN, _ACC = 0x56, 0x40, 0x52, 0xb8, 0x44, 0x72  # traci.constants VAR_*
_VARS = [_POS, _SPEED, _LANE, _LAT, _LEN]
_AT_CENTRE_M = 1e-6  # [m] lateral offset below which the ego is at its lane's centre
_FINISH_S = 10.0  # [s] at most this long past the section's end to finish a lane change


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

    def step(self, api: Any, t: float, ego: VehicleState, lateral_m: float,
             others: dict[str, VehicleState]) -> None:
        """Called after every step with the ego, its offset from its lane centre and the other vehicles."""


def sumo_args(net: Path, routes: Path, lc_out: Path, settings: SumoSettings, seed: int) -> list[str]:
    """Command-line options of one run."""
    return ["-n", str(net), "-r", str(routes), "--step-length", f"{settings.step_s:g}",
            "--lanechange.duration", f"{settings.lane_change_s:g}", "--seed", str(seed),
            "--begin", "0", "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true",
            "--collision.action", "warn", "--lanechange-output", str(lc_out)]


def lane_change_starts(y: np.ndarray, lane: np.ndarray, width: float) -> list[tuple[int, str, int]]:
    """(sample, direction, from lane) of every lane change: the first sample off the lane centre."""
    off = np.abs(y - lane * width) > _AT_CENTRE_M
    starts = np.flatnonzero(off[1:] & ~off[:-1]) + 1
    return [(int(k), "left" if y[k] > y[k - 1] else "right", int(lane[k - 1])) for k in starts]


def _reasons(lc_out: Path) -> list[tuple[float, str]]:
    """(simulation time of the lane flip, SUMO's reason) of the ego's lane changes."""
    if not lc_out.is_file():
        return []
    out = []
    for _, el in ET.iterparse(lc_out):
        if el.tag == "change" and el.get("id") == EGO_ID:
            out.append((float(el.get("time", "nan")), el.get("reason", "")))
        el.clear()
    return out


def _inputs(v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Throttle and brake (0-1) from the ego's acceleration: brake only below -0.3 m/s^2."""
    braking = a < -0.3
    throttle = np.where(braking, 0.0, np.clip(0.1 + 0.008 * v + 0.15 * a, 0.0, 1.0))
    brake = np.where(braking, np.clip(-a / 8.0, 0.0, 1.0), 0.0)
    return throttle, brake


def run_section(settings: SumoSettings, net: Path, routes: Path, limit_kph: float, seed: int,
                rng: np.random.Generator, workdir: Path, control: Optional[EgoControl] = None) -> SectionLog:
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
        veh.add(EGO_ID, ROUTE, EGO_TYPE, depart="now", departLane="0", departPos=f"{s.ego_start_m:g}",
                departSpeed="desired")
        veh.subscribe(EGO_ID, _VARS + [_ACC])
        bubble = TrafficBubble(sim.api, s, limit_kph / 3.6, rng, _VARS)
        if control is not None:
            control.start(sim.api)
        sim.step()
        bubble.fill(veh.getAllSubscriptionResults()[EGO_ID][_POS] - s.ego_length_m / 2)
        for i in range(n_steps + int(_FINISH_S / s.step_s)):
            sim.step()
            t = round(i * s.step_s, 6)
            states = _log_step(veh.getAllSubscriptionResults(), t, s, ego_rows, traffic_rows)
            sim_t.append(sim.api.simulation.getTime())
            collisions += sim.api.simulation.getCollidingVehiclesNumber()
            emergency += sim.api.simulation.getEmergencyStoppingVehiclesNumber()
            _, ex, ey, ev, lane, _ = ego_rows[-1]
            if i + 1 >= n_steps and abs(ey - lane * s.lane_width_m) <= _AT_CENTRE_M:
                break  # the section is over and no lane change is under way
            if control is not None and i + 1 < n_steps:
                control.step(sim.api, t, VehicleState(ex, ev, lane, s.ego_length_m), ey - lane * s.lane_width_m,
                             states)
            bubble.update(t, ex, ev, states)
        version, api = sim.version, sim.api_name
    log = _assemble(s, ego_rows, np.asarray(sim_t), traffic_rows, _reasons(lc_out), collisions, version, api)
    log.sumo_seed, log.n_emergency_brakes = seed, emergency
    return log


def _log_step(res: dict[str, dict[int, Any]], t: float, s: SumoSettings, ego_rows: list,
              traffic_rows: list) -> dict[str, VehicleState]:
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


def _assemble(s: SumoSettings, ego_rows: list, sim_t: np.ndarray, traffic_rows: list,
              reasons: list[tuple[float, str]], collisions: int, version: str, api: str) -> SectionLog:
    t, x, y, v, lane, a = (np.asarray(c) for c in zip(*ego_rows))
    lane = lane.astype(np.int64)
    n = len(t)
    hold = max(1, int(round(s.button_hold_s / s.step_s)))
    button = np.zeros(n, dtype=bool)
    direction = np.full(n, None, dtype=object)
    changes = []
    starts = lane_change_starts(y, lane, s.lane_width_m)
    for j, (k, d, from_lane) in enumerate(starts):
        end = starts[j + 1][0] if j + 1 < len(starts) else n
        button[k:min(k + hold, end)] = True
        direction[k:min(k + hold, end)] = d
        flips = np.flatnonzero(lane[k:end] != from_lane)
        flip = k + int(flips[0]) if len(flips) else None
        # SUMO stamps a change with the time the step that made it began: one step before the flip sample
        reason = next((r for tt, r in reasons
                       if flip is not None and abs(tt + s.step_s - sim_t[flip]) < s.step_s / 2), "")
        changes.append({"sample": k, "press_t_s": float(t[k]), "direction": d, "from_lane": from_lane,
                        "target_lane": from_lane + (1 if d == "left" else -1), "changed": flip is not None,
                        "lane_flip_t_s": float(t[flip]) if flip is not None else None,
                        "v_e_mps": float(v[k]), "sumo_reason": reason})
    throttle, brake = _inputs(v, a)
    ego = pd.DataFrame({
        "t_s": t, "ego_x_m": x, "ego_y_m": y, "ego_v_mps": v, "ego_lane": lane,
        "ego_length_m": np.full(n, s.ego_length_m), "steer_rad": np.full(n, np.nan),
        "throttle": throttle, "brake": brake, "lc_button": button, "lc_direction": direction,
    })
    cols = ["t_s", "vehicle_id", "x_m", "y_m", "v_mps", "lane", "length_m"]
    traffic = pd.DataFrame(traffic_rows, columns=cols)
    traffic["lane"] = traffic["lane"].astype(np.int64)
    return SectionLog(ego, traffic, changes, collisions, int(traffic["vehicle_id"].nunique()), version, api)
