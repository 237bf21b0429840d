"""A synthetic driver-in-the-loop study: traffic scenes and a driver behaviour model.

Public API: `StudySettings`, `simulate_study(settings, seed) -> Study`,
`write_study(study, out, fmt)` and `read_ground_truth(folder)` (imported lazily: they
pull in the log writers), `decisions_frame(ground_truth)` (the decisions as a table).
"""

from laneprint.simulator.config import CASES, StudySettings
from laneprint.simulator.study import Study, decisions_frame, simulate_study


def write_study(*args, **kwargs):  # noqa: ANN002, ANN003 - thin lazy wrapper
    """See `laneprint.simulator.output.write_study`."""
    from laneprint.simulator.output import write_study as _write

    return _write(*args, **kwargs)


def read_ground_truth(folder):  # noqa: ANN001, ANN201 - thin lazy wrapper
    """See `laneprint.simulator.output.read_ground_truth`."""
    from laneprint.simulator.output import read_ground_truth as _read

    return _read(folder)


__all__ = ["CASES", "Study", "StudySettings", "decisions_frame", "read_ground_truth", "simulate_study",
           "write_study"]
