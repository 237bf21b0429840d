"""Message streams on the sample clock: what both MCAP readers (JSON, and decoded ROS 2 / protobuf) share."""
from __future__ import annotations

from typing import Any

import numpy as np


def asof(sample_times: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Index of the last message at or before each sample (-1 when none yet)."""
    return np.searchsorted(times, sample_times, side="right") - 1


def place_presses(ego_times: np.ndarray, stimes: np.ndarray, states: np.ndarray,
                  dirs: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    """Button state on the ego samples (state of the last message), each press on >= 1 sample.

    `stimes`, `states`, `dirs`: the button messages in time order; returns (lc_button, lc_direction).
    """
    n = len(ego_times)
    pressed = np.zeros(n, dtype=bool)
    direction = np.full(n, None, dtype=object)
    if not len(stimes):
        return pressed, direction
    idx = asof(ego_times, stimes)
    pressed[idx >= 0] = states[idx[idx >= 0]]
    prev = np.concatenate([[False], states[:-1]])
    for k in np.flatnonzero(states & ~prev):
        i = int(np.searchsorted(ego_times, stimes[k], side="left"))
        if i < n:
            pressed[i] = True
            if dirs[k] is not None:
                direction[i] = dirs[k]
    return pressed, direction
