"""The agent's observation, documented as data: what each input is, in which unit, how it is scaled.

`observation_spec(cfg)` describes `rl.problem.env.observation` input by input, so that a
program outside laneprint (a vehicle stack, a simulator) can build the same
vector from raw measurements. Each input's ``transform`` is one of

- ``linear``: ``value = raw * scale + offset``;
- ``log1p_capped``: ``value = log1p(min(max(raw, 0), cap)) / log1p(cap)``;
- ``constant``: ``value`` whatever the scene;
- ``flag``: 1 when the quantity it names is defined, else 0;

then clipped to ``clip`` = [lo, hi]. Where the raw quantity is undefined (its
vehicle absent, or a time to collision not closing) the input takes
``when_undefined``: ``{"value": v}`` (after scaling) or ``{"same_as": name}`` (the
raw value of another input). The test `tests/rl/test_rl_export.py` rebuilds the
observation from this description alone and checks it against `observation`.
"""

from __future__ import annotations

from typing import Any

from indicators.acceptance import MIN_SPEED_MPS
from rl.problem.env import EnvConfig, observation_names
from rl.problem.scene import DIRECTION_FEATURE, DV_RANGE_MPS, HEADWAY_CAP_S, OBS_FLOOR, TTC_CAP_S

#: Action index -> meaning (rl.problem.rewards.CHANGE = 0, KEEP = 1).
ACTIONS: dict[int, str] = {
    0: "TO CHANGE: start the lane change to the target lane now",
    1: "NOT TO CHANGE: keep the lane for this step",
}

#: Which vehicle each role is (the analysis's rule, indicators/decisions.py).
ROLES: dict[str, str] = {
    "C_f": "nearest vehicle ahead of the ego in the ego's lane",
    "C_nf": "nearest vehicle ahead of the ego in the target lane",
    "C_nb": "nearest vehicle behind (or alongside) the ego in the target lane",
    "gap": "|x_other - x_ego| - (length_ego + length_other) / 2, centre positions along the road [m]",
    "seen": "a vehicle counts only within range_m of the ego, centre to centre; farther ones are absent",
}


def _speed(name: str, who: str, cfg: EnvConfig) -> dict[str, Any]:
    spec = {
        "name": name,
        "quantity": f"speed of {who}",
        "unit": "m/s",
        "transform": "linear",
        "scale": 1.0 / cfg.v_max_mps,
        "offset": 0.0,
    }
    if name != "v_e":
        spec["when_undefined"] = {"same_as": "v_e", "why": f"{who} absent: shown moving at the ego's speed"}
    return spec


def _position(name: str, who: str, edge: float, cfg: EnvConfig) -> dict[str, Any]:
    side = "front" if edge == 1.0 else "rear"
    return {
        "name": name,
        "quantity": f"position of {who}'s centre minus the ego's centre along the road (negative behind)",
        "unit": "m",
        "transform": "linear",
        "scale": 1.0 / (2.0 * cfg.range_m),
        "offset": 0.5,
        "when_undefined": {"value": edge, "why": f"{who} absent: shown at the {side} edge of the range"},
    }


def _ttc(name: str, who: str) -> dict[str, Any]:
    return {
        "name": name,
        "quantity": f"time to collision with {who}: max(gap, 0) / (v_e - v_{who[2:]}), "
        "defined when it is seen and the ego is faster",
        "unit": "s",
        "transform": "log1p_capped",
        "cap": TTC_CAP_S,
        "when_undefined": {"value": 1.0, "why": "absent or not closing: read as the cap"},
    }


def _log_gap(name: str, quantity: str, unit: str, cap: float, who: str, also: str = "") -> dict[str, Any]:
    return {
        "name": name,
        "quantity": quantity,
        "unit": unit,
        "transform": "log1p_capped",
        "cap": cap,
        "when_undefined": {"value": 1.0, "why": f"{who} absent{also}: read as the cap (nothing within range)"},
    }


_STOPPED = f" or {{}} < {MIN_SPEED_MPS:g} m/s"


def _acceptance(cfg: EnvConfig) -> list[dict[str, Any]]:
    r = cfg.range_m
    return [
        _log_gap("gap_f", "gap to C_f (negative: alongside)", "m", r, "C_f"),
        _log_gap("thw_f", "time headway to C_f: gap_f / v_e", "s", HEADWAY_CAP_S, "C_f", _STOPPED.format("v_e")),
        _log_gap("gap_nf", "gap to C_nf, the lead gap in the target lane", "m", r, "C_nf"),
        _log_gap("gap_nb", "gap to C_nb, the lag gap in the target lane", "m", r, "C_nb"),
        _log_gap(
            "thw_nb",
            "time headway of C_nb to the ego: gap_nb / v_nb",
            "s",
            HEADWAY_CAP_S,
            "C_nb",
            _STOPPED.format("v_nb"),
        ),
    ]


def observation_spec(cfg: EnvConfig) -> list[dict[str, Any]]:
    """One dict per input of `rl.problem.env.observation(scene, cfg)`, in order (see the module doc)."""
    specs: list[dict[str, Any]] = [
        _speed("v_e", "the ego", cfg),
        {
            "name": "x_e",
            "quantity": "the ego's own position (always the middle of the range)",
            "unit": "-",
            "transform": "constant",
            "value": 0.5,
        },
        _speed("v_f", "C_f", cfg),
        _position("x_f", "C_f", 1.0, cfg),
        _speed("v_nf", "C_nf", cfg),
        _position("x_nf", "C_nf", 1.0, cfg),
        _speed("v_nb", "C_nb", cfg),
        _position("x_nb", "C_nb", 0.0, cfg),
    ]
    if cfg.observation in ("indicators", "direction", "acceptance"):
        specs += [
            _ttc("t_f", "C_f"),
            _ttc("t_nf", "C_nf"),
            {
                "name": "dv_nb",
                "quantity": f"v_e - v_nb, defined when C_nb is seen within {cfg.far_follower_m:g} m (gap)",
                "unit": "m/s",
                "transform": "linear",
                "scale": 1.0 / (2.0 * DV_RANGE_MPS),
                "offset": 0.5,
                "when_undefined": {"value": 0.5, "why": "no follower within reach: no relative speed"},
            },
            {"name": "t_f_ok", "quantity": "1 when t_f is defined", "unit": "-", "transform": "flag", "of": "t_f"},
            {"name": "t_nf_ok", "quantity": "1 when t_nf is defined", "unit": "-", "transform": "flag", "of": "t_nf"},
            {
                "name": "dv_nb_ok",
                "quantity": "1 when dv_nb is defined",
                "unit": "-",
                "transform": "flag",
                "of": "dv_nb",
            },
        ]
    if cfg.observation == "acceptance":
        specs += _acceptance(cfg)
    if cfg.observation == "direction":
        specs.append(
            {
                "name": DIRECTION_FEATURE,
                "quantity": "the side of the target lane: 1 to the left "
                "(overtaking), the floor to the right (returning)",
                "unit": "-",
                "transform": "flag",
                "of": "target lane side",
            }
        )
    for i, s in enumerate(specs):
        s["index"] = i
        s["clip"] = [OBS_FLOOR, 1.0]
    assert tuple(s["name"] for s in specs) == observation_names(cfg)
    return specs


def constants(cfg: EnvConfig) -> dict[str, float]:
    """The numbers the observation is built with."""
    return {
        "range_m": cfg.range_m,
        "v_max_mps": cfg.v_max_mps,
        "far_follower_m": cfg.far_follower_m,
        "ttc_cap_s": TTC_CAP_S,
        "headway_cap_s": HEADWAY_CAP_S,
        "dv_range_mps": DV_RANGE_MPS,
        "obs_floor": OBS_FLOOR,
        "dt_s": cfg.dt_s,
    }
