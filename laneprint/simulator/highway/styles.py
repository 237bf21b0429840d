"""Driver styles as highway-env IDM + MOBIL parameters, and the study's drivers.

A style is a set of the ego's `IDMVehicle` constants (`STYLE_PARAMS`): car following
(IDM: `TIME_WANTED`, `DISTANCE_WANTED`, `COMFORT_ACC_MAX`), the lane-change decision
(MOBIL: `POLITENESS`, `LANE_CHANGE_MIN_ACC_GAIN`, `LANE_CHANGE_MAX_BRAKING_IMPOSED`),
the desired speed (`SPEED_FACTOR` x the limit) and a keep-right bias. Defensive
drivers keep long headways, impose little braking on a new follower and need a large
gain to change; Aggressive ones the opposite; Normal ones sit in between.

Styles are handed out round-robin over their counts (`style_counts` of the settings'
shares: 3/3/3 gives D01 Defensive, D02 Normal, D03 Aggressive, D04 Defensive, ...).
The first driver of each style drives the nominal values (`typical`); every other one
has each value multiplied by `exp(N(0, sd * SD_SCALE))`, clipped to +-2 sd: the styles
are a continuum, yet far enough apart that k-means on the true parameters finds them
(`true_parameter_ari`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from laneprint.simulator.drivers import driver_ids, style_order

#: style -> parameter -> nominal value. TIME_WANTED [s]: IDM desired time headway; DISTANCE_WANTED [m]:
#: IDM jam distance, centre to centre as highway-env measures it (its default is 5 m + the 5 m LENGTH);
#: COMFORT_ACC_MAX [m/s^2]: IDM acceleration; POLITENESS (0-1): MOBIL weight of the others' gains;
#: LANE_CHANGE_MIN_ACC_GAIN [m/s^2]: MOBIL incentive threshold; LANE_CHANGE_MAX_BRAKING_IMPOSED
#: [m/s^2]: MOBIL safety criterion, the braking the ego may impose on its new follower (small: large
#: safety margin); SPEED_FACTOR: desired speed / limit; KEEP_RIGHT_BIAS [m/s^2]: lowers the incentive
#: threshold of a change to the right (a free right lane draws the driver back when it exceeds the gain).
STYLE_PARAMS: dict[str, dict[str, float]] = {
    "Defensive": {
        "TIME_WANTED": 2.15,
        "DISTANCE_WANTED": 10.0,
        "COMFORT_ACC_MAX": 1.0,
        "POLITENESS": 0.4,
        "LANE_CHANGE_MIN_ACC_GAIN": 0.3,
        "LANE_CHANGE_MAX_BRAKING_IMPOSED": 1.0,
        "SPEED_FACTOR": 0.97,
        "KEEP_RIGHT_BIAS": 1.0,
    },
    "Normal": {
        "TIME_WANTED": 1.25,
        "DISTANCE_WANTED": 7.5,
        "COMFORT_ACC_MAX": 1.8,
        "POLITENESS": 0.2,
        "LANE_CHANGE_MIN_ACC_GAIN": 0.15,
        "LANE_CHANGE_MAX_BRAKING_IMPOSED": 2.5,
        "SPEED_FACTOR": 1.05,
        "KEEP_RIGHT_BIAS": 0.6,
    },
    "Aggressive": {
        "TIME_WANTED": 0.9,
        "DISTANCE_WANTED": 6.0,
        "COMFORT_ACC_MAX": 3.0,
        "POLITENESS": 0.05,
        "LANE_CHANGE_MIN_ACC_GAIN": 0.06,
        "LANE_CHANGE_MAX_BRAKING_IMPOSED": 4.5,
        "SPEED_FACTOR": 1.13,
        "KEEP_RIGHT_BIAS": 0.35,
    },
}
#: Relative perturbation of a parameter, as a multiple of `perturbation_sd` (1 when not listed). The
#: desired speed and the headway move less: IDM's following gap grows steeply as the speed nears the
#: desired one, so a Normal driver with a Defensive's desired speed would follow at a Defensive's
#: headway; the headway stays in its style's band (Defensive 2.02-2.28 s, Normal 1.18-1.33 s,
#: Aggressive 0.85-0.95 s at +-2 sd).
SD_SCALE: dict[str, float] = {"SPEED_FACTOR": 0.15, "TIME_WANTED": 0.3}
#: Parameters kept within these bounds after a perturbation.
BOUNDS: dict[str, tuple[float, float]] = {"POLITENESS": (0.0, 1.0)}


@dataclass(frozen=True)
class HighwayDriver:
    """One simulated driver: a style and the IDM + MOBIL parameters it drives with."""

    driver_id: str
    style: str  # Defensive / Normal / Aggressive
    typical: bool  # drives its style's nominal parameters
    params: dict[str, float]  # STYLE_PARAMS key -> value

    def to_dict(self) -> dict[str, Any]:
        return {"driver_id": self.driver_id, "style": self.style, "typical": self.typical, "params": dict(self.params)}


def perturb(nominal: dict[str, float], rng: np.random.Generator, sd: float) -> dict[str, float]:
    """Each value times exp(N(0, sd * SD_SCALE)) clipped to +-2 sd (in a fixed key order), rounded."""
    out = {}
    for key in sorted(nominal):
        z = float(np.clip(rng.normal(0.0, 1.0), -2.0, 2.0))
        lo, hi = BOUNDS.get(key, (0.0, np.inf))
        out[key] = round(float(np.clip(nominal[key] * np.exp(sd * SD_SCALE.get(key, 1.0) * z), lo, hi)), 4)
    return {k: out[k] for k in nominal}


def make_highway_drivers(
    n_drivers: int, sd: float, rng: np.random.Generator, shares: tuple[float, float, float] = (1.0, 1.0, 1.0)
) -> list[HighwayDriver]:
    """The study's drivers: styles by `style_order`, the first of each style typical (nominal values)."""
    drivers, seen = [], set()
    for did, style in zip(driver_ids(n_drivers), style_order(n_drivers, shares)):
        typical = style not in seen
        seen.add(style)
        params = dict(STYLE_PARAMS[style]) if typical else perturb(STYLE_PARAMS[style], rng, sd)
        drivers.append(HighwayDriver(did, style, typical, params))
    return drivers


def true_parameter_ari(drivers: list[HighwayDriver]) -> Optional[float]:
    """ARI of k-means (k = 3, standardised true parameters) against the styles; None with < 3 styles.

    1.0 says the styles are apart by construction: a method that misses them on this world
    cannot blame the world.
    """
    from sklearn.cluster import KMeans
    from sklearn.metrics import adjusted_rand_score
    from sklearn.preprocessing import StandardScaler

    styles = [d.style for d in drivers]
    if len(set(styles)) < 3 or len(drivers) <= 3:
        return None
    x = StandardScaler().fit_transform(np.array([[d.params[k] for k in STYLE_PARAMS["Normal"]] for d in drivers]))
    labels = KMeans(n_clusters=3, n_init=20, random_state=0).fit_predict(x)
    return float(adjusted_rand_score(styles, labels))
