"""What the Training form offers: targets, rewards and the trainer's defaults (Table 2).

The defaults are read from the RL stage's settings dataclass when it is installed;
until then the study's Table 2 values below are shown.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import pandas as pd

from dashboard.context import EPISODES_ENV, env_int
from laneprint.reference import STYLES

#: Table 2 of the study (PAPER_NOTES.md), the fallback when rl/ has no settings class yet.
TABLE2: dict[str, Any] = {
    "learning_rate": 0.005, "epsilon_start": 0.8, "epsilon_end": 0.1, "gamma": 0.98,
    "replay_size": 10000, "learning_starts": 2000, "batch_size": 32, "target_update_episodes": 20,
    "max_steps": 200, "episodes": 10000,
}


def rewards() -> list[str]:
    """Reward formulations the trainer knows (its default first)."""
    try:
        from rl.rewards import REWARDS, RewardSettings
        default = RewardSettings().name
        return [default, *[r for r in REWARDS if r != default]]
    except (ImportError, AttributeError, TypeError):
        return ["paper"]


def hyperparameters() -> dict[str, Any]:
    """Trainer settings and their defaults (Table 2), flat name -> value."""
    try:
        from rl.dqn import DQNSettings  # type: ignore[import-not-found]
        return {f.name: getattr(DQNSettings(), f.name) for f in dataclasses.fields(DQNSettings)}
    except ImportError:
        return dict(TABLE2)


def default_episodes() -> int:
    """Episodes pre-filled in the form: $LANEPRINT_DASHBOARD_EPISODES, else the trainer's default."""
    return env_int(EPISODES_ENV, None) or int(hyperparameters().get("episodes", TABLE2["episodes"]))


def style_targets(reference_lines: pd.DataFrame | None) -> list[str]:
    """Styles with reference lines in the analysis, else the study's three."""
    if reference_lines is not None and "scope" in reference_lines:
        names = reference_lines.loc[reference_lines["scope"] == "style", "name"].astype(str).unique().tolist()
        if names:
            return names
    return list(STYLES)


def driver_targets(reference_lines: pd.DataFrame | None, recordings: pd.DataFrame) -> list[str]:
    """Drivers with their own reference lines, else every driver in the workspace."""
    if reference_lines is not None and "scope" in reference_lines:
        names = reference_lines.loc[reference_lines["scope"] == "driver", "name"].astype(str).unique().tolist()
        if names:
            return sorted(names)
    return sorted(recordings["driver_id"].astype(str).unique()) if len(recordings) else []
