"""Settings of the highway-env study generator (one frozen dataclass, units in comments).

`simulate_highway_study(settings, seed)` is a pure function of these fields and the
seed: every random choice (driver perturbations, traffic, the drivers' moment-to-moment
variability) is drawn from generators derived from them.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from typing import Any, Optional

from laneprint.reference import SPEED_LIMITS_KPH

#: Numbers of lanes of the highway (`--lanes N`), the default first. Lane 0 is the rightmost (LOG_FORMAT).
LANES: tuple[int, ...] = (2, 3)
DEFAULT_LANES = LANES[0]


@dataclass(frozen=True)
class HighwaySettings:
    """Everything that shapes a highway-env study besides the seed."""

    # --- the study -------------------------------------------------------------
    n_drivers: int = 9  # drivers D01..Dnn
    style_shares: tuple[float, float, float] = (1.0, 1.0, 1.0)  # Defensive, Normal, Aggressive shares of the
    # drivers (largest remainder, at least one per style from 3 drivers on): (2, 4, 3) with 9 drivers gives 2/4/3
    speed_limits_kph: tuple[int, ...] = SPEED_LIMITS_KPH  # one recording per driver and limit [km/h]
    minutes: float = 6.0  # [min] logged driving per section
    warmup_s: float = 10.0  # [s] simulated before logging starts (traffic settles), not logged
    step_s: float = 0.1  # [s] simulation step = log period (10 Hz)
    perturbation_sd: float = 0.1  # relative sd (log-normal, clipped to +-2 sd) of a non-typical driver's
    # parameters around its style's nominal values (styles.SD_SCALE scales it per parameter)

    # --- the person in the loop ----------------------------------------------------
    decision_period_s: float = 0.5  # [s] MOBIL is consulted this often (highway-env's LANE_CHANGE_DELAY)
    settle_lateral_m: float = 0.5  # [m] no new decision while the ego is farther than this from a lane centre
    safety_noise_sd: float = 0.4  # sd of log(drawn / own LANE_CHANGE_MAX_BRAKING_IMPOSED): the braking the
    # driver accepts to impose on the new follower is re-drawn at every decision (people are inconsistent)
    reaction_s: tuple[float, float] = (0.3, 1.0)  # [s] press to start of the manoeuvre ~ Uniform; safety is
    # re-checked at the start (same drawn threshold) and a press whose gap has closed is aborted
    button_hold_s: tuple[float, float] = (0.3, 0.5)  # [s] how long the button is held ~ Uniform
    missed_press_p: float = 0.04  # probability that a lane change is made without pressing the button
    lateral_tau_s: float = 0.6  # [s] highway-env's TAU_LATERAL of the ego (lateral time constant)

    # --- road and vehicles ---------------------------------------------------------
    n_lanes: int = DEFAULT_LANES  # lanes of the road (one of LANES); lane 0 on the right in the logs
    lane_width_m: float = 4.0  # [m] highway-env's StraightLane.DEFAULT_WIDTH; lane k's centre at y = k * width
    ego_length_m: float = 4.5  # [m]
    car_length_m: tuple[float, float] = (4.0, 5.0)  # [m] traffic car length ~ Uniform
    truck_length_m: tuple[float, float] = (10.0, 16.0)  # [m] truck length ~ Uniform
    truck_share: float = 0.3  # share of rightmost-lane traffic that are trucks (keep their lane)
    truck_speed_frac: tuple[float, float] = (0.7, 0.85)  # trucks' desired speed / limit ~ Uniform
    scene_range_m: float = 200.0  # [m] a vehicle is in the log while |x - ego_x| <= this (centres)

    # --- traffic: a window around the ego --------------------------------------------
    lane_spacing_s: tuple[tuple[float, float], ...] = ((2.5, 9.0), (1.5, 5.0), (1.5, 5.0))  # [s] mean
    # centre-to-centre spacing of each lane's traffic stream in seconds of driving at the limit (rightmost,
    # middle, leftmost; two lanes use the first and the last), drawn per section, stratified over the
    # sections (study.section_densities) and the same for every driver: sections and studies differ in how
    # busy they are, alike at every limit
    lane_speed_frac: tuple[tuple[float, float], ...] = ((0.7, 0.95), (0.8, 1.05), (0.95, 1.25))  # traffic's
    # desired speed / limit ~ Uniform by lane, as lane_spacing_s: the right lane slow, the leftmost fast
    right_lane_keeps: bool = True  # the rightmost lane's stream (slow cars, and trucks always) keeps its lane;
    # the other streams' cars change lanes by MOBIL with a keep-right bias
    traffic_politeness: tuple[float, float] = (0.1, 0.5)  # MOBIL POLITENESS of traffic cars ~ Uniform
    traffic_keep_right: float = 0.5  # [m/s^2] keep-right bias of traffic cars (as the ego's KEEP_RIGHT_BIAS)
    spawn_ahead_m: float = 350.0  # [m] slower vehicles appear this far ahead of the ego
    spawn_behind_m: float = 260.0  # [m] faster vehicles appear this far behind the ego
    remove_ahead_m: float = 400.0  # [m] vehicles farther ahead than this leave the simulation
    remove_behind_m: float = 280.0  # [m] vehicles farther behind than this leave the simulation
    window_period_s: float = 0.5  # [s] the window adds and removes vehicles this often
    min_spawn_gap_s: float = 1.0  # [s] a new vehicle keeps at least 10 m + this time at its speed to its
    # lane neighbours (plus the closing speed's braking distance); otherwise it waits

    def __post_init__(self) -> None:
        if self.n_drivers < 1:
            raise ValueError("n_drivers must be at least 1")
        if self.n_lanes not in LANES:
            raise ValueError(f"n_lanes must be one of {', '.join(map(str, LANES))}")
        if len(self.style_shares) != 3 or min(self.style_shares) < 0 or sum(self.style_shares) <= 0:
            raise ValueError("style_shares needs three non-negative shares (Defensive, Normal, Aggressive)")
        if not self.speed_limits_kph:
            raise ValueError("speed_limits_kph must name at least one section")
        if self.minutes <= 0:
            raise ValueError("minutes must be positive")
        if not (
            self.scene_range_m < self.spawn_ahead_m < self.remove_ahead_m and self.spawn_behind_m < self.remove_behind_m
        ):
            raise ValueError("need scene_range_m < spawn_ahead_m < remove_ahead_m and spawn_behind_m < remove_behind_m")
        if len(self.lane_speed_frac) != 3 or len(self.lane_spacing_s) != 3:
            raise ValueError("lane_speed_frac and lane_spacing_s need three ranges (right, middle, left)")

    @property
    def duration_s(self) -> float:
        """Logged driving per section [s]."""
        return self.minutes * 60.0

    def by_lane(self, ranges: tuple[tuple[float, float], ...], lane: int) -> tuple[float, float]:
        """The (right, middle, left) range of LOG_FORMAT lane `lane` (0 = rightmost)."""
        if lane == 0:
            return ranges[0]
        return ranges[2] if lane == self.n_lanes - 1 else ranges[1]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready copy (tuples become lists)."""
        return {k: _listify(v) for k, v in asdict(self).items()}


def _listify(v: Any) -> Any:
    return [_listify(x) for x in v] if isinstance(v, tuple) else v


def simulator_text(version: str, n_lanes: int = DEFAULT_LANES) -> str:
    """The `simulator` field of a study's recordings, e.g. 'highway-env 1.12.1 (laneprint simulate --engine
    highway --lanes 3)' (the default lanes left out); `study_world` reads it back."""
    opts = "" if n_lanes == DEFAULT_LANES else f" --lanes {n_lanes}"
    return f"highway-env {version} (laneprint simulate --engine highway{opts})"


def study_world(simulator: Any) -> Optional[int]:
    """The number of lanes of a recording whose `simulator` field `simulator_text` wrote, else None."""
    m = re.search(r"\(laneprint simulate --engine highway((?: --[a-z]+ \S+)*)\)", str(simulator or ""))
    if m is None:
        return None
    return int(dict(re.findall(r"--([a-z]+) (\S+)", m.group(1))).get("lanes", DEFAULT_LANES))
