"""The study's greedy benchmark (section 5.2).

At every step it compares the immediate rewards of TO CHANGE and NOT TO CHANGE
under the study's reward (`paper`, eqs. 10-13) and takes the larger; with the
constant-sum reward that is "change when the summed closeness exceeds 1.5".
"""

from __future__ import annotations

import numpy as np

from rl.problem.rewards import CHANGE, KEEP, ReferenceLines, RewardSettings, action_rewards
from rl.problem.scene import Indicators


def greedy_actions(
    ind: Indicators, lines: ReferenceLines, settings: RewardSettings | None = None, dt: float = 0.1
) -> np.ndarray:
    """Greedy action per scene: 0 (change) where its immediate reward is larger, else 1 (keep).

    `settings` defaults to the paper's reward (the study's benchmark); ties keep.
    """
    settings = settings or RewardSettings(name="paper")
    r_change, r_keep = action_rewards(ind, lines, settings, dt)
    return np.where(r_change > r_keep, CHANGE, KEEP)
