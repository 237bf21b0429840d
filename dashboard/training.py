"""What the Training form offers: targets, rewards and the trainer's defaults (Table 2).

The defaults are read from the RL stage's settings dataclass when it is installed;
until then the study's Table 2 values below are shown.
"""

from __future__ import annotations

from typing import Any

import numpy as np
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


def episode_length(ws, req, tables: dict[str, pd.DataFrame] | None = None) -> tuple[float | None, str]:
    """Transitions per episode to expect for `req`, and where the figure comes from: the mean episode
    length of this workspace's earlier runs of the same target (early episodes included), else the
    states per recorded approach of the target's drivers (an upper bound: exploring agents change
    lane, and end their episode, early). `tables`: the analysis tables when the caller has them
    (the page's cached loader), else they are read."""
    import json

    import numpy as np

    from rl.runs import read_metrics

    lengths = []
    for cfg_path in sorted(ws.runs_dir.glob("*/config.json"))[-20:]:
        try:
            cfg = json.loads(cfg_path.read_text())
        except (OSError, ValueError):
            continue
        if cfg.get("target") != {"kind": req.target, "name": req.name}:
            continue
        m = read_metrics(cfg_path.parent / "metrics.jsonl")
        if len(m) and "length" in m:
            lengths.append(float(m["length"].head(2000).mean()))
    if lengths:
        return float(np.median(lengths)), f"the mean episode length of {len(lengths)} earlier run(s) of this target"
    if tables is None:
        tables = {name: ws.read_table("analysis", name) for name in ("decisions", "styles")
                  if ws.has_table("analysis", name)}
    dec = tables.get("decisions")
    if dec is None:
        return None, ""
    drivers = [req.name]
    styles = tables.get("styles")
    if req.target == "style" and styles is not None:
        drivers = styles.loc[styles["style"].astype(str) == req.name, "driver_id"].astype(str).tolist()
    d = dec[dec["driver_id"].astype(str).isin(drivers)]
    presses = int((d["label"] == "change").sum())
    if not presses:
        return None, ""
    return len(d) / presses, "the recorded states per approach of the target's drivers (an upper bound)"


def learning_check(ws, req, values: dict[str, Any] | None = None,
                   tables: dict[str, pd.DataFrame] | None = None) -> tuple[str, str]:
    """('refuse' | 'warn' | '', why) for a training request: refused when its episodes are too few for
    learning to begin at the current settings (the replay memory must hold `learning_starts`
    transitions before the first update), warned when learning would begin only in the last fifth."""
    from rl.settings import DQNSettings

    values = values or {}
    starts = int(values.get("learning_starts") or DQNSettings().learning_starts)
    per_episode, source = episode_length(ws, req, tables)
    if not per_episode:
        return "", ""
    expected = per_episode * int(req.episodes)
    needed = int(np.ceil(starts / per_episode)) if per_episode else 0
    if expected < starts:
        return "refuse", (f"{req.episodes:,} episodes make about {expected:,.0f} transitions (about {per_episode:.1f} "
                          f"per episode, from {source}), but learning starts after {starts:,}: the agent would "
                          f"learn nothing. Use at least about {needed:,} episodes, or lower 'learning starts'.")
    if expected < 1.25 * starts:
        return "warn", (f"Learning would begin only near the end: about {expected:,.0f} transitions in "
                        f"{req.episodes:,} episodes against {starts:,} before the first update (about "
                        f"{per_episode:.1f} per episode, from {source}).")
    return "", ""
