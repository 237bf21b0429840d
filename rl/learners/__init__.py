"""The learners: DQN in torch (one agent) and its weights stacked for many agents at once."""

from laneprint.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, {
    "DQNTrainer": "rl.learners.dqn",
    "q_network": "rl.learners.dqn",
    "q_values": "rl.learners.dqn",
    "ReplayBuffer": "rl.learners.dqn",
    "StackedAdam": "rl.learners.batched",
})
