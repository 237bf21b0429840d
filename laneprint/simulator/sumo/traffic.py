"""Background traffic as a moving bubble around the ego.

Three streams, each vehicle with its own desired speed (a fraction of the limit):

- `slow`: cars and trucks in the right lane, slower than the ego; spaced
  `slow_spacing_s` seconds (at the limit) apart along the road, so the ego meets
  one every spacing / closing speed seconds, alone or in short platoons;
- `middle` (three lanes only): cars in the middle lane, slower than the ego, so
  it overtakes them on the left and returns right past them;
- `left`: cars that appear in the top (leftmost) lane, slower than the ego but faster than
  the right lane (they overtake there and then keep right); only when
  `ahead_streams` names it (the default family's; not the `acceptance` family's);
- `fast`: cars faster than the limit that appear behind the ego in the top lane
  now and then; they close the gap the ego wants and make it wait.

Streams appear in the lanes of `SumoSettings.stream_lane` (`STREAM_LANES`).

Vehicles ahead appear `spawn_ahead_m` in front of the ego (outside the logged
range), the next one of a stream when its spacing behind the stream's frontmost
vehicle has come within reach; every vehicle leaves the simulation when it is
farther than `remove_behind_m` / `remove_ahead_m` from the ego, or when it is
beyond the logged range ahead and pulling away (faster than the ego). Background
vehicles follow with Krauss (no dawdling) and change lanes with LC2013 (see
`scenario.py`: they return right within seconds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from laneprint.simulator.sumo.scenario import CAR_TYPE, ROUTE, TRUCK_TYPE
from laneprint.simulator.sumo.settings import SumoSettings

#: stream -> (settings field of its desired speed / limit, settings field of its spacing [s])
_STREAM_FIELDS: dict[str, tuple[str, str]] = {
    "slow": ("slow_speed_frac", "slow_spacing_s"),
    "middle": ("middle_speed_frac", "middle_spacing_s"),
    "left": ("left_speed_frac", "left_spacing_s"),
}


@dataclass(frozen=True)
class VehicleState:
    """A vehicle at one step: centre position [m], speed [m/s], lane, length [m], and its lateral offset
    from its lane's centre [m] (positive to the left; away from 0 while it changes lane)."""

    x: float
    v: float
    lane: int
    length: float
    lat: float = 0.0


class TrafficBubble:
    """Adds and removes background vehicles around the ego; all choices from `rng`."""

    def __init__(
        self, api: Any, settings: SumoSettings, limit_mps: float, rng: np.random.Generator, subscribe_vars: list[int]
    ) -> None:
        self.api = api
        self.s = settings
        self.limit = limit_mps
        self.rng = rng
        self.vars = subscribe_vars
        self.stream: dict[str, str] = {}  # vehicle id -> stream
        self.pending: set[str] = set()  # added, not yet seen on the road
        self.n_added = 0
        self.spacing = {stream: self._spacing(stream) for stream in ("slow", "left")}
        if "middle" in settings.ahead_streams:  # drawn after the others: two-lane studies keep their draws
            self.spacing["middle"] = self._spacing("middle")
        self.next_fast_s = self._u(settings.fast_interval_s)

    def _u(self, lo_hi: tuple[float, float]) -> float:
        return float(self.rng.uniform(lo_hi[0], lo_hi[1]))

    # --- one step ------------------------------------------------------------------

    def update(self, t: float, ego_x: float, ego_v: float, vehicles: dict[str, VehicleState]) -> None:
        """Remove far and never-inserted vehicles, then add the ones due, given the states at `t`."""
        s = self.s
        for vid in sorted(self.pending):
            if vid not in vehicles:
                self._remove(vid)  # could not be inserted where asked: give up on it
        self.pending.clear()
        for vid, st in vehicles.items():
            gone_ahead = st.x > ego_x + s.remove_ahead_m or (st.x > ego_x + s.scene_range_m + 30.0 and st.v > ego_v)
            if st.x < ego_x - s.remove_behind_m or gone_ahead:
                self._remove(vid)
        live = {vid: st for vid, st in vehicles.items() if vid in self.stream}
        for stream in s.ahead_streams:
            self._spawn_ahead(stream, ego_x, live)
        if t >= self.next_fast_s:
            v = self._u(s.fast_speed_frac) * self.limit
            if self._add("fast", ego_x - s.spawn_behind_m, v, live):
                self.next_fast_s = t + self._u(s.fast_interval_s)

    def fill(self, ego_x: float) -> None:
        """The first scene: each ahead stream from half the logged range ahead up to `spawn_ahead_m`."""
        s = self.s
        live: dict[str, VehicleState] = {}
        for stream in s.ahead_streams:
            x = ego_x + s.scene_range_m / 2 + self._u((0.0, self.spacing[stream]))
            while x <= ego_x + s.spawn_ahead_m:
                self._add(stream, x, self._speed(stream), live)
                x += self._spacing(stream)
            self.spacing[stream] = x - (ego_x + s.spawn_ahead_m)  # the rest of the last spacing

    # --- helpers -----------------------------------------------------------------------

    def _spacing(self, stream: str) -> float:
        """Distance to the stream's next vehicle [m]."""
        return self._u(getattr(self.s, _STREAM_FIELDS[stream][1])) * self.limit

    def _speed(self, stream: str) -> float:
        return self._u(getattr(self.s, _STREAM_FIELDS[stream][0])) * self.limit

    def _spawn_ahead(self, stream: str, ego_x: float, live: dict[str, VehicleState]) -> None:
        s = self.s
        ahead = [st.x for vid, st in live.items() if self.stream[vid] == stream and st.x > ego_x]
        frontier = max(ahead) if ahead else ego_x + s.spawn_ahead_m - self.spacing[stream]
        x = frontier + self.spacing[stream]
        if x > ego_x + s.spawn_ahead_m:
            return
        if x < ego_x + s.scene_range_m + 20.0:  # fell behind (a blocked spot): skip this one
            x = ego_x + s.spawn_ahead_m
        self._add(stream, x, self._speed(stream), live)
        self.spacing[stream] = self._spacing(stream)

    def _length(self, stream: str) -> tuple[str, float]:
        s = self.s
        if stream == "slow" and self.rng.random() < s.truck_share:
            return TRUCK_TYPE, self._u(s.truck_length_m)
        return CAR_TYPE, self._u(s.car_length_m)

    def _free(self, lane: int, x: float, v: float, length: float, live: dict[str, VehicleState]) -> bool:
        clearance = self.s.spawn_clearance_s * v + 10.0
        return all(abs(st.x - x) - (st.length + length) / 2 >= clearance for st in live.values() if st.lane == lane)

    def _add(self, stream: str, x: float, v: float, live: dict[str, VehicleState]) -> bool:
        """Insert a vehicle with centre `x` and desired speed `v` unless the spot is taken."""
        vtype, length = self._length(stream)
        lane = self.s.stream_lane(stream)
        if x - length / 2 < 1.0 or not self._free(lane, x, v, length, live):
            return False
        self.n_added += 1
        vid = f"V{self.n_added:03d}"
        veh = self.api.vehicle
        veh.add(
            vid,
            ROUTE,
            vtype,
            depart="now",
            departLane=str(lane),
            departPos=f"{x + length / 2:.3f}",
            departSpeed=f"{v:.3f}",
        )
        veh.setLength(vid, round(length, 3))
        veh.setMaxSpeed(vid, v)
        veh.subscribe(vid, self.vars)
        self.stream[vid] = stream
        self.pending.add(vid)
        live[vid] = VehicleState(x, v, lane, length)
        return True

    def _remove(self, vid: str) -> None:
        veh = self.api.vehicle
        veh.unsubscribe(vid)  # libsumo keeps a removed vehicle's subscription and then fails
        veh.remove(vid)
        self.stream.pop(vid, None)
