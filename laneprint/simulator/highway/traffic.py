"""Traffic around the ego: a window of highway-env vehicles that follows it along the road.

Traffic comes in streams, one per lane (its home lane): the rightmost lane's stream
is slow (cars and trucks that keep their lane), the leftmost lane's fast, a middle
lane's in between (`HighwaySettings.lane_speed_frac`); cars of the other streams
change lanes by MOBIL with a keep-right bias. Every stream has its own density
(vehicles per km, drawn per section: `study.section_densities`), counted over its
vehicles wherever they drive, so fast cars that keep right do not push the slow
stream off the road.

At the start the window is filled ahead of the ego and behind it. Afterwards, on
each side of the ego a stream below its density gets a new vehicle: one slower than
the ego at the window's front edge (the ego closes on it) or one faster at its rear
edge (it catches up), once the stream's last such vehicle is a drawn spacing away
and the new one clears its lane neighbours (`min_spawn_gap_s`; where it does not, a
spot nearer the ego, still outside the logged scene, is tried). Vehicles that leave the window are
removed. So the ego meets slower leaders and faster cars from behind all recording
long; once in the window every vehicle drives by highway-env's IDM (and MOBIL).

Imports highway_env; only `section.py` imports this module.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from laneprint.simulator.highway.settings import HighwaySettings
from laneprint.simulator.highway.world import FastRoad, LaneKeeper, TrafficCar, set_length

#: Desired speeds drawn for a vehicle that must be slower / faster than the ego before giving up for the step.
_SPEED_TRIES = 8
#: highway-env's IDMVehicle.DELTA_RANGE (the exponent of IDM's free-road term), drawn per traffic vehicle.
IDM_DELTA_RANGE: tuple[float, float] = (3.5, 4.5)
_MIN_SPACING_M = 15.0  # [m] centre to centre, the shortest drawn spacing
_SPOT_STEP_M = 10.0  # [m] a new vehicle that does not fit at the edge is tried this much nearer the ego ...
_SPOT_MARGIN_M = 20.0  # [m] ... down to this far outside the logged scene


class TrafficWindow:
    """Adds and removes the traffic vehicles of one recording around the ego."""

    def __init__(
        self,
        road: FastRoad,
        settings: HighwaySettings,
        limit_mps: float,
        density_per_km: list[float],
        rng: np.random.Generator,
    ) -> None:
        self.road, self.s, self.limit, self.rng = road, settings, limit_mps, rng
        n = settings.n_lanes
        self.density = list(density_per_km)  # vehicles per km of each stream, by home lane (rightmost first)
        self.ids: dict[int, str] = {}  # id(vehicle) -> log id
        self.lengths: dict[int, float] = {}  # id(vehicle) -> length [m]
        self.stream: dict[int, int] = {}  # id(vehicle) -> home lane of its stream
        self._count = 0
        self._next = {(k, front): self._spacing(k) for k in range(n) for front in (True, False)}

    # --- drawing -----------------------------------------------------------------
    def _spacing(self, lane: int) -> float:
        """A centre-to-centre spacing [m] in a stream: exponential around 1 / density."""
        return max(_MIN_SPACING_M, float(self.rng.exponential(1000.0 / self.density[lane])))

    def _kind(self, lane: int) -> str:
        return "truck" if lane == 0 and self.rng.random() < self.s.truck_share else "car"

    def _desired_speed(self, lane: int, kind: str) -> float:
        frac = self.s.truck_speed_frac if kind == "truck" else self.s.by_lane(self.s.lane_speed_frac, lane)
        return float(self.rng.uniform(*frac)) * self.limit

    def _speed_relative(self, lane: int, kind: str, v_ego: float, slower: bool) -> float | None:
        for _ in range(_SPEED_TRIES):
            v = self._desired_speed(lane, kind)
            if (v < v_ego) if slower else (v > v_ego):
                return v
        return None

    # --- vehicles ----------------------------------------------------------------
    def add(self, lane: int, x: float, desired: float, kind: str) -> Any:
        """Put a vehicle of stream `lane` into its home lane at `x`, driving at its `desired` speed."""
        hw = self.s.n_lanes - 1 - lane
        keeps_lane = kind == "truck" or (lane == 0 and self.s.right_lane_keeps)
        cls = LaneKeeper if keeps_lane else TrafficCar
        v = cls(
            self.road,
            self.road.network.get_lane(("0", "1", hw)).position(x, 0.0),
            speed=desired,
            target_speed=desired,
            timer=float(self.rng.uniform(0.0, 1.0)),
        )
        length = float(self.rng.uniform(*(self.s.truck_length_m if kind == "truck" else self.s.car_length_m)))
        set_length(v, length)
        v.DELTA = float(self.rng.uniform(*IDM_DELTA_RANGE))
        if not keeps_lane:
            v.POLITENESS = float(self.rng.uniform(*self.s.traffic_politeness))
            v.keep_right_bias = self.s.traffic_keep_right
        self.road.vehicles.append(v)
        self.road.invalidate()
        self._count += 1
        self.ids[id(v)], self.lengths[id(v)], self.stream[id(v)] = f"v{self._count:04d}", length, lane
        return v

    def fill(self, ego: Any) -> None:
        """Lay out every stream in its home lane from the window's rear edge to its front edge."""
        x0 = ego.position[0]
        for lane in range(self.s.n_lanes):
            x = x0 - self.s.spawn_behind_m + self.rng.uniform(0.0, self._spacing(lane))
            while x < x0 + self.s.spawn_ahead_m:
                kind = self._kind(lane)
                v = self._desired_speed(lane, kind)
                if self._free_spot(lane, x, x + 1.0, v) is not None:
                    self.add(lane, x, v, kind)
                x += self._spacing(lane)

    def update(self, ego: Any) -> int:
        """Remove vehicles outside the window and crashed ones, add new ones at its edges. Returns the number
        of crashed traffic vehicles removed."""
        s, x0 = self.s, ego.position[0]
        keep, crashed = [], 0
        for v in self.road.vehicles:
            if v is ego:
                keep.append(v)
            elif v.crashed:
                crashed += 1
            elif x0 - s.remove_behind_m <= v.position[0] <= x0 + s.remove_ahead_m:
                keep.append(v)
        if len(keep) != len(self.road.vehicles):
            kept = {id(v) for v in keep}
            for v in self.road.vehicles:
                if id(v) not in kept:
                    self.stream.pop(id(v), None)
            self.road.vehicles[:] = keep
            self.road.invalidate()
        for lane in range(s.n_lanes):
            for front in (True, False):
                self._spawn_edge(lane, ego, front)
        return crashed

    def _spawn_edge(self, lane: int, ego: Any, front: bool) -> None:
        """A vehicle of stream `lane`, slower than the ego at the front edge or faster at the rear edge, when
        the stream is below its density on that side and its last such vehicle is a spacing away."""
        s, x0, v_ego = self.s, ego.position[0], ego.speed
        edge = x0 + s.spawn_ahead_m if front else x0 - s.spawn_behind_m
        mine = [v for v in self.road.vehicles if self.stream.get(id(v)) == lane]
        xs = np.array([v.position[0] for v in mine])
        vs = np.array([v.speed for v in mine])
        side = (xs > x0) & (xs <= edge) if front else (xs >= edge) & (xs < x0)
        if np.count_nonzero(side) >= self.density[lane] * abs(edge - x0) / 1000.0:
            return
        drifting = side & ((vs < v_ego) if front else (vs > v_ego))  # entered the window as this one would
        room = abs(edge - (xs[drifting].max() if front else xs[drifting].min())) if drifting.any() else np.inf
        if room < self._next[lane, front]:
            return
        kind = self._kind(lane) if front else "car"
        desired = self._speed_relative(lane, kind, v_ego, slower=front)
        if desired is None:
            return
        x = self._free_spot(lane, edge, x0 + (s.scene_range_m + _SPOT_MARGIN_M) * (1 if front else -1), desired)
        if x is not None:
            self.add(lane, x, desired, kind)
            self._next[lane, front] = self._spacing(lane)

    def _free_spot(self, lane: int, start: float, stop: float, desired: float) -> float | None:
        """The first x from `start` towards `stop` (every `_SPOT_STEP_M`) where a vehicle driving `desired`
        clears every vehicle in `lane`, or None."""
        y = (self.s.n_lanes - 1 - lane) * self.s.lane_width_m
        others = [v for v in self.road.vehicles if abs(v.position[1] - y) < self.s.lane_width_m]  # also changing
        step = _SPOT_STEP_M if stop > start else -_SPOT_STEP_M
        for x in np.arange(start, stop, step):
            if all(self._clear(float(x), desired, v) for v in others):
                return float(x)
        return None

    def _clear(self, x: float, v_new: float, other: Any) -> bool:
        """Whether a new vehicle at `x` driving `v_new` keeps a safe spacing to `other`: 10 m + min_spawn_gap_s
        at the rear one's speed + its braking distance to the front one's speed at 3 m/s^2 + half lengths."""
        behind = other.position[0] < x
        v_rear, v_front = (other.speed, v_new) if behind else (v_new, other.speed)
        closing = max(0.0, v_rear - v_front)
        need = 10.0 + self.s.min_spawn_gap_s * v_rear + closing**2 / (2 * 3.0) + (other.LENGTH + 16.0) / 2
        return abs(other.position[0] - x) >= need
