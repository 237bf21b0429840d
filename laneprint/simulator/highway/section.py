"""One recording: a driver in one section of a highway-env road, logged at every step.

The ego (`driver.HumanDriver`) starts in the rightmost lane inside a window of
traffic (`traffic.TrafficWindow`); the world runs `warmup_s` with the ego's lane
changes switched off, then `minutes` are logged at 1 / `step_s` Hz. Every sample
holds the ego's state before it acts (LOG_FORMAT lanes and y: lane 0 rightmost, y to
the left), its steering and the throttle / brake read from its acceleration, the
lane-change button, and the traffic vehicles within `scene_range_m`. The button is
pressed at the sample of each decision that was not a missed press, held for the
decision's `hold_s`, with the direction.

Imports highway_env (the `highway` extra).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from laneprint.simulator.highway.driver import Decision, HumanDriver
from laneprint.simulator.highway.settings import HighwaySettings
from laneprint.simulator.highway.traffic import TrafficWindow
from laneprint.simulator.highway.world import log_lane, log_y, set_length, straight_road

_ROAD_MARGIN_M = 3000.0  # [m] road beyond the farthest the window can get
_SAME_COLLISION_S = 2.0  # [s] contacts of the ego closer in time than this are one collision
_FLIP_LOOKAHEAD_S = 15.0  # [s] a decision's lane change is looked for this long (or to the next decision)


@dataclass
class SectionLog:
    """Frames of one recording, the ego's decisions, and what happened."""

    ego: pd.DataFrame  # laneprint.schemas.EGO
    traffic: pd.DataFrame  # laneprint.schemas.TRAFFIC
    decisions: list[dict[str, Any]] = field(default_factory=list)  # LOG_FORMAT lanes, times of the log
    collision_t_s: list[float] = field(default_factory=list)  # when the ego collided (log time) [s]
    n_traffic_collisions: int = 0  # crashed traffic vehicles (removed from the road)
    n_vehicles: int = 0  # traffic vehicles in the log
    density_per_km: list[float] = field(default_factory=list)  # drawn traffic density by lane, rightmost first
    version: str = ""  # highway-env's version


def highway_env_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("highway-env")
    except PackageNotFoundError:  # pragma: no cover - an unpackaged checkout
        return "unknown"


def run_section(
    settings: HighwaySettings,
    params: dict[str, float],
    limit_kph: float,
    density_per_km: list[float],
    seeds: np.random.SeedSequence,
) -> SectionLog:
    """Drive one section (traffic streams of `density_per_km`, rightmost first) with the driver's `params`;
    every random choice from `seeds`."""
    s = settings
    driver_ss, traffic_ss, road_ss = seeds.spawn(3)
    limit = limit_kph / 3.6
    length = s.remove_behind_m + (s.warmup_s + s.duration_s) * limit * 1.6 + _ROAD_MARGIN_M
    road = straight_road(s.n_lanes, length, s.lane_width_m, np.random.RandomState(int(road_ss.generate_state(1)[0])))
    start = road.network.get_lane(("0", "1", s.n_lanes - 1)).position(s.remove_behind_m + 50.0, 0.0)
    ego = HumanDriver(
        road, start, 0.9 * params["SPEED_FACTOR"] * limit, params, limit, s, np.random.default_rng(driver_ss)
    )
    set_length(ego, s.ego_length_m)
    ego.clock = -s.warmup_s
    road.vehicles.append(ego)
    window = TrafficWindow(road, s, limit, density_per_km, np.random.default_rng(traffic_ss))
    window.fill(ego)

    n_warm, n_log = int(round(s.warmup_s / s.step_s)), int(round(s.duration_s / s.step_s))
    every = max(1, int(round(s.window_period_s / s.step_s)))
    ego_rows: list[list[float]] = []
    traffic_rows: list[tuple[float, str, float, float, float, int, float]] = []
    collisions: list[float] = []
    traffic_collisions = 0
    for i in range(n_warm + n_log):
        logged = ego.enable_lane_change = i >= n_warm  # no lane changes while the traffic settles
        if logged:
            t = round((i - n_warm) * s.step_s, 6)
            _log_traffic(t, ego, window, s, traffic_rows)
        road.act()
        if logged:
            ego_rows.append(
                [
                    t,
                    float(ego.position[0]),
                    log_y(ego.position[1], s.n_lanes, s.lane_width_m),
                    float(ego.speed),
                    log_lane(ego.lane_index, s.n_lanes),
                    float(ego.action["steering"]),
                    float(ego.action["acceleration"]),
                ]
            )
        road.step(s.step_s)
        if ego.crashed:
            if logged and (not collisions or t - collisions[-1] > _SAME_COLLISION_S):
                collisions.append(t)
            ego.crashed, ego.impact = False, None
        if i % every == 0:
            removed_crashed = window.update(ego)
            traffic_collisions += removed_crashed if logged else 0
    log = _assemble(s, ego_rows, traffic_rows, ego.decisions)
    log.collision_t_s, log.n_traffic_collisions = collisions, traffic_collisions
    log.density_per_km, log.version = list(window.density), highway_env_version()
    return log


def _log_traffic(t: float, ego: HumanDriver, window: TrafficWindow, s: HighwaySettings, rows: list) -> None:
    ex = ego.position[0]
    for v in ego.road.vehicles:
        if v is ego or abs(v.position[0] - ex) > s.scene_range_m:
            continue
        rows.append(
            (
                t,
                window.ids[id(v)],
                float(v.position[0]),
                log_y(v.position[1], s.n_lanes, s.lane_width_m),
                float(v.speed),
                log_lane(v.lane_index, s.n_lanes),
                window.lengths[id(v)],
            )
        )


def inputs(v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Throttle and brake (0-1) from the ego's acceleration: brake only below -0.3 m/s^2."""
    braking = a < -0.3
    throttle = np.where(braking, 0.0, np.clip(0.1 + 0.008 * v + 0.15 * a, 0.0, 1.0))
    brake = np.where(braking, np.clip(-a / 8.0, 0.0, 1.0), 0.0)
    return throttle, brake


def _assemble(s: HighwaySettings, ego_rows: list, traffic_rows: list, decisions: list[Decision]) -> SectionLog:
    t, x, y, v, lane, steer, a = (np.asarray(c) for c in zip(*ego_rows))
    lane = lane.astype(np.int64)
    n = len(t)
    button = np.zeros(n, dtype=bool)
    direction = np.full(n, None, dtype=object)
    logged = [d for d in decisions if d.t_s >= -1e-9 and d.t_s <= t[-1] + 1e-9]
    samples = [int(round(d.t_s / s.step_s)) for d in logged]
    out = []
    for j, (dec, k) in enumerate(zip(logged, samples)):
        end = samples[j + 1] if j + 1 < len(samples) else n
        if dec.pressed:
            stop = min(k + max(1, int(round(dec.hold_s / s.step_s))), end)
            button[k:stop] = True
            direction[k:stop] = dec.direction
        from_lane, target = log_lane(dec.from_lane, s.n_lanes), log_lane(dec.target_lane, s.n_lanes)
        horizon = min(end, k + int(round(_FLIP_LOOKAHEAD_S / s.step_s)))
        flips = np.flatnonzero(lane[k:horizon] == target)
        flip = k + int(flips[0]) if len(flips) else None
        out.append(
            {
                "decision_t_s": float(t[k]),
                "press_t_s": float(t[k]) if dec.pressed else None,
                "direction": dec.direction,
                "from_lane": from_lane,
                "target_lane": target,
                "pressed": dec.pressed,
                "missed": not dec.pressed,
                "aborted": dec.started is False,
                "changed": flip is not None,
                "lane_flip_t_s": float(t[flip]) if flip is not None else None,
                "reaction_s": round(dec.start_t_s - dec.t_s, 4),
                "hold_s": round(dec.hold_s, 4),
                "max_braking_drawn_mps2": round(dec.max_braking, 4),
                "mobil_margin_mps2": round(dec.margin, 4),
                "v_e_mps": float(v[k]),
            }
        )
    throttle, brake = inputs(v, a)
    ego = pd.DataFrame(
        {
            "t_s": t,
            "ego_x_m": x,
            "ego_y_m": y,
            "ego_v_mps": v,
            "ego_lane": lane,
            "ego_length_m": np.full(n, s.ego_length_m),
            "steer_rad": steer,
            "throttle": throttle,
            "brake": brake,
            "lc_button": button,
            "lc_direction": direction,
        }
    )
    cols = ["t_s", "vehicle_id", "x_m", "y_m", "v_mps", "lane", "length_m"]
    traffic = pd.DataFrame(traffic_rows, columns=cols)
    traffic["lane"] = traffic["lane"].astype(np.int64)
    return SectionLog(ego, traffic, out, n_vehicles=int(traffic["vehicle_id"].nunique()))
