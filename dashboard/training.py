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
    lr = (
        f"the learning rate falls linearly from {d.learning_rate:g} to {d.learning_rate_end:g} over the run"
        if d.learning_rate_end is not None
        else f"constant learning rate {d.learning_rate:g}"
    )
    updates = "one minibatch" if d.gradient_steps == 1 else f"{d.gradient_steps} minibatches"
    policy = (
        f"; from {d.average_from:.0%} of the episodes on, the policy is an average of the weights"
        if d.average_tau > 0
        else ""
    )
    return (
        f"Table 2 of the study, stepped as {d.num_envs} environments at once with {updates} of "
        f"{d.batch_size} per step (1 environment and minibatch 32 is the study's own loop); {lr}{policy}."
    )


def rewards() -> list[str]:
    """Reward formulations the trainer knows, its default first."""
    from rl.problem.rewards import REWARDS
    from rl.settings import DEFAULT_REWARD

    default = DEFAULT_REWARD
    return [default, *[r for r in REWARDS if r != default]]


def learners(reward: str, lines: str) -> list[str]:
    """The learners `laneprint train --learner` offers for `reward` and `lines`, the default first (the trees,
    alone or in 'auto', fit only the decisions reward on recorded scenes)."""
    from rl.settings import LEARNERS, default_learner, resolve_formulation

    name, scenes, _ = resolve_formulation(reward, None, None, lines)
    default = default_learner(name, scenes)
    return [default, *[x for x in LEARNERS if x != default]] if default != "dqn" else ["dqn"]


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


def learning_check(
    ws, req, values: dict[str, Any] | None = None, tables: dict[str, pd.DataFrame] | None = None
) -> tuple[str, str]:
    """('refuse' | 'warn' | '', why) for a training request, as `laneprint train` checks it before a run
    (`rl.settings.learning_check`): refused when its episodes are too few for learning to begin at the
    form's settings (the replay memory must hold `learning_starts` transitions before the first update),
    warned when learning would begin only near the end. `values`: the form's trainer settings;
    `tables`: `styles` and `decision_counts` (`loaders.training_inputs`) or `decisions` when the caller
    has them, else they are read."""
    from rl.problem.env import EnvConfig, formulation_config
    from rl.settings import DQNSettings, approach_steps, decision_counts, target_counts
    from rl.settings import learning_check as check_settings

    if tables is None:
        tables = {
            name: ws.read_table("analysis", name) for name in ("decisions", "styles") if ws.has_table("analysis", name)
        }
    counts = tables.get("decision_counts")
    if counts is None and tables.get("decisions") is not None:
        counts = decision_counts(tables["decisions"])
    states, presses = target_counts(counts, tables.get("styles"), req.target, req.name)
    env = formulation_config(EnvConfig().lines, req.reward, None, None, req.lines or "analysis")
    steps, source = approach_steps(env, states, presses)
    try:
        settings = DQNSettings(
            episodes=int(req.episodes),
            episodes_per_approach=0.0,
            **{k: v for k, v in (values or {}).items() if k in FORM_SETTINGS},
        )
    except (TypeError, ValueError):
        return "", ""
    check = check_settings(
        settings, steps, source, episodes_name="the Episodes field", starts_name="'learning starts' (Hyperparameters)"
    )
    return {"never": "refuse", "late": "warn"}.get(check.verdict, ""), check.message[:1].upper() + check.message[1:]
