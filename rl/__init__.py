"""RL: the lane-change decision environment, DQN trainer, greedy benchmark, evaluation."""
