"""The highway-env world of one section: a straight road, its traffic vehicles, and MOBIL with a keep-right bias.

Imports highway_env (the `highway` extra); only `section.py` imports this module.

- `FastRoad` is highway-env's `Road` with the same answers, found faster on a straight
  road along x: the neighbours of a vehicle in a lane (a vehicle is in a lane while its
  centre is within half a lane width plus 1 m of the lane's centre line, as
  `Road.neighbour_vehicles` checks with `margin=1`) from arrays cached once per step, and
  the collision check only for pairs whose x are close enough for highway-env's own
  pre-check to pass.
- `mobil_margin` is highway-env's `IDMVehicle.mobil` for one candidate lane, with the
  safety threshold as an argument and an asymmetric incentive threshold (a keep-right
  bias, as in Treiber's MOBIL for European roads); it returns how far the incentive
  clears the threshold, or None when the change is unsafe.
- `TrafficCar` is an `IDMVehicle` deciding by that MOBIL; `LaneKeeper` keeps its lane.
- `OnStraightRoad` finds a vehicle's lane from its y (what highway-env's search finds on this road).

highway-env numbers lanes from the left (index 0 = leftmost) and its y grows to the
right; the logs use LOG_FORMAT's numbering (0 = rightmost) and y to the left
(`log_lane`, `log_y`).
"""

from __future__ import annotations

from bisect import bisect_left
from typing import Any, Optional

import numpy as np
from highway_env.road.road import LaneIndex, Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle

#: highway-env's `on_lane` margin in `Road.neighbour_vehicles` [m].
_LANE_MARGIN_M = 1.0


class FastRoad(Road):
    """`Road` on a straight network along x: cached neighbour search, collision checks of close pairs only."""

    def __init__(self, network: RoadNetwork, np_random: np.random.RandomState, lane_width: float) -> None:
        super().__init__(network=network, np_random=np_random, record_history=False)
        self.lane_width = lane_width
        self.lanes = network.graph["0"]["1"]  # highway-env lane index -> lane
        self._cache: Optional[list[tuple[list[float], list[Any]]]] = None

    def invalidate(self) -> None:
        """Forget the cached positions (after vehicles moved, were added or removed)."""
        self._cache = None

    def _buckets(self) -> list[tuple[list[float], list[Any]]]:
        """Per lane, the x of the vehicles in it (sorted) and the vehicles, a vehicle being in every lane whose
        centre line is within half a lane width + 1 m of its centre."""
        if self._cache is None:
            reach = self.lane_width / 2 + _LANE_MARGIN_M
            rows: list[list[tuple[float, int, Any]]] = [[] for _ in self.lanes]
            for i, v in enumerate(self.vehicles):
                x, y = float(v.position[0]), float(v.position[1])
                for k in range(len(self.lanes)):
                    if abs(y - k * self.lane_width) <= reach:
                        rows[k].append((x, i, v))
            self._cache = []
            for row in rows:
                row.sort(key=lambda r: (r[0], r[1]))
                self._cache.append(([r[0] for r in row], [r[2] for r in row]))
        return self._cache

    def neighbour_vehicles(self, vehicle: Any, lane_index: LaneIndex = None) -> tuple[Any, Any]:
        """The nearest vehicle ahead (at or beyond the same x) and behind in `lane_index` (default its lane)."""
        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        xs, vehicles = self._buckets()[lane_index[2]]
        s = float(vehicle.position[0])
        i = bisect_left(xs, s)
        front = next((v for v in vehicles[i:] if v is not vehicle), None)
        rear = next((v for v in reversed(vehicles[:i]) if v is not vehicle), None)
        return front, rear

    def step(self, dt: float) -> None:
        """Move every vehicle, then let highway-env check collisions of pairs close enough to collide."""
        for vehicle in self.vehicles:
            vehicle.step(dt)
        self._cache = None
        if not self.vehicles:
            return
        order = sorted(self.vehicles, key=lambda v: v.position[0])
        reach = max(v.diagonal for v in order) + max(abs(v.speed) for v in order) * dt
        for i, a in enumerate(order):
            for b in order[i + 1 :]:
                if b.position[0] - a.position[0] > reach:
                    break
                a.handle_collisions(b, dt)


class OnStraightRoad:
    """Mixin for vehicles on a `FastRoad`: the closest lane from y alone (highway-env's
    `get_closest_lane_index` weighs the distance to each lane's centre line and the heading
    relative to it, which is the same for parallel lanes: the same lane, found without a search)."""

    # attributes of the highway-env vehicle this is mixed into (declared for the type checker only)
    road: Any
    position: np.ndarray
    lane_index: LaneIndex
    lane: Any
    target_lane_index: LaneIndex
    timer: float

    def on_state_update(self) -> None:
        road = self.road
        if road:
            k = min(max(int(round(float(self.position[1]) / road.lane_width)), 0), len(road.lanes) - 1)
            self.lane_index = ("0", "1", k)
            self.lane = road.lanes[k]


def straight_road(n_lanes: int, length_m: float, lane_width: float, np_random: np.random.RandomState) -> FastRoad:
    """A straight `n_lanes` road of `length_m` from x = 0, no speed limit on the lanes (the drivers' own)."""
    net = RoadNetwork.straight_road_network(lanes=n_lanes, length=length_m, speed_limit=None)
    return FastRoad(net, np_random, lane_width)


def set_length(vehicle: Any, length_m: float) -> None:
    """Give one vehicle its own length (highway-env's LENGTH is a class constant; collisions use `diagonal`)."""
    vehicle.LENGTH = float(length_m)
    vehicle.diagonal = float(np.hypot(vehicle.LENGTH, vehicle.WIDTH))


def is_right_of(vehicle: Any, lane_index: LaneIndex) -> bool:
    """Whether `lane_index` is to the right of the vehicle's lane (highway-env: a larger index)."""
    return lane_index[2] > vehicle.lane_index[2]


def mobil_margin(
    vehicle: IDMVehicle, lane_index: LaneIndex, max_braking: float, keep_right_bias: float
) -> Optional[float]:
    """highway-env's MOBIL for a change to `lane_index`: None when the new follower would have to brake
    harder than `max_braking` [m/s^2] (as the vehicle predicts it, with its own IDM), else the incentive
    minus the threshold (LANE_CHANGE_MIN_ACC_GAIN, less `keep_right_bias` for a change to the right)."""
    road = vehicle.road
    new_preceding, new_following = road.neighbour_vehicles(vehicle, lane_index)
    new_following_a = vehicle.acceleration(ego_vehicle=new_following, front_vehicle=new_preceding)
    new_following_pred_a = vehicle.acceleration(ego_vehicle=new_following, front_vehicle=vehicle)
    if new_following_pred_a < -max_braking:
        return None
    old_preceding, old_following = road.neighbour_vehicles(vehicle)
    self_pred_a = vehicle.acceleration(ego_vehicle=vehicle, front_vehicle=new_preceding)
    self_a = vehicle.acceleration(ego_vehicle=vehicle, front_vehicle=old_preceding)
    old_following_a = vehicle.acceleration(ego_vehicle=old_following, front_vehicle=vehicle)
    old_following_pred_a = vehicle.acceleration(ego_vehicle=old_following, front_vehicle=old_preceding)
    gain = (
        self_pred_a
        - self_a
        + vehicle.POLITENESS * (new_following_pred_a - new_following_a + old_following_pred_a - old_following_a)
    )
    threshold = vehicle.LANE_CHANGE_MIN_ACC_GAIN - (keep_right_bias if is_right_of(vehicle, lane_index) else 0.0)
    return float(gain - threshold)


def is_safe(vehicle: IDMVehicle, lane_index: LaneIndex, max_braking: float) -> bool:
    """Whether a change to `lane_index` is still safe as the manoeuvre starts: no overlap with the target
    lane's leader or follower, MOBIL's safety criterion (the new follower brakes at most `max_braking`),
    and the vehicle itself need not brake harder than that behind its new leader (a person looks ahead
    too; MOBIL counts that only as a loss of incentive)."""
    front, rear = vehicle.road.neighbour_vehicles(vehicle, lane_index)
    for other in (front, rear):
        if other is not None and abs(other.position[0] - vehicle.position[0]) < (other.LENGTH + vehicle.LENGTH) / 2:
            return False
    return (
        vehicle.acceleration(ego_vehicle=rear, front_vehicle=vehicle) >= -max_braking
        and vehicle.acceleration(ego_vehicle=vehicle, front_vehicle=front) >= -max_braking
    )


def best_lane(
    vehicle: IDMVehicle, max_braking: float, keep_right_bias: float, look_ahead: bool = False
) -> tuple[Optional[LaneIndex], float]:
    """The side lane MOBIL (`mobil_margin`) recommends most, with its margin, or (None, 0); with `look_ahead`
    only lanes where `is_safe` holds too."""
    best, best_margin = None, 0.0
    if abs(vehicle.speed) < 1:  # highway-env: only change lane when moving
        return best, best_margin
    for lane_index in vehicle.road.network.side_lanes(vehicle.lane_index):
        margin = mobil_margin(vehicle, lane_index, max_braking, keep_right_bias)
        if margin is None or margin < best_margin:
            continue
        if look_ahead and not is_safe(vehicle, lane_index, max_braking):
            continue
        best, best_margin = lane_index, margin
    return best, best_margin


class TrafficCar(OnStraightRoad, IDMVehicle):
    """A traffic car: highway-env's IDM, and its MOBIL with a keep-right bias (`keep_right_bias` per instance),
    changing only where it need not brake hard itself behind its new leader (`is_safe`)."""

    keep_right_bias: float = 0.0

    def change_lane_policy(self) -> None:
        if self.lane_index != self.target_lane_index:
            super().change_lane_policy()  # highway-env's handling of a change under way
            return
        if not self.timer > self.LANE_CHANGE_DELAY:
            return
        self.timer = 0
        best, _ = best_lane(self, self.LANE_CHANGE_MAX_BRAKING_IMPOSED, self.keep_right_bias, look_ahead=True)
        if best is not None:
            self.target_lane_index = best


class LaneKeeper(OnStraightRoad, IDMVehicle):
    """A truck, or a car of the right lane's slow stream: highway-env's IDM, no lane changes."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, enable_lane_change=False, **kwargs)


def log_lane(lane_index: LaneIndex, n_lanes: int) -> int:
    """LOG_FORMAT lane (0 = rightmost) of a highway-env lane index (0 = leftmost)."""
    return n_lanes - 1 - int(lane_index[2])


def log_y(y: float, n_lanes: int, lane_width: float) -> float:
    """LOG_FORMAT y (left positive, the rightmost lane's centre at 0) of a highway-env y (right positive)."""
    return (n_lanes - 1) * lane_width - float(y)
