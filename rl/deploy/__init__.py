"""A trained policy leaves the workspace: as ONNX (`export`) or as decisions written into a log (`annotate`)."""

from laneprint.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "export_run": "rl.deploy.export",
        "annotate_recording": "rl.deploy.annotate",
    },
)
