"""Small studies generated in memory, and an independent reading of the indicators from frames."""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Optional

import numpy as np
import pandas as pd
import pytest

from laneprint.simulator import StudySettings, simulate_study

SMALL = replace(StudySettings(), n_drivers=3, speed_limits_kph=(60, 90), decisions_per_driver=13)


@pytest.fixture(scope="session")
def small_settings() -> StudySettings:
    return SMALL


@pytest.fixture(scope="session")
def small_study():
    return simulate_study(SMALL, seed=7)


@pytest.fixture(scope="session")
def default_study():
    """The shipped study, in memory (about a second)."""
    return simulate_study(StudySettings(), seed=0)


def scene_at(ego: pd.DataFrame, traffic: pd.DataFrame, t: float, target_lane: int) -> dict[str, Any]:
    """LOG_FORMAT's indicators at time t, computed from the frames alone (nearest cars, centre x, lengths)."""
    e = ego.loc[np.isclose(ego["t_s"], t, atol=1e-6)].iloc[0]
    cars = traffic.loc[np.isclose(traffic["t_s"], t, atol=1e-6)]
    dx = cars["x_m"] - e["ego_x_m"]
    gap = dx.abs() - (cars["length_m"] + e["ego_length_m"]) / 2
    v = e["ego_v_mps"]

    def pick(mask: pd.Series, ahead: bool) -> Optional[pd.Series]:
        if not mask.any():
            return None
        sel = dx[mask]
        return cars.loc[sel.idxmin() if ahead else sel.idxmax()]

    def ttc(car: Optional[pd.Series]) -> Optional[float]:
        if car is None or not v > car["v_mps"]:
            return None
        return float(gap[car.name] / (v - car["v_mps"]))

    f = pick((cars["lane"] == e["ego_lane"]) & (dx > 0), True)
    nf = pick((cars["lane"] == target_lane) & (dx > 0), True)
    nb = pick((cars["lane"] == target_lane) & (dx < 0), False)
    return {
        "v_e": float(v),
        "ego_lane": int(e["ego_lane"]),
        "f": f,
        "nf": nf,
        "nb": nb,
        "t_f": ttc(f),
        "t_nf": ttc(nf),
        "dv_nb": None if nb is None else float(v - nb["v_mps"]),
        "nb_gap": None if nb is None else float(gap[nb.name]),
    }


@pytest.fixture
def indicators_at():
    return scene_at


def press_times(ego: pd.DataFrame) -> np.ndarray:
    """Times of the rising edges of the lane-change button."""
    b = ego["lc_button"].to_numpy(dtype=bool)
    edges = np.flatnonzero(b & ~np.concatenate([[False], b[:-1]]))
    return ego["t_s"].to_numpy()[edges]


@pytest.fixture
def presses():
    return press_times
