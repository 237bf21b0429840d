"""Message streams on the sample clock: what both MCAP readers (JSON, and decoded ROS 2 / protobuf) share."""

from __future__ import annotations

from typing import Any

import numpy as np


def asof(sample_times: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Index of the last message at or before each sample (-1 when none yet)."""
    return np.searchsorted(times, sample_times, side="right") - 1


def place_presses(
    ego_times: np.ndarray, stimes: np.ndarray, states: np.ndarray, dirs: list[Any], warnings: list[str] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Button state on the ego samples (state of the last message), each press on >= 1 sample.

    `stimes`, `states`, `dirs`: the button messages in time order (ns, as `ego_times`); returns
    (lc_button, lc_direction). A press after the last ego sample is on none: `warnings` says so.
    """
    n = len(ego_times)
    pressed = np.zeros(n, dtype=bool)
    direction = np.full(n, None, dtype=object)
    if not len(stimes):
        return pressed, direction
    idx = asof(ego_times, stimes)
    pressed[idx >= 0] = states[idx[idx >= 0]]
    prev = np.concatenate([[False], states[:-1]])
    late = []
    for k in np.flatnonzero(states & ~prev):
        i = int(np.searchsorted(ego_times, stimes[k], side="left"))
        if i < n:
            pressed[i] = True
            if dirs[k] is not None:
                direction[i] = dirs[k]
        else:
            late.append(k)
    if late and warnings is not None:
        after = (float(stimes[late[0]]) - float(ego_times[-1])) / 1e9
        warnings.append(
            f"{len(late)} lane-change press(es) after the last ego sample (the first {after:.3g} s after "
            f"it): no sample to put them on, not kept"
        )
    return pressed, direction
