"""Write a SUMO study to a folder: the logs (via `ingest.writers`), ground_truth.json, README.md.

Same conventions as the synthetic study (`laneprint.app.simulator.output`): file names
are session ids, `mixed` writes odd drivers as MCAP and even ones as .csv.gz,
everything goes into a temporary sibling folder and is moved into place at the
end, and a folder is only written into when it is empty, holds a previous study,
or `force` is given.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

from laneprint.progress import ProgressFn
from laneprint.app.simulator.output import write_study_files  # one set of file conventions for both engines
from laneprint.simulator.sumo.readme import render_readme
from laneprint.simulator.sumo.study import SumoStudy


def write_sumo_study(
    study: SumoStudy, out: Path, fmt: str = "mixed", force: bool = False, progress: Optional[ProgressFn] = None
) -> dict[str, Any]:
    """Write `study` into `out`; returns a JSON-ready summary."""
    files, total, log_bytes = write_study_files(study, out, fmt, render_readme, force, progress=progress)
    return summary(study, out, fmt, len(files) + 2, total, log_bytes)


def summary(study: SumoStudy, out: Path, fmt: str, n_files: int, total_bytes: int, log_bytes: int) -> dict[str, Any]:
    """The JSON result of `laneprint simulate --engine sumo`."""
    gt = study.ground_truth
    per_driver = {d["driver_id"]: 0 for d in gt["drivers"]}
    directions = {"left": 0, "right": 0}
    by_lane: dict[str, int] = {}
    for dec in study.decisions:
        per_driver[dec["driver_id"]] += 1
        directions[dec["direction"]] += 1
        key = f"{dec['from_lane']}>{dec['target_lane']}"
        by_lane[key] = by_lane.get(key, 0) + 1
    return {
        "out": str(Path(out).resolve()),
        "engine": gt["engine"],
        "family": gt["family"],
        "lanes": gt["n_lanes"],
        "sumo_version": gt["sumo_version"],
        "seed": study.seed,
        "format": fmt,
        "minutes": study.settings.minutes,
        "drivers": len(gt["drivers"]),
        "styles": {d["driver_id"]: d["style"] for d in gt["drivers"]},
        "recordings": len(study.recordings),
        "decisions": len(study.decisions),
        "decisions_per_driver": per_driver,
        "directions": directions,
        "changes_by_lane": dict(sorted(by_lane.items())),
        "collisions": sum(s["n_collisions"] for s in gt["sessions"]),
        "files": n_files,
        "bytes": total_bytes,
        "log_bytes": log_bytes,
    }
