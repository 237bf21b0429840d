"""Settings of the synthetic driver-in-the-loop study (one typed dataclass, units in comments).

The defaults are the shipped study (`sample_logs/`). The RL stage matches its
environment defaults to the traffic fields here (`traffic_v_min_mps`,
`traffic_v_max_mps`, `scene_range_m`, `lane_width_m`, lengths).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from laneprint.reference import FAR_FOLLOWER_M, SPEED_LIMITS_KPH

#: Decision cases: the clean one and the four untidy ones real studies have.
CASE_CLEAN = "clean"
CASE_SLOWED = "slowed"  # had to slow down behind the front car before the gap opened
CASE_NO_TARGET_LEADER = "no_target_leader"  # nobody ahead in the target lane
CASE_FAR_FOLLOWER = "far_follower"  # target-lane follower beyond FAR_FOLLOWER_M
CASE_CANCELLED = "cancelled"  # button pressed, no lane change
CASES: tuple[str, ...] = (CASE_CLEAN, CASE_SLOWED, CASE_NO_TARGET_LEADER, CASE_FAR_FOLLOWER, CASE_CANCELLED)


@dataclass(frozen=True)
class StudySettings:
    """Everything that shapes a synthetic study; `simulate_study(settings, seed)` is a pure function of it."""

    # --- the study -------------------------------------------------------------
    n_drivers: int = 10  # drivers D01..Dnn
    speed_limits_kph: tuple[int, ...] = SPEED_LIMITS_KPH  # one section (= one recording) per limit [km/h]
    decisions_per_driver: int = 50  # button presses per driver, spread over the sections
    sample_rate_hz: float = 50.0  # [Hz] log rate
    style_shares: tuple[float, float, float] = (0.3, 0.4, 0.3)  # Defensive, Normal, Aggressive shares of drivers

    # --- road and vehicles ---------------------------------------------------------
    lane_width_m: float = 3.5  # [m] two lanes: 0 right (y = 0), 1 left (y = lane_width_m)
    ego_length_m: float = 4.5  # [m]
    car_length_min_m: float = 4.0  # [m] traffic car length ~ Uniform(min, max)
    car_length_max_m: float = 5.0  # [m]
    truck_share: float = 0.1  # share of traffic vehicles that are trucks
    truck_length_min_m: float = 10.0  # [m] truck length ~ Uniform(min, max)
    truck_length_max_m: float = 16.0  # [m]
    scene_range_m: float = 150.0  # [m] a vehicle is in the log while |x - ego_x| <= this

    # --- surrounding traffic (constant speeds, independent of the section) ----------
    traffic_v_min_mps: float = 5.0  # [m/s] traffic speed ~ Uniform(min, max)
    traffic_v_max_mps: float = 14.0  # [m/s]
    extra_leader_prob: float = 0.3  # chance of a second car ahead of the front car, per lane and decision
    extra_leader_gap_m: tuple[float, float] = (20.0, 80.0)  # [m] its gap ahead of the car it follows, at the press

    # --- the ego / the driver ------------------------------------------------------
    speed_band_kph: float = 5.0  # [km/h] ego cruises at Uniform(limit - band, limit + band)
    speed_change_mps2: float = 0.4  # [m/s^2] rate of the ego's speed changes between decisions
    approach_s: tuple[float, float] = (6.0, 15.0)  # [s] waiting in lane before a press ~ Uniform
    lane_change_s: tuple[float, float] = (2.0, 2.6)  # [s] duration of the lateral move ~ Uniform
    after_change_s: tuple[float, float] = (0.5, 2.0)  # [s] ego alone after the change, before the next scene
    button_hold_s: tuple[float, float] = (0.3, 0.6)  # [s] how long the button is held ~ Uniform
    noise_ttc_s: float = 0.35  # [s] sd of the decision-to-decision variability of t_f and t_nf
    noise_dv_mps: float = 1.0  # [m/s] sd of the variability of dv_nb
    min_t_f_s: float = 1.5  # [s] shortest t_f a driver accepts (clip; the ego must leave its lane first)
    min_t_nf_s: float = 2.2  # [s] shortest t_nf a driver accepts (clip; no collision during the change)
    nb_gap_m: tuple[float, float] = (5.0, 50.0)  # [m] gap to the target-lane follower at the press ~ Uniform
    driver_slope_rel_sd: float = 0.08  # relative sd of a non-typical driver's slope A around its style's
    driver_shift_sd: tuple[float, float, float] = (0.25, 0.25, 0.5)  # sd of the line's shift at mid speed
    # (t_f [s], t_nf [s], dv_nb [m/s]); shifts are clipped to +-2 sd so styles stay separable

    # --- untidy cases (shares of each driver's decisions) ---------------------------
    share_slowed: float = 0.08  # slowed behind the front car; t_f long or undefined at the press
    share_no_target_leader: float = 0.12  # no leader in the target lane
    share_far_follower: float = 0.08  # target-lane follower farther than far_follower_m
    share_cancelled: float = 0.04  # press without lane change
    far_follower_m: float = FAR_FOLLOWER_M  # [m] beyond this a follower has no influence
    far_follower_gap_m: tuple[float, float] = (105.0, 140.0)  # [m] its gap in the far-follower case
    slowed_leader_v_mps: tuple[float, float] = (8.0, 14.0)  # [m/s] front-car speed in the slowed case
    slowed_headway_s: tuple[float, float] = (1.2, 2.0)  # [s] following headway while slowed
    slowed_follow_s: tuple[float, float] = (3.0, 8.0)  # [s] time spent following before the press
    slowed_decel_mps2: tuple[float, float] = (1.5, 2.5)  # [m/s^2] braking down to the leader's speed
    slowed_accel_mps2: float = 1.5  # [m/s^2] recovering the cruise speed after the change
    slowed_not_closing_share: float = 0.5  # of slowed cases: ego exactly at the leader's speed (t_f undefined)
    slowed_creep_mps: tuple[float, float] = (0.1, 0.3)  # [m/s] otherwise ego this much faster (t_f long)

    # --- driver inputs ---------------------------------------------------------------
    wheelbase_m: float = 2.8  # [m] for steer = ratio * wheelbase * curvature
    steering_ratio: float = 15.0  # steering-wheel angle per road-wheel angle
    steer_noise_rad: float = 0.003  # [rad] sd of steering jitter
    throttle_noise: float = 0.01  # sd of throttle jitter

    def __post_init__(self) -> None:
        if self.n_drivers < 1:
            raise ValueError("n_drivers must be at least 1")
        if not self.speed_limits_kph:
            raise ValueError("speed_limits_kph must name at least one section")
        if self.decisions_per_driver < len(self.speed_limits_kph):
            raise ValueError("decisions_per_driver must be at least one per section")
        shares = (self.share_slowed, self.share_no_target_leader, self.share_far_follower, self.share_cancelled)
        if min(shares) < 0 or sum(shares) > 1:
            raise ValueError("case shares must be >= 0 and sum to at most 1")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready copy (tuples become lists)."""
        return asdict(self)
