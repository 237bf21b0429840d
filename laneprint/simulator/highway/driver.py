"""The ego: a person driving a highway-env `IDMVehicle`, with a lane-change button.

Car following is highway-env's IDM with the driver's constants. Lane changes are
decided by MOBIL (`world.mobil_margin`) every `decision_period_s`, while the ego is
settled in its lane, and carried out by highway-env's lateral controller. What makes
the driver a person rather than a model:

- the braking the driver accepts to impose on the new follower is re-drawn at every
  decision: its own `LANE_CHANGE_MAX_BRAKING_IMPOSED` x exp(N(0, safety_noise_sd));
- when MOBIL first picks a new lane the button is pressed (held `button_hold_s`), and
  the manoeuvre starts after a reaction time (`reaction_s`); safety is checked again
  then, with the same drawn threshold, and when it no longer holds the press is
  **aborted** (a press without a lane change);
- now and then (`missed_press_p`) the lane change is made without pressing: a
  **missed** press.

Every decision is kept in `decisions` (times in simulation seconds, highway-env lanes).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
from highway_env.road.road import LaneIndex
from highway_env.vehicle.behavior import IDMVehicle

from laneprint.simulator.highway.settings import HighwaySettings
from laneprint.simulator.highway.world import OnStraightRoad, best_lane, is_right_of, is_safe


@dataclass
class Decision:
    """One lane-change decision of the ego (MOBIL picked a new lane)."""

    t_s: float  # simulation time of the decision = of the press [s]
    from_lane: LaneIndex  # highway-env lane indices
    target_lane: LaneIndex
    direction: str  # 'left' / 'right'
    pressed: bool  # False: a missed press
    hold_s: float  # how long the button is held [s]
    start_t_s: float  # when the manoeuvre is due to start [s]
    max_braking: float  # the drawn safety threshold [m/s^2]
    margin: float  # MOBIL's incentive minus threshold at the decision [m/s^2]
    started: Optional[bool] = None  # the manoeuvre started (None while waiting); False: aborted


class HumanDriver(OnStraightRoad, IDMVehicle):
    """highway-env's IDMVehicle with a driver's constants and a human lane-change decision."""

    def __init__(
        self,
        road: Any,
        position: np.ndarray,
        speed: float,
        params: dict[str, float],
        limit_mps: float,
        settings: HighwaySettings,
        rng: np.random.Generator,
    ) -> None:
        super().__init__(road, position, speed=speed, target_speed=params["SPEED_FACTOR"] * limit_mps, timer=0.0)
        for key in (
            "TIME_WANTED",
            "DISTANCE_WANTED",
            "COMFORT_ACC_MAX",
            "POLITENESS",
            "LANE_CHANGE_MIN_ACC_GAIN",
            "LANE_CHANGE_MAX_BRAKING_IMPOSED",
        ):
            setattr(self, key, float(params[key]))
        self.keep_right_bias = float(params["KEEP_RIGHT_BIAS"])
        self.LANE_CHANGE_DELAY = settings.decision_period_s
        self.KP_LATERAL = 1.0 / settings.lateral_tau_s
        self.settings = settings
        self.rng = rng
        self.clock = 0.0  # simulation time [s]
        self.decisions: list[Decision] = []
        self.pending: Optional[Decision] = None

    def step(self, dt: float) -> None:
        super().step(dt)
        self.clock = round(self.clock + dt, 9)

    def lateral_offset(self) -> float:
        """Distance of the ego's centre from its lane's centre line [m]."""
        return abs(float(self.lane.local_coordinates(self.position)[1]))

    def change_lane_policy(self) -> None:
        if self.pending is not None:
            self._maybe_start()
            return
        if self.lane_index != self.target_lane_index:
            super().change_lane_policy()  # highway-env's handling of a change under way
            return
        if not self.timer > self.LANE_CHANGE_DELAY or self.lateral_offset() > self.settings.settle_lateral_m:
            return
        self.timer = 0
        noise = float(np.exp(self.rng.normal(0.0, self.settings.safety_noise_sd)))
        max_braking = self.LANE_CHANGE_MAX_BRAKING_IMPOSED * noise  # re-drawn at every decision
        best, best_margin = best_lane(self, max_braking, self.keep_right_bias)
        if best is not None:
            self._decide(best, max_braking, best_margin)

    def _decide(self, lane_index: LaneIndex, max_braking: float, margin: float) -> None:
        s, rng = self.settings, self.rng
        pressed = bool(rng.random() >= s.missed_press_p)
        dec = Decision(
            t_s=self.clock,
            from_lane=self.lane_index,
            target_lane=lane_index,
            direction="right" if is_right_of(self, lane_index) else "left",
            pressed=pressed,
            hold_s=float(rng.uniform(*s.button_hold_s)),
            start_t_s=self.clock + float(rng.uniform(*s.reaction_s)),
            max_braking=max_braking,
            margin=margin,
        )
        self.decisions.append(dec)
        self.pending = dec
        self._maybe_start()

    def _maybe_start(self) -> None:
        """Start the pending manoeuvre when its reaction time is over and the gap is still safe; else abort."""
        dec = self.pending
        if dec is None or self.clock + 1e-9 < dec.start_t_s:
            return
        self.pending = None
        self.timer = 0
        dec.started = bool(self.lane_index == dec.from_lane and is_safe(self, dec.target_lane, dec.max_braking))
        if dec.started:
            self.target_lane_index = dec.target_lane
