"""What the Training form offers: targets, rewards and the trainer's defaults (Table 2).

The defaults are read from the RL stage's settings dataclass when it is installed;
until then the study's Table 2 values below are shown.
"""

from __future__ import annotations

from typing import Any

import pandas as pd

from dashboard.context import EPISODES_ENV, env_int
from laneprint.reference import STYLES

#: Trainer settings the form offers -> (label, `laneprint train` option); defaults from rl.settings.DQNSettings.
FORM_SETTINGS: dict[str, tuple[str, str]] = {
    "learning_rate": ("learning rate", "--lr"),
    "gamma": ("discount gamma", "--gamma"),
    "eps_start": ("epsilon start", "--eps-start"),
    "eps_end": ("epsilon end", "--eps-end"),
    "buffer_size": ("replay memory [transitions]", "--buffer-size"),
    "learning_starts": ("learning starts [transitions]", "--learning-starts"),
    "batch_size": ("minibatch [transitions]", "--batch-size"),
    "target_update_episodes": ("target copy every [episodes]", "--target-update"),
    "num_envs": ("environments stepped together", "--num-envs"),
    "gradient_steps": ("updates per vector step", "--gradient-steps"),
}


def defaults_note() -> str:
    """How the trainer's defaults relate to the study's Table 2."""
    from rl.settings import DQNSettings

    d = DQNSettings()
    lr = (f"the learning rate falls linearly from {d.learning_rate:g} to {d.learning_rate_end:g} over the run"
          if d.learning_rate_end is not None else f"constant learning rate {d.learning_rate:g}")
    updates = "one minibatch" if d.gradient_steps == 1 else f"{d.gradient_steps} minibatches"
    policy = (f"; from {d.average_from:.0%} of the episodes on, the policy is an average of the weights"
              if d.average_tau > 0 else "")
    return (f"Table 2 of the study, stepped as {d.num_envs} environments at once with {updates} of "
            f"{d.batch_size} per step (1 environment and minibatch 32 is the study's own loop); {lr}{policy}.")


def rewards() -> list[str]:
    """Reward formulations the trainer knows, its default first."""
    from rl.problem.rewards import REWARDS
    from rl.settings import DEFAULT_REWARD

    default = DEFAULT_REWARD
    return [default, *[r for r in REWARDS if r != default]]


def hyperparameters() -> dict[str, Any]:
    """The form's trainer settings with their defaults (the study's Table 2)."""
    from rl.settings import DQNSettings

    defaults = DQNSettings()
    return {name: getattr(defaults, name) for name in FORM_SETTINGS}


def changed_options(values: dict[str, Any]) -> dict[str, str]:
    """`laneprint train` options for the settings that differ from their defaults."""
    defaults = hyperparameters()
    return {FORM_SETTINGS[k][1]: str(v) for k, v in values.items() if k in defaults and v != defaults[k]}


def default_episodes() -> int:
    """Episodes pre-filled in the form: $LANEPRINT_DASHBOARD_EPISODES, else the trainer's default."""
    from rl.settings import DQNSettings

    return env_int(EPISODES_ENV, None) or DQNSettings().episodes


def check_target(ws, req) -> str:
    """Why the trainer would refuse this target and these lines at once ('' when it would not)."""
    from laneprint.errors import UserError
    from rl.runs import Target, resolve_lines

    try:
        resolve_lines(ws, Target(req.target, req.name), req.lines or "analysis")
    except (UserError, ValueError, KeyError) as exc:
        return str(exc)
    return ""


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
