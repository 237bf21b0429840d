"""The free speed: how fast a driver goes when nothing holds it back.

Read by steady following (`indicators.following`: a driver is held back when slower than a share of
it) and carried by every decision state (`indicators.decisions`, column `ego_v_free_mps`), whence the
behaviour parameter `v_free` (`clustering.behaviour`).
"""

from __future__ import annotations

import numpy as np

#: The quantile of the ego's speed over a recording taken as its free speed there.
FREE_SPEED_QUANTILE = 0.9


def free_speed(v: np.ndarray) -> float:
    """The `FREE_SPEED_QUANTILE` quantile of a driver's speeds over a recording [m/s] (NaN with no speed)."""
    v = np.asarray(v, dtype=float)
    return float(np.nanquantile(v, FREE_SPEED_QUANTILE)) if np.isfinite(v).any() else np.nan
