"""A synthetic driver-in-the-loop study: traffic scenes and a driver behaviour model.

Public API: `StudySettings`, `simulate_study(settings, seed) -> Study`,
`write_study(study, out, fmt)` (imported lazily: it pulls in the log writers).
"""

from laneprint.simulator.config import CASES, StudySettings
from laneprint.simulator.study import Study, simulate_study


def write_study(*args, **kwargs):  # noqa: ANN002, ANN003 - thin lazy wrapper
    """See `laneprint.simulator.output.write_study`."""
    from laneprint.simulator.output import write_study as _write

    return _write(*args, **kwargs)


__all__ = ["CASES", "Study", "StudySettings", "simulate_study", "write_study"]
