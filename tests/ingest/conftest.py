"""Tiny recordings built in memory for the ingest tests."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest


def make_recording(seconds: float = 4.0, hz: int = 50) -> tuple[dict, pd.DataFrame, pd.DataFrame]:
    """A few seconds of ego + 3 traffic vehicles entering/leaving, 2 presses (the second cancelled)."""
    n = int(seconds * hz)
    t = np.arange(n) / hz
    x = 100.0 + 25.0 * t + 0.0004 * np.arange(n)
    v = 25.0 + 0.1 * np.sin(t)
    lane = np.zeros(n, dtype=np.int64)
    lane[int(1.5 * hz) :] = 1
    y = np.where(lane == 1, 3.5, 0.0) + 0.0001 * np.arange(n)
    button = np.zeros(n, dtype=bool)
    button[int(1.0 * hz) : int(1.2 * hz)] = True  # press 1 (followed by a lane change)
    button[int(3.0 * hz) : int(3.1 * hz)] = True  # press 2 (cancelled)
    direction = pd.Series([None] * n, dtype=object)
    direction[int(1.0 * hz)] = "left"
    direction[int(3.0 * hz)] = "right"
    ego = pd.DataFrame(
        {
            "t_s": t,
            "ego_x_m": np.round(x, 3),
            "ego_y_m": np.round(y, 3),
            "ego_v_mps": np.round(v, 3),
            "ego_lane": lane,
            "ego_length_m": 4.5,
            "steer_rad": np.round(0.01 * np.sin(3 * t), 4),
            "throttle": np.round(0.3 + 0.01 * t, 4),
            "brake": 0.0,
            "lc_button": button,
            "lc_direction": direction,
        }
    )
    rows = []
    for vid, start, stop, x0, vv, ln, length in (
        ("a", 0.0, 2.5, 150.0, 22.0, 0, 4.5),
        ("b", 1.0, 4.0, 80.0, 28.5, 1, 5.2),
        ("c12", 2.0, 3.0, 200.0, 20.0, 1, 4.0),
    ):
        sel = (t >= start) & (t < stop)
        for ti in t[sel]:
            rows.append((ti, vid, round(x0 + vv * ti, 3), None if vid == "c12" else float(ln) * 3.5, vv, ln, length))
    traffic = pd.DataFrame(rows, columns=["t_s", "vehicle_id", "x_m", "y_m", "v_mps", "lane", "length_m"])
    traffic = traffic.sort_values(["t_s", "vehicle_id"], ignore_index=True)
    meta = {"driver_id": "D07", "session_id": "D07_s80_01", "speed_limit_kph": 80, "simulator": "test rig"}
    return meta, ego, traffic


@pytest.fixture
def recording():
    return make_recording()


@pytest.fixture(scope="module")
def module_recording():
    """The same recording, shared by the tests of one module (for fixtures that write files from it)."""
    return make_recording()
