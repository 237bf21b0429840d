"""Evaluation against the drivers' decisions: in-sample, and held out by session (cross-validation)."""

from laneprint.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "evaluate_policies": "rl.evaluation.evaluate",
        "CrossvalSettings": "rl.evaluation.crossval",
        "crossvalidate": "rl.evaluation.crossval",
        "run_crossval": "rl.evaluation.crossval_store",
        "list_crossvals": "rl.evaluation.crossval_store",
        "load_crossval": "rl.evaluation.crossval_store",
    },
)
