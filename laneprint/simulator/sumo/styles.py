"""Driver styles as SUMO vehicle-type parameters, and the study's drivers.

A style is a set of car-following and lane-change parameters, one set per
study family (`FAMILY_STYLE_PARAMS`; see `docs/history/sumo.md` for why
these values): Krauss + LC2013 for `ttc`, IDM + LC2013 for `acceptance`, Krauss +
SL2015 for `sublane`. Drivers get styles
round-robin (D01 Defensive, D02 Normal, D03 Aggressive, D04 Defensive, ...); the
first driver of each style drives the nominal values (`typical`), every other one
has each value multiplied by `exp(N(0, perturbation_sd))`, clipped to +-2 sd (a
fifth of that for speedFactor: the desired speed alone moves every time to
collision, so it may not blur the styles).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from laneprint.simulator.drivers import driver_ids, style_order

#: style -> SUMO vType attribute -> nominal value. Car following (Krauss): tau [s],
#: minGap [m], accel/decel [m/s^2], speedFactor (desired speed / limit), sigma
#: (dawdling 0-1). Lane change (LC2013): lcSpeedGain, lcSpeedGainLookahead [s],
#: lcAssertive, lcKeepRight, lcKeepRightAcceptanceTime [s], lcCooperative.
STYLE_PARAMS: dict[str, dict[str, float]] = {
    "Defensive": {
        "tau": 1.3,
        "minGap": 3.0,
        "accel": 1.8,
        "decel": 3.5,
        "speedFactor": 0.97,
        "sigma": 0.2,
        "lcSpeedGain": 1.5,
        "lcSpeedGainLookahead": 6.0,
        "lcAssertive": 0.7,
        "lcKeepRight": 1.0,
        "lcKeepRightAcceptanceTime": 6.0,
        "lcCooperative": 1.0,
    },
    "Normal": {
        "tau": 0.9,
        "minGap": 2.5,
        "accel": 2.6,
        "decel": 4.5,
        "speedFactor": 1.05,
        "sigma": 0.15,
        "lcSpeedGain": 2.0,
        "lcSpeedGainLookahead": 1.5,
        "lcAssertive": 1.2,
        "lcKeepRight": 2.0,
        "lcKeepRightAcceptanceTime": 3.0,
        "lcCooperative": 0.7,
    },
    "Aggressive": {
        "tau": 0.4,
        "minGap": 1.5,
        "accel": 3.5,
        "decel": 8.0,
        "speedFactor": 1.13,
        "sigma": 0.1,
        "lcSpeedGain": 4.0,
        "lcSpeedGainLookahead": 0.0,
        "lcAssertive": 2.5,
        "lcKeepRight": 3.0,
        "lcKeepRightAcceptanceTime": 2.0,
        "lcCooperative": 0.3,
    },
}

#: The `acceptance` family: style -> SUMO vType attribute -> nominal value. Car following (IDM):
#: tau [s] = desired time headway T, minGap [m] = standstill gap s0, accel [m/s^2] = a, decel
#: [m/s^2] = comfortable deceleration b, speedFactor (desired speed / limit). Lane change
#: (LC2013): lcAssertive (the safe gaps to the target lane's leader and follower are divided by
#: it: higher accepts shorter gaps), lcSpeedGain (eagerness to change for speed), lcKeepRight
#: (eagerness to return right), lcCooperative. What the styles differ in is what they accept
#: (headway, standstill gap, lead and lag gaps); the parameters that set the times to collision
#: of the `ttc` family (lcSpeedGainLookahead, lcKeepRightAcceptanceTime) are SUMO's defaults for all.
ACCEPTANCE_STYLE_PARAMS: dict[str, dict[str, float]] = {
    "Defensive": {
        "tau": 2.8,
        "minGap": 5.0,
        "accel": 1.2,
        "decel": 2.0,
        "speedFactor": 1.0,
        "lcAssertive": 1.6,
        "lcSpeedGain": 2.5,
        "lcKeepRight": 1.5,
        "lcCooperative": 1.0,
    },
    "Normal": {
        "tau": 1.4,
        "minGap": 2.5,
        "accel": 2.0,
        "decel": 2.8,
        "speedFactor": 1.07,
        "lcAssertive": 1.8,
        "lcSpeedGain": 1.0,
        "lcKeepRight": 1.0,
        "lcCooperative": 0.7,
    },
    "Aggressive": {
        "tau": 0.7,
        "minGap": 1.0,
        "accel": 3.0,
        "decel": 4.5,
        "speedFactor": 1.14,
        "lcAssertive": 3.0,
        "lcSpeedGain": 0.6,
        "lcKeepRight": 1.0,
        "lcCooperative": 0.3,
    },
}

#: The `sublane` family: style -> SUMO vType attribute -> nominal value. Car following (Krauss, as
#: `ttc`): tau [s] (about the time headway it keeps), minGap [m], accel / decel [m/s^2], speedFactor,
#: sigma (dawdling 0-1: its speed wavers). Lane change (SL2015 on sublanes): lcAssertive (divides the
#: safe gaps to the target lane's vehicles: larger accepts shorter gaps), lcSpeedGain (eagerness to
#: change for speed), lcKeepRight and lcKeepRightAcceptanceTime [s] (eagerness to return right; the
#: free time at full speed it wants ahead in the right lane), lcCooperative, lcPushy (0-1: squeezes into
#: a lateral gap under minGapLat), lcImpatience (-1..1: SUMO's factor on lcAssertive and lcPushy),
#: minGapLat [m] (lateral gap it keeps), maxSpeedLat [m/s] (how fast it moves sideways: a lane change
#: of 3.5 m takes about 3.5 / maxSpeedLat s and more), lcSigma (lateral positioning imperfection: it
#: wanders about its lane centre; not a randomness of its decisions, which SL2015 takes deterministically).
#: Every parameter is ordered by style, so the parameters alone tell the styles apart (the test
#: clusters them).
SUBLANE_STYLE_PARAMS: dict[str, dict[str, float]] = {
    "Defensive": {
        "tau": 2.2,
        "minGap": 4.0,
        "accel": 1.4,
        "decel": 2.5,
        "speedFactor": 1.0,
        "sigma": 0.3,
        "lcAssertive": 0.7,
        "lcSpeedGain": 1.5,
        "lcKeepRight": 0.7,
        "lcKeepRightAcceptanceTime": 5.0,
        "lcCooperative": 1.0,
        "lcPushy": 0.05,
        "lcImpatience": 0.1,
        "minGapLat": 0.9,
        "maxSpeedLat": 0.8,
        "lcSigma": 0.05,
    },
    "Normal": {
        "tau": 1.3,
        "minGap": 2.5,
        "accel": 2.0,
        "decel": 3.0,
        "speedFactor": 1.07,
        "sigma": 0.2,
        "lcAssertive": 1.4,
        "lcSpeedGain": 2.5,
        "lcKeepRight": 1.5,
        "lcKeepRightAcceptanceTime": 3.0,
        "lcCooperative": 0.7,
        "lcPushy": 0.3,
        "lcImpatience": 0.4,
        "minGapLat": 0.6,
        "maxSpeedLat": 1.2,
        "lcSigma": 0.1,
    },
    "Aggressive": {
        "tau": 0.7,
        "minGap": 1.2,
        "accel": 3.0,
        "decel": 4.5,
        "speedFactor": 1.14,
        "sigma": 0.1,
        "lcAssertive": 3.0,
        "lcSpeedGain": 4.0,
        "lcKeepRight": 3.0,
        "lcKeepRightAcceptanceTime": 2.0,
        "lcCooperative": 0.3,
        "lcPushy": 0.7,
        "lcImpatience": 0.8,
        "minGapLat": 0.3,
        "maxSpeedLat": 1.8,
        "lcSigma": 0.2,
    },
}

#: family (settings.FAMILIES) -> its styles' parameters.
FAMILY_STYLE_PARAMS: dict[str, dict[str, dict[str, float]]] = {
    "ttc": STYLE_PARAMS,
    "acceptance": ACCEPTANCE_STYLE_PARAMS,
    "sublane": SUBLANE_STYLE_PARAMS,
}

#: Parameters kept within these bounds after a perturbation (SUMO rejects some values outside).
_BOUNDS: dict[str, tuple[float, float]] = {
    "sigma": (0.0, 1.0),
    "lcCooperative": (0.0, 1.0),
    "lcPushy": (0.0, 1.0),
    "lcImpatience": (-1.0, 1.0),
}
#: Relative perturbation of a parameter, as a multiple of `perturbation_sd` (1 when not listed).
_SD_SCALE: dict[str, float] = {"speedFactor": 0.2}


@dataclass(frozen=True)
class SumoDriver:
    """One simulated driver: a style and the SUMO vType parameters it drives with."""

    driver_id: str
    style: str  # Defensive / Normal / Aggressive
    typical: bool  # drives its style's nominal parameters
    params: dict[str, float]  # SUMO vType attribute -> value

    def to_dict(self) -> dict[str, Any]:
        return {
            "driver_id": self.driver_id,
            "style": self.style,
            "typical": self.typical,
            "sumo_params": dict(self.params),
        }


def perturb(nominal: dict[str, float], rng: np.random.Generator, sd: float) -> dict[str, float]:
    """Each value times exp(N(0, sd)) clipped to +-2 sd (in a fixed key order), rounded."""
    out = {}
    for key in sorted(nominal):
        z = float(np.clip(rng.normal(0.0, 1.0), -2.0, 2.0))
        lo, hi = _BOUNDS.get(key, (0.0, np.inf))
        out[key] = round(float(np.clip(nominal[key] * np.exp(sd * _SD_SCALE.get(key, 1.0) * z), lo, hi)), 4)
    return {k: out[k] for k in nominal}


def make_sumo_drivers(
    n_drivers: int,
    sd: float,
    rng: np.random.Generator,
    family: str = "ttc",
    shares: tuple[float, float, float] = (1.0, 1.0, 1.0),
) -> list[SumoDriver]:
    """The study's drivers of `family`: styles by `style_order`, the first of each style typical (nominal values)."""
    styles = FAMILY_STYLE_PARAMS[family]
    drivers, seen = [], set()
    for did, style in zip(driver_ids(n_drivers), style_order(n_drivers, shares)):
        typical = style not in seen
        seen.add(style)
        params = dict(styles[style]) if typical else perturb(styles[style], rng, sd)
        drivers.append(SumoDriver(did, style, typical, params))
    return drivers
