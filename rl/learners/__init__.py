"""The learners: DQN in torch (one training loop for one agent or many, their weights stacked) and boosted trees."""

from laneprint.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "DQNTrainer": "rl.learners.dqn",
        "q_network": "rl.learners.dqn",
        "q_values": "rl.learners.dqn",
        "DQNLoop": "rl.learners.dqn",
        "StackedAdam": "rl.learners.batched",
    },
)
