"""Policies the agents are measured against: the study's greedy benchmark, an imitation classifier."""

from laneprint.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "greedy_actions": "rl.baselines.greedy",
        "ImitationClassifier": "rl.baselines.imitation",
        "fitted_classifier": "rl.baselines.imitation",
    },
)
