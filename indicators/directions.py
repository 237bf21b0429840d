"""Decisions by direction: overtaking (target lane to the left) and returning (to the right).

Drivers read a gap differently when they pull out to overtake and when they return
behind the car they passed (on SUMO studies the median lag gap at a return is a
sixth of that at an overtake). Lines and correlations are fitted per direction for
every driver whose presses on that side are enough for a fit; where they are not,
the reason says so and the pooled line (both directions) stands.

Lanes count from the right (lane 0 is the rightmost), so a target lane above the
ego's is to the left.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from indicators.settings import AnalysisSettings
from indicators.stats import correlate, fit_lines, indicator_points

DIRECTIONS: tuple[str, ...] = ("left", "right")
POOLED = "both"  # the direction of a line fitted on every press


def directions(decisions: pd.DataFrame) -> np.ndarray:
    """'left' or 'right' for every row: the side of its target lane."""
    return np.where(decisions["target_lane"].to_numpy() > decisions["ego_lane"].to_numpy(), "left", "right")


def press_counts(decisions: pd.DataFrame) -> dict[str, int]:
    """Presses to each side."""
    side = directions(decisions[decisions["label"] == "change"])
    return {d: int((side == d).sum()) for d in DIRECTIONS}


def fits_by_direction(
    decisions: pd.DataFrame, settings: AnalysisSettings, drivers: list[str], indicators: tuple[str, ...]
) -> pd.DataFrame:
    """`fit_lines` rows (plus pearson_r, pearson_p, significant) per driver, indicator and direction.

    A side with too few presses for a fit keeps its row, status 'skipped', and a reason
    that ends in "the pooled line stands".
    """
    side = directions(decisions)
    parts = []
    for d in DIRECTIONS:
        sub = decisions[side == d]
        points = indicator_points(sub, settings)
        fits = fit_lines(sub, settings, points, drivers, indicators)
        corr = correlate(sub, settings, points, drivers, indicators)
        fits = fits.merge(
            corr[["driver_id", "indicator", "pearson_r", "pearson_p", "significant"]],
            on=["driver_id", "indicator"],
            how="left",
        )
        skipped = fits["status"] != "ok"
        fits.loc[skipped, "reason"] = fits.loc[skipped, "reason"].astype(str) + f" to the {d}: the pooled line stands"
        fits.insert(2, "direction", d)
        parts.append(fits)
    return pd.concat(parts, ignore_index=True)
