"""A synthetic driver-in-the-loop study: traffic scenes and a driver behaviour model.

Public API: `StudySettings`, `simulate_study(settings, seed) -> Study`,
`decisions_frame(ground_truth)` (the decisions as a table). Writing a study as log files
(`write_study`, `read_ground_truth`) needs ingest's log writers, so it lives above the
stages, in `laneprint.app.simulator`.
"""

from laneprint.simulator.config import CASES, StudySettings
from laneprint.simulator.study import Study, decisions_frame, simulate_study


__all__ = ["CASES", "Study", "StudySettings", "decisions_frame", "simulate_study"]
