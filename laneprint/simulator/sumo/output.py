"""Write a SUMO study to a folder: the logs (via `ingest.writers`), ground_truth.json, README.md.

Same conventions as the synthetic study (`laneprint.simulator.output`): file names
are session ids, `mixed` writes odd drivers as MCAP and even ones as .csv.gz,
everything goes into a temporary sibling folder and is moved into place at the
end, and a folder is only written into when it is empty, holds a previous study,
or `force` is given.
"""

from __future__ import annotations

import json
import shutil
import uuid
from pathlib import Path
from typing import Any, Optional

from laneprint.progress import ProgressFn
from laneprint.simulator.output import (  # the synthetic study's helpers: one set of file conventions
    GROUND_TRUTH,
    README,
    _json_default,
    _move_into_place,
    check_destination,
    planned_files,
    write_recordings,
)
from laneprint.simulator.sumo.readme import render_readme
from laneprint.simulator.sumo.study import SumoStudy


def write_sumo_study(study: SumoStudy, out: Path, fmt: str = "mixed", force: bool = False,
                     progress: Optional[ProgressFn] = None) -> dict[str, Any]:
    """Write `study` into `out`; returns a JSON-ready summary."""
    out = Path(out)
    plan = planned_files(study, fmt)  # type: ignore[arg-type]  # needs .recordings and .ground_truth only
    old_files = check_destination(out, force)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    try:
        files = write_recordings(study.recordings, plan, tmp, progress)
        gt = dict(study.ground_truth, format=fmt, files=files)
        (tmp / GROUND_TRUTH).write_text(json.dumps(gt, indent=1, default=_json_default) + "\n")
        (tmp / README).write_text(render_readme(study, fmt, files))
        log_bytes = sum(f["bytes"] for f in files)
        total = log_bytes + (tmp / GROUND_TRUTH).stat().st_size + (tmp / README).stat().st_size
        _move_into_place(tmp, out, [f["path"] for f in files] + [GROUND_TRUTH, README], old_files or [])
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return summary(study, out, fmt, len(files) + 2, total, log_bytes)


def summary(study: SumoStudy, out: Path, fmt: str, n_files: int, total_bytes: int, log_bytes: int) -> dict[str, Any]:
    """The JSON result of `laneprint simulate --engine sumo`."""
    gt = study.ground_truth
    per_driver = {d["driver_id"]: 0 for d in gt["drivers"]}
    directions = {"left": 0, "right": 0}
    for dec in study.decisions:
        per_driver[dec["driver_id"]] += 1
        directions[dec["direction"]] += 1
    return {
        "out": str(Path(out).resolve()),
        "engine": gt["engine"],
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
        "collisions": sum(s["n_collisions"] for s in gt["sessions"]),
        "files": n_files,
        "bytes": total_bytes,
        "log_bytes": log_bytes,
    }
