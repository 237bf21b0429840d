"""Settings of the SUMO study generator (one frozen dataclass, units in comments).

`simulate_sumo_study(settings, seed)` is a pure function of these fields and the
seed: every random choice (driver perturbations, background traffic, SUMO's own
`--seed`) is derived from them.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass, replace
from typing import Any, Optional

from laneprint.reference import SPEED_LIMITS_KPH

#: Study families (`laneprint simulate --engine sumo --family NAME`), the default first: `ttc`, styles
#: that differ in the times to collision they accept (Krauss + LC2013 in traffic that keeps the ego
#: closing on slower leaders); `acceptance`, styles that differ in the gaps and headways they accept
#: (IDM + LC2013 in a busy left lane: most presses have no closing leader); `sublane`, SUMO's sublane
#: model (Krauss + SL2015, SL2015 for the traffic too, `--lateral-resolution`): lane changes are lateral
#: moves at the driver's own lateral speed, styles differ in headway and SL2015's eagerness. See SUMO.md.
FAMILIES: tuple[str, ...] = ("ttc", "acceptance", "sublane")
DEFAULT_FAMILY = FAMILIES[0]
#: Numbers of lanes a SUMO road can have (`--lanes N`), the default first. Lane 0 is the rightmost.
LANES: tuple[int, ...] = (2, 3)
DEFAULT_LANES = LANES[0]
#: Background streams (traffic.py) and where they appear: a lane index, or "top" for the leftmost lane.
STREAM_LANES: dict[str, int | str] = {"slow": 0, "middle": 1, "left": "top", "fast": "top"}


@dataclass(frozen=True)
class SumoSettings:
    """Everything that shapes a SUMO study besides the seed."""

    # --- the study -------------------------------------------------------------
    family: str = DEFAULT_FAMILY  # one of FAMILIES: which styles (styles.FAMILY_STYLE_PARAMS) and traffic
    n_drivers: int = 9  # drivers D01..Dnn, styles round-robin Defensive, Normal, Aggressive
    style_shares: tuple[float, float, float] = (1.0, 1.0, 1.0)  # Defensive, Normal, Aggressive shares of the
    # drivers (drivers.style_counts); the round-robin skips a style whose count is used up
    speed_limits_kph: tuple[int, ...] = SPEED_LIMITS_KPH  # one SUMO run (= one recording) per limit [km/h]
    minutes: float = 5.0  # [min] logged driving per section (a lane change in progress is finished)
    step_s: float = 0.1  # [s] SUMO step length = log period (10 Hz)
    lane_change_s: float = 3.0  # [s] --lanechange.duration: a lane change is a continuous lateral move
    button_hold_s: float = 0.4  # [s] how long the button is held from the start of a lane change
    perturbation_sd: float = 0.1  # relative sd (log-normal, clipped to +-2 sd) of a non-typical
    # driver's parameters around its style's nominal values

    # --- road and vehicles ---------------------------------------------------------
    n_lanes: int = DEFAULT_LANES  # lanes of the road (one of LANES), numbered from 0 on the right
    lane_width_m: float = 3.5  # [m] lane k's centre is at y = k * lane_width_m (lane 0 right, y = 0)
    ego_length_m: float = 4.5  # [m]
    ego_start_m: float = 400.0  # [m] where the ego departs (front bumper) on the edge
    road_margin_m: float = 1500.0  # [m] road length beyond the farthest the ego can get
    car_length_m: tuple[float, float] = (4.0, 5.0)  # [m] background car length ~ Uniform
    truck_length_m: tuple[float, float] = (10.0, 16.0)  # [m] truck length ~ Uniform
    scene_range_m: float = 150.0  # [m] a vehicle is in the log while |x - ego_x| <= this (centres)
    car_follow_model: str = "Krauss"  # the ego's SUMO carFollowModel (its parameters come with the style)
    lane_change_model: str = "LC2013"  # the ego's SUMO laneChangeModel; SL2015 (sublane) for every vehicle
    lateral_resolution_m: float = 0.0  # [m] SUMO's --lateral-resolution (sublane width); 0: no sublanes
    # (LC2013). SL2015 needs it > 0: a lane change is then a lateral move at the vehicle's lateral speed
    background_sigma: float = 0.0  # Krauss dawdling (0-1) of background vehicles: their speed wavers

    # --- background traffic: a bubble around the ego ---------------------------------
    ahead_streams: tuple[str, ...] = ("slow", "left")  # streams appearing ahead of the ego (traffic.py)
    slow_speed_frac: tuple[float, float] = (0.4, 0.8)  # right-lane vehicles' desired speed / limit ~ Uniform
    truck_share: float = 0.4  # share of right-lane vehicles that are trucks
    slow_spacing_s: tuple[float, float] = (2.0, 16.0)  # [s] spacing of consecutive right-lane vehicles,
    # in seconds of driving at the limit, ~ Uniform (the ego closes on one every ~20 s)
    left_speed_frac: tuple[float, float] = (0.75, 0.92)  # cars appearing in the left lane, desired speed / limit
    left_spacing_s: tuple[float, float] = (4.0, 15.0)  # [s] their spacing, as slow_spacing_s
    middle_speed_frac: tuple[float, float] = (0.6, 0.85)  # three lanes: cars appearing in the middle lane
    # (lane 1), desired speed / limit ~ Uniform: slower than the ego, so it overtakes them on the left
    middle_spacing_s: tuple[float, float] = (6.0, 20.0)  # [s] their spacing, as slow_spacing_s
    fast_speed_frac: tuple[float, float] = (1.1, 1.3)  # faster left-lane cars from behind, speed / limit ~ Uniform
    fast_interval_s: tuple[float, float] = (60.0, 180.0)  # [s] between two faster cars appearing behind ~ Uniform
    # (they block the ego's change to the left until they have passed)
    spawn_ahead_m: float = 250.0  # [m] vehicles ahead appear this far ahead of the ego (beyond scene_range_m)
    spawn_behind_m: float = 200.0  # [m] faster cars appear this far behind the ego
    remove_behind_m: float = 220.0  # [m] vehicles farther behind the ego than this leave the simulation
    remove_ahead_m: float = 450.0  # [m] vehicles farther ahead than this leave the simulation (and those
    # faster than the ego once beyond scene_range_m + 30 m)
    spawn_clearance_s: float = 1.5  # [s] gap a new vehicle needs to its lane neighbours, as time at its own
    # speed, plus 10 m; otherwise it is not added

    def __post_init__(self) -> None:
        if self.family not in FAMILIES:
            raise ValueError(f"unknown family {self.family!r}; choose one of {', '.join(FAMILIES)}")
        if self.n_drivers < 1:
            raise ValueError("n_drivers must be at least 1")
        if len(self.style_shares) != 3 or min(self.style_shares) < 0 or sum(self.style_shares) <= 0:
            raise ValueError("style_shares needs three non-negative shares (Defensive, Normal, Aggressive)")
        if self.n_lanes not in LANES:
            raise ValueError(f"n_lanes must be one of {', '.join(map(str, LANES))}")
        bad = [st for st in self.ahead_streams if st not in STREAM_LANES or self.stream_lane(st) >= self.n_lanes]
        if bad:
            raise ValueError(f"stream {bad[0]!r} does not fit a {self.n_lanes}-lane road")
        if not self.speed_limits_kph:
            raise ValueError("speed_limits_kph must name at least one section")
        if (self.lane_change_model == "SL2015") != (self.lateral_resolution_m > 0):
            raise ValueError("SL2015 needs lateral_resolution_m > 0 (sublanes), and sublanes need SL2015")
        if self.minutes <= 0:
            raise ValueError("minutes must be positive")
        if self.spawn_ahead_m <= self.scene_range_m or self.remove_ahead_m <= self.spawn_ahead_m:
            raise ValueError("need scene_range_m < spawn_ahead_m < remove_ahead_m")

    @property
    def duration_s(self) -> float:
        """Logged driving per section [s]."""
        return self.minutes * 60.0

    def stream_lane(self, stream: str) -> int:
        """The lane in which vehicles of `stream` appear."""
        lane = STREAM_LANES[stream]
        return self.n_lanes - 1 if lane == "top" else int(lane)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready copy (tuples become lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


#: What each family changes in `SumoSettings()` (the default family changes nothing). `acceptance`:
#: IDM for the ego; slower right-lane vehicles with wavering speeds, and a busy left lane fed from
#: behind by cars near the limit, so the ego mostly follows a leader at its own speed and waits for a
#: gap it accepts before changing left, and returns right when the right lane has room. Its drivers
#: wait for gaps, so they press about a third as often as the `ttc` family's: 15 minutes a section
#: give a study about as many presses as the third simulator's study of issue 18 (docs/history/sumo.md, "Study
#: length"). `sublane`: SL2015 on sublanes of `lateral_resolution_m` for every vehicle, Krauss for the
#: ego; the default family's traffic with faster cars from behind every 8-25 s (they are the target
#: lane's followers the styles accept or wait for); 6 minutes a section give every driver 20 or more
#: presses (docs/history/sumo.md, "The `sublane` family").
FAMILY_OVERRIDES: dict[str, dict[str, Any]] = {
    "ttc": {},
    "acceptance": {
        "minutes": 15.0,
        "car_follow_model": "IDM",
        "background_sigma": 0.3,
        "ahead_streams": ("slow",),
        "slow_speed_frac": (0.7, 0.9),
        "slow_spacing_s": (3.0, 20.0),
        "fast_speed_frac": (1.1, 1.3),
        "fast_interval_s": (3.0, 10.0),
    },
    "sublane": {
        "minutes": 6.0,
        "car_follow_model": "Krauss",
        "lane_change_model": "SL2015",
        "lateral_resolution_m": 0.8,
        "fast_speed_frac": (1.05, 1.25),
        "fast_interval_s": (8.0, 25.0),
    },
}


#: What a road of more lanes changes on top of its family's settings: (family, lanes) -> changes.
#: Three lanes add the `middle` stream (slower cars in lane 1), so the ego meets slower leaders in
#: every lane but the top one: it changes left from lanes 0 and 1 (speed gain) and right from lanes
#: 2 and 1 (keep right). The `left` and `fast` streams move to the top lane (`STREAM_LANES`).
LANE_OVERRIDES: dict[tuple[str, int], dict[str, Any]] = {
    ("ttc", 3): {"ahead_streams": ("slow", "middle", "left")},
    ("acceptance", 3): {
        "ahead_streams": ("slow", "middle"),
        "middle_speed_frac": (0.8, 0.95),
        "middle_spacing_s": (4.0, 16.0),
    },
    ("sublane", 3): {"ahead_streams": ("slow", "middle", "left")},
}


def family_settings(family: str = DEFAULT_FAMILY, n_lanes: int = DEFAULT_LANES, **changes: Any) -> SumoSettings:
    """`SumoSettings` of `family` (its `FAMILY_OVERRIDES`) on `n_lanes` lanes (`LANE_OVERRIDES`), then `changes`."""
    if family not in FAMILY_OVERRIDES:
        raise ValueError(f"unknown family {family!r}; choose one of {', '.join(FAMILIES)}")
    if n_lanes not in LANES:
        raise ValueError(f"n_lanes must be one of {', '.join(map(str, LANES))}")
    return replace(
        SumoSettings(),
        family=family,
        n_lanes=n_lanes,
        **{**FAMILY_OVERRIDES[family], **LANE_OVERRIDES.get((family, n_lanes), {}), **changes},
    )


def simulator_text(sumo_version: str, family: str = DEFAULT_FAMILY, n_lanes: int = DEFAULT_LANES) -> str:
    """The `simulator` field of a study's recordings, e.g. 'Eclipse SUMO 1.24.0 (laneprint simulate --engine
    sumo --family acceptance --lanes 3)' (defaults left out); `study_traffic` reads it back."""
    opts = "" if family == DEFAULT_FAMILY else f" --family {family}"
    opts += "" if n_lanes == DEFAULT_LANES else f" --lanes {n_lanes}"
    return f"Eclipse SUMO {sumo_version} (laneprint simulate --engine sumo{opts})"


def study_traffic(simulator: Any) -> Optional[tuple[str, int]]:
    """(family, lanes) of a recording whose `simulator` field `simulator_text` wrote, else None."""
    m = re.search(r"\(laneprint simulate --engine sumo((?: --[a-z]+ \S+)*)\)", str(simulator or ""))
    if m is None:
        return None
    opts = dict(re.findall(r"--([a-z]+) (\S+)", m.group(1)))
    return opts.get("family", DEFAULT_FAMILY), int(opts.get("lanes", DEFAULT_LANES))
