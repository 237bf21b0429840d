"""The decision problem: scenes, reference lines and rewards, the gymnasium environment, its observation."""

from rl.problem.env import (
    Approach,
    EnvConfig,
    LaneChangeDecisionEnv,
    VecLaneChangeEnv,
    approaches_from_decisions,
    default_config,
    formulation_config,
)
from rl.problem.observation import observation_spec
from rl.problem.rewards import ReferenceLines, RewardSettings
from rl.problem.scene import Scene

__all__ = [
    "Approach",
    "EnvConfig",
    "LaneChangeDecisionEnv",
    "ReferenceLines",
    "RewardSettings",
    "Scene",
    "VecLaneChangeEnv",
    "approaches_from_decisions",
    "default_config",
    "formulation_config",
    "observation_spec",
]
