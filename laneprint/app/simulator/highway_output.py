"""Write a highway-env study to a folder: the logs (via `ingest.writers`), ground_truth.json, README.md.

The same file conventions as the other engines (`laneprint.app.simulator.output.write_study_files`):
file names are session ids, everything is written into a temporary sibling folder
and moved into place at the end, and a folder is only written into when it is
empty, holds a previous study, or `force` is given.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

from laneprint.progress import ProgressFn
from laneprint.simulator.highway.readme import render_readme
from laneprint.simulator.highway.study import HighwayStudy
from laneprint.app.simulator.output import write_study_files


def write_highway_study(
    study: HighwayStudy, out: Path, fmt: str = "csv", force: bool = False, progress: Optional[ProgressFn] = None
) -> dict[str, Any]:
    """Write `study` into `out`; returns a JSON-ready summary."""
    files, total, log_bytes = write_study_files(study, out, fmt, render_readme, force, progress=progress)
    return summary(study, out, fmt, len(files) + 2, total, log_bytes)


def summary(study: HighwayStudy, out: Path, fmt: str, n_files: int, total_bytes: int, log_bytes: int) -> dict[str, Any]:
    """The JSON result of `laneprint simulate --engine highway`."""
    gt = study.ground_truth
    per_driver = {d["driver_id"]: 0 for d in gt["drivers"]}
    directions = {"left": 0, "right": 0}
    by_lane: dict[str, int] = {}
    for dec in study.presses:
        per_driver[dec["driver_id"]] += 1
        directions[dec["direction"]] += 1
        key = f"{dec['from_lane']}>{dec['target_lane']}"
        by_lane[key] = by_lane.get(key, 0) + 1
    return {
        "out": str(Path(out).resolve()),
        "engine": gt["engine"],
        "lanes": gt["n_lanes"],
        "highway_env_version": gt["highway_env_version"],
        "seed": study.seed,
        "format": fmt,
        "minutes": study.settings.minutes,
        "drivers": len(gt["drivers"]),
        "styles": {d["driver_id"]: d["style"] for d in gt["drivers"]},
        "recordings": len(study.recordings),
        "presses": len(study.presses),
        "presses_per_driver": per_driver,
        "directions": directions,
        "presses_by_lane": dict(sorted(by_lane.items())),
        "aborted": sum(d["aborted"] for d in study.presses),
        "missed": sum(d["missed"] for d in study.decisions),
        "lane_changes": sum(d["changed"] for d in study.decisions),
        "collisions": sum(s["n_collisions"] for s in gt["sessions"]),
        "traffic_collisions": sum(s["n_traffic_collisions"] for s in gt["sessions"]),
        "true_parameter_ari": gt["true_parameter_ari"],
        "files": n_files,
        "bytes": total_bytes,
        "log_bytes": log_bytes,
    }
