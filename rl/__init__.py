"""RL: the lane-change decision environment, DQN trainer, greedy benchmark, evaluation.

Importing `rl` registers the environment as ``laneprint/LaneChangeDecision-v0``.
"""

from rl.problem.env import ENV_ID, register

register()

__all__ = ["ENV_ID"]
