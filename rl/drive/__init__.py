"""Closed loop: a trained agent makes the ego's lane changes in SUMO traffic (`laneprint drive`)."""

from laneprint.lazy import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "drive_sections": "rl.drive.loop",
        "drive_run": "rl.drive.store",
    },
)
