"""One recording: a driver in one section, episode after episode.

An episode is one decision. The ego drives in its lane behind a slower front car
(the "not yet" seconds: its time to collision shrinks), the driver presses the
button the moment the scene meets the driver's personal values for `t_f`, `t_nf`
and `dv_nb` (line + noise at the current speed), then changes lane over 2-3 s.
The scene is built backwards from the press: every traffic car drives at a
constant speed, so placing it at the press fixes it for the whole episode, and the
indicators computed from the log at the press equal the driver's values exactly.

Each episode has its own cars (stable ids, never reused); they are in the log from
the episode's start until the lane change ends (a scene cut: the simulator's
traffic is re-spawned for the next decision), and only while within
`scene_range_m` of the ego.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from laneprint.reference import kph_to_mps
from laneprint.simulator.config import (
    CASE_CANCELLED,
    CASE_FAR_FOLLOWER,
    CASE_NO_TARGET_LEADER,
    CASE_SLOWED,
    StudySettings,
)
from laneprint.simulator.drivers import Driver

_MIN_SPACING_M = 2.0  # [m] bumper-to-bumper distance kept between traffic cars of one lane
_MAX_TRIES = 400
_Car = tuple[
    str, int, float, float, float
]  # role, lane, v [m/s], dx from the ego's centre at the press [m], length [m]


@dataclass
class _Vehicle:
    vid: str
    role: str  # f, f2, nf, nf2, nb
    lane: int
    v: float  # [m/s]
    x_press: float  # [m] centre at the press
    length: float  # [m]


@dataclass
class RecordingResult:
    """Frames of one recording plus the ground truth of its decisions."""

    meta: dict[str, Any]
    ego: pd.DataFrame
    traffic: pd.DataFrame
    decisions: list[dict[str, Any]] = field(default_factory=list)


def _u(rng: np.random.Generator, lo_hi: tuple[float, float]) -> float:
    return float(rng.uniform(lo_hi[0], lo_hi[1]))


def _ramp(v_from: float, v_to: float, rate: float, hz: float) -> np.ndarray:
    """Speeds of the samples of a linear speed change (excluding the start value)."""
    n = int(math.ceil(abs(v_to - v_from) / rate * hz))
    if n == 0:
        return np.zeros(0)
    return v_from + (v_to - v_from) * np.arange(1, n + 1) / n


class RecordingBuilder:
    """Appends episodes to one recording; `finish()` returns the frames."""

    def __init__(
        self,
        settings: StudySettings,
        rng: np.random.Generator,
        driver: Driver,
        speed_limit_kph: float,
        session_id: str,
        simulator: str,
    ) -> None:
        self.s = settings
        self.rng = rng
        self.driver = driver
        self.limit = float(speed_limit_kph)
        self.session_id = session_id
        self.simulator = simulator
        self.hz = settings.sample_rate_hz
        self.dt = 1.0 / self.hz
        self.v_parts: list[np.ndarray] = []
        self.x_parts: list[np.ndarray] = []
        self.y_parts: list[np.ndarray] = []
        self.lane_parts: list[np.ndarray] = []
        self.button_parts: list[np.ndarray] = []
        self.dir_parts: list[np.ndarray] = []
        self.traffic_parts: list[dict[str, np.ndarray]] = []
        self.decisions: list[dict[str, Any]] = []
        self.n = 0  # samples so far
        self.x_last: float | None = None
        self.v_last: float | None = None
        self.lane = 0
        self.n_vehicles = 0

    # --- helpers ---------------------------------------------------------------

    def _lane_y(self, lane: int) -> float:
        return lane * self.s.lane_width_m

    def _new_id(self) -> str:
        self.n_vehicles += 1
        return f"V{self.n_vehicles:03d}"

    def _length(self) -> float:
        s = self.s
        if self.rng.random() < s.truck_share:
            return _u(self.rng, (s.truck_length_min_m, s.truck_length_max_m))
        return _u(self.rng, (s.car_length_min_m, s.car_length_max_m))

    def _cruise_speed(self) -> float:
        band = self.s.speed_band_kph
        return kph_to_mps(float(self.rng.uniform(self.limit - band, self.limit + band)))

    def _preference(self, indicator: str, v: float) -> tuple[float, float]:
        """(line value, line value + noise clipped to what the scene allows) at ego speed v."""
        line = self.driver.line_value(indicator, v)
        if indicator == "dv_nb":
            return line, line + float(self.rng.normal(0.0, self.s.noise_dv_mps))
        lo = self.s.min_t_f_s if indicator == "t_f" else self.s.min_t_nf_s
        return line, max(lo, line + float(self.rng.normal(0.0, self.s.noise_ttc_s)))

    def _speed_between(self, lo: float, hi: float) -> float:
        if lo >= hi:
            return hi
        return float(self.rng.uniform(lo, hi))

    def _place_cars(
        self,
        case: str,
        v: float,
        t_f: float,
        t_nf: float,
        dv_nb: float,
        slowed_leader_v: float | None,
        from_lane: int,
        to_lane: int,
        t_app: float,
        t_cut: float,
    ) -> list[_Car]:
        """The episode's cars as (role, lane, v, dx from the ego's centre at the press, length).

        Redrawn until no two cars of a lane touch between `t_app` before and `t_cut` after the press.
        """
        s, rng = self.s, self.rng
        le = s.ego_length_m
        range_gap = s.scene_range_m - 5.0
        has_nf = case != CASE_NO_TARGET_LEADER
        for _ in range(_MAX_TRIES):
            cars: list[_Car] = []
            lf = self._length()
            if slowed_leader_v is not None:  # following at the leader's speed (or creeping a little faster)
                vf = slowed_leader_v
                gap_f = _u(rng, s.slowed_headway_s) * v
            else:
                vf = self._speed_between(
                    max(s.traffic_v_min_mps, v - (range_gap - (le + lf) / 2) / t_f), min(s.traffic_v_max_mps, v - 0.5)
                )
                gap_f = t_f * (v - vf)
            cars.append(("f", from_lane, vf, gap_f + (le + lf) / 2, lf))
            if has_nf:
                lnf = self._length()
                hi = min(s.traffic_v_max_mps, v - 0.5)
                lo = max(min(s.traffic_v_min_mps, hi - 2.0), v - (range_gap - (le + lnf) / 2) / t_nf)
                vnf = self._speed_between(lo, hi)
                cars.append(("nf", to_lane, vnf, t_nf * (v - vnf) + (le + lnf) / 2, lnf))
            lnb = self._length()
            if case == CASE_FAR_FOLLOWER:
                vnb = _u(rng, (s.traffic_v_min_mps, s.traffic_v_max_mps))
                gap_nb = _u(rng, s.far_follower_gap_m)
            else:
                vnb = v - dv_nb
                closing = max(0.0, vnb - v)  # a faster follower closes in during the change
                gap_nb = _u(rng, s.nb_gap_m) + closing * (t_cut + 1.0)
            cars.append(("nb", to_lane, vnb, -(gap_nb + (le + lnb) / 2), lnb))
            for role, lane, ahead in (("f2", from_lane, cars[0]), ("nf2", to_lane, cars[1] if has_nf else None)):
                if ahead is not None and rng.random() < s.extra_leader_prob:
                    l2 = self._length()
                    dx = ahead[3] + (ahead[4] + l2) / 2 + _u(rng, s.extra_leader_gap_m)
                    cars.append((role, lane, _u(rng, (s.traffic_v_min_mps, s.traffic_v_max_mps)), dx, l2))
            if _lanes_ordered(cars, -t_app, t_cut):
                return cars
        raise RuntimeError(f"{self.session_id}: could not place a consistent scene")  # pragma: no cover

    # --- one episode ---------------------------------------------------------------

    def add_episode(self, case: str) -> None:
        """Append one decision episode of the given case."""
        s, rng, hz = self.s, self.rng, self.hz
        v_cruise = self._cruise_speed()
        if self.v_last is None:  # first sample of the recording
            self.v_last = v_cruise
            self.x_last = -v_cruise * self.dt
        from_lane = self.lane
        to_lane = 1 - from_lane
        direction = "left" if to_lane > from_lane else "right"
        le = s.ego_length_m

        # ego speed up to and including the press sample
        ramp = _ramp(self.v_last, v_cruise, s.speed_change_mps2, hz)
        if case == CASE_SLOWED:
            v_f = _u(rng, s.slowed_leader_v_mps)
            creep = 0.0 if rng.random() < s.slowed_not_closing_share else _u(rng, s.slowed_creep_mps)
            v_press = v_f + creep
            cruise = np.full(int(round(_u(rng, (1.0, 4.0)) * hz)), v_cruise)
            brake = _ramp(v_cruise, v_press, _u(rng, s.slowed_decel_mps2), hz)
            follow = np.full(int(round(_u(rng, s.slowed_follow_s) * hz)), v_press)
            before = np.concatenate([ramp, cruise, brake, follow])
        else:
            v_press = v_cruise
            n_app = max(int(round(_u(rng, s.approach_s) * hz)), len(ramp) + int(2 * hz))
            before = np.concatenate([ramp, np.full(n_app - len(ramp), v_cruise)])
        p = len(before) - 1  # local index of the press sample
        before[p] = v_press  # exact, so a not-closing TTC is exactly undefined
        v = v_press

        # the driver's values at the press
        line = {k: self.driver.line_value(k, v) for k in ("t_f", "t_nf", "dv_nb")}
        _, t_f = self._preference("t_f", v)
        _, t_nf = self._preference("t_nf", v)
        _, dv_nb = self._preference("dv_nb", v)
        has_nf = case != CASE_NO_TARGET_LEADER
        changed = case != CASE_CANCELLED

        n_hold = max(1, int(round(_u(rng, s.button_hold_s) * hz)))
        if changed:
            dur = _u(rng, s.lane_change_s)
            if has_nf:
                dur = min(dur, t_nf - 0.2)
            n_man = max(2, int(round(dur * hz)))
            n_cut = n_man  # traffic leaves the log when the lateral move ends
        else:
            n_man = 0
            n_cut = n_hold + int(round(_u(rng, (0.3, 0.6)) * hz))

        cars = self._place_cars(
            case, v, t_f, t_nf, dv_nb, v_f if case == CASE_SLOWED else None, from_lane, to_lane, p / hz, n_cut / hz
        )

        # ego arrays for the whole episode
        after_v: list[np.ndarray] = [np.full(n_man, v)]
        n_post = int(round(_u(rng, s.after_change_s) * hz))
        if case == CASE_SLOWED:
            rec = _ramp(v, v_cruise, s.slowed_accel_mps2, hz)
            after_v.append(rec)
            n_post = max(0, n_post - len(rec))
        after_v.append(np.full(n_post if changed else n_cut + n_post, v if case != CASE_SLOWED else v_cruise))
        v_loc = np.concatenate([before] + after_v)
        n_loc = len(v_loc)
        prev = np.concatenate([[self.v_last], v_loc[:-1]])
        x_loc = self.x_last + np.cumsum((prev + v_loc) / 2.0 * self.dt)

        y0, y1 = self._lane_y(from_lane), self._lane_y(to_lane)
        tau = (np.arange(n_loc) - p) / hz
        y_loc = np.full(n_loc, y0)
        lane_loc = np.full(n_loc, from_lane, dtype=np.int64)
        if changed:
            d = n_man / hz
            k = (tau >= 0) & (tau <= d)
            y_loc[k] = y0 + (y1 - y0) * (1.0 - np.cos(np.pi * tau[k] / d)) / 2.0
            y_loc[tau > d] = y1
            lane_loc[tau >= d / 2.0] = to_lane
        button = np.zeros(n_loc, dtype=bool)
        button[p : p + n_hold] = True
        dirs = np.full(n_loc, None, dtype=object)
        dirs[p : p + n_hold] = direction

        # traffic rows
        t0 = self.n
        t_press = (t0 + p) / hz
        x_e_press = float(x_loc[p])
        idx_window = np.arange(0, p + n_cut)
        t_window = (t0 + idx_window) / hz
        roles: dict[str, _Vehicle] = {}
        for role, lane, vv, dx, ln in cars:
            veh = _Vehicle(self._new_id(), role, lane, vv, x_e_press + dx, ln)
            roles[role] = veh
            xs = veh.x_press + veh.v * (t_window - t_press)
            inside = np.abs(xs - x_loc[idx_window]) <= s.scene_range_m
            m = int(inside.sum())
            if m == 0:
                continue
            self.traffic_parts.append(
                {
                    "t_s": t_window[inside],
                    "vehicle_id": np.full(m, veh.vid, dtype=object),
                    "x_m": xs[inside],
                    "y_m": np.full(m, self._lane_y(lane)),
                    "v_mps": np.full(m, veh.v),
                    "lane": np.full(m, lane, dtype=np.int64),
                    "length_m": np.full(m, veh.length),
                }
            )

        # ground truth of this decision, computed as LOG_FORMAT defines the indicators
        f, nb = roles["f"], roles["nb"]
        nf = roles.get("nf")
        gap_f_real = (f.x_press - x_e_press) - (f.length + le) / 2
        t_f_real = gap_f_real / (v - f.v) if v > f.v else None
        t_nf_real = None
        gap_nf_real = None
        if nf is not None:
            gap_nf_real = (nf.x_press - x_e_press) - (nf.length + le) / 2
            t_nf_real = gap_nf_real / (v - nf.v)
        gap_nb_real = (x_e_press - nb.x_press) - (nb.length + le) / 2
        self.decisions.append(
            {
                "session_id": self.session_id,
                "driver_id": self.driver.driver_id,
                "index": len(self.decisions),
                "press_t_s": t_press,
                "case": case,
                "direction": direction,
                "from_lane": from_lane,
                "target_lane": to_lane,
                "changed": changed,
                "speed_limit_kph": self.limit,
                "v_e_mps": v,
                "t_f_s": t_f_real,
                "t_f_status": "ok" if t_f_real is not None else "not_closing",
                "t_nf_s": t_nf_real,
                "t_nf_status": "ok" if nf is not None else "absent",
                "dv_nb_mps": v - nb.v,
                "dv_nb_status": "far" if gap_nb_real > s.far_follower_m else "ok",
                "from_preference": {
                    "t_f": case != CASE_SLOWED,
                    "t_nf": nf is not None,
                    "dv_nb": case != CASE_FAR_FOLLOWER,
                },
                "line": line,
                "gaps_m": {"f": gap_f_real, "nf": gap_nf_real, "nb": gap_nb_real},
                "vehicles": {r: veh.vid for r, veh in roles.items()},
                "episode_start_t_s": t0 / hz,
                "episode_end_t_s": (t0 + n_loc - 1) / hz,
                "lane_change_end_t_s": (t0 + p + n_man) / hz if changed else None,
            }
        )

        self.v_parts.append(v_loc)
        self.x_parts.append(x_loc)
        self.y_parts.append(y_loc)
        self.lane_parts.append(lane_loc)
        self.button_parts.append(button)
        self.dir_parts.append(dirs)
        self.n += n_loc
        self.x_last = float(x_loc[-1])
        self.v_last = float(v_loc[-1])
        self.lane = int(lane_loc[-1])

    # --- the frames --------------------------------------------------------------

    def finish(self) -> RecordingResult:
        """Concatenate the episodes into EGO and TRAFFIC frames."""
        s, hz = self.s, self.hz
        v = np.concatenate(self.v_parts)
        y = np.concatenate(self.y_parts)
        n = len(v)
        t = np.arange(n) / hz
        x = np.concatenate(self.x_parts)  # the positions the scenes were placed against
        a = np.gradient(v, self.dt)
        ay = np.gradient(np.gradient(y, self.dt), self.dt)
        steer = s.steering_ratio * s.wheelbase_m * ay / np.maximum(v, 1.0) ** 2
        steer = steer + self.rng.normal(0.0, s.steer_noise_rad, n)
        braking = a < -0.3
        throttle = np.clip(0.12 + 0.008 * v + 0.15 * a + self.rng.normal(0.0, s.throttle_noise, n), 0.0, 1.0)
        throttle[braking] = 0.0
        brake = np.where(braking, np.clip(-a / 8.0, 0.0, 1.0), 0.0)
        ego = pd.DataFrame(
            {
                "t_s": t,
                "ego_x_m": x,
                "ego_y_m": y,
                "ego_v_mps": v,
                "ego_lane": np.concatenate(self.lane_parts),
                "ego_length_m": np.full(n, s.ego_length_m),
                "steer_rad": steer,
                "throttle": throttle,
                "brake": brake,
                "lc_button": np.concatenate(self.button_parts),
                "lc_direction": np.concatenate(self.dir_parts),
            }
        )
        if self.traffic_parts:
            traffic = pd.DataFrame(
                {k: np.concatenate([p[k] for p in self.traffic_parts]) for k in self.traffic_parts[0]}
            )
            traffic = traffic.sort_values(["t_s", "vehicle_id"], kind="stable").reset_index(drop=True)
        else:
            traffic = pd.DataFrame(
                {"t_s": [], "vehicle_id": [], "x_m": [], "y_m": [], "v_mps": [], "lane": [], "length_m": []}
            )
        meta = {
            "driver_id": self.driver.driver_id,
            "session_id": self.session_id,
            "speed_limit_kph": self.limit,
            "simulator": self.simulator,
        }
        return RecordingResult(meta, ego, traffic, self.decisions)


def _lanes_ordered(cars: list[_Car], tau0: float, tau1: float) -> bool:
    """True when no two cars of one lane touch between press-relative times tau0 and tau1.

    Constant speeds make each distance linear in time, so the window's ends suffice.
    """
    for lane in {c[1] for c in cars}:
        in_lane = sorted((c for c in cars if c[1] == lane), key=lambda c: c[3])
        for back, front in zip(in_lane, in_lane[1:]):
            need = (back[4] + front[4]) / 2 + _MIN_SPACING_M
            for tau in (tau0, tau1):
                if (front[3] + front[2] * tau) - (back[3] + back[2] * tau) < need:
                    return False
    return True
