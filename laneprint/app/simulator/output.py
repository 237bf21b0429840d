"""Write a generated study to a folder: the logs (via `ingest.writers`), ground_truth.json, README.md.

The edge of the simulator: the only module of it that touches files. Everything is
written into a temporary sibling folder first and moved into place at the end, so a
failed run leaves nothing half written. A folder that already holds files is only
written into when it holds a previous study (its `ground_truth.json` says so) or
when `force` is given; files of the previous study that the new one does not
write are removed, any other file is left alone.
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from pathlib import Path
from typing import Any, Callable, Optional

from ingest.writers import write_csv, write_mcap
from laneprint.errors import UserError
from laneprint.progress import ProgressFn, report
from laneprint.simulator.readme import render_readme
from laneprint.simulator.study import GENERATOR, Study

FORMATS: tuple[str, ...] = ("mixed", "csv", "mcap", "both")
GROUND_TRUTH = "ground_truth.json"
README = "README.md"


def planned_files(study: Study, fmt: str, gzip_csv: bool = True) -> list[tuple[str, int, str]]:
    """(relative path, recording index, format) of every log file `fmt` asks for.

    `mixed` writes odd-numbered drivers (D01, D03, ...) as MCAP and the others as CSV,
    so no session appears twice; `both` writes every recording into `csv/` and `mcap/`.
    """
    if fmt not in FORMATS:
        raise UserError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    csv_ext = ".csv.gz" if gzip_csv else ".csv"
    drivers = [d["driver_id"] for d in study.ground_truth["drivers"]]
    out = []
    for i, (meta, _, _) in enumerate(study.recordings):
        sid = meta["session_id"]
        if fmt == "both":
            out.append((f"csv/{sid}{csv_ext}", i, "csv"))
            out.append((f"mcap/{sid}.mcap", i, "mcap"))
        elif fmt == "csv" or (fmt == "mixed" and (drivers.index(meta["driver_id"]) + 1) % 2 == 0):
            out.append((f"{sid}{csv_ext}", i, "csv"))
        else:
            out.append((f"{sid}.mcap", i, "mcap"))
    return out


def read_ground_truth(folder: Path) -> dict[str, Any]:
    """The `ground_truth.json` of a study folder (raises `UserError` when there is none)."""
    path = Path(folder) / GROUND_TRUTH
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise UserError(f"{path} not found: is {folder} a folder written by laneprint simulate?") from None
    except (OSError, ValueError) as exc:
        raise UserError(f"{path} is not readable JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("generator") != GENERATOR:
        raise UserError(f"{path} was not written by laneprint simulate")
    return data


def previous_study_files(folder: Path) -> Optional[list[str]]:
    """Relative paths written by a previous study in `folder`, or None when it holds none."""
    gt = folder / GROUND_TRUTH
    if not gt.is_file():
        return None
    try:
        data = json.loads(gt.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("generator") != GENERATOR:
        return None
    return [f["path"] for f in data.get("files", []) if isinstance(f, dict) and "path" in f] + [GROUND_TRUTH, README]


def check_destination(out: Path, force: bool = False) -> Optional[list[str]]:
    """Raise `UserError` when a study may not be written into `out`; returns the previous study's files."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out} exists and is not a folder")
    existing = out.is_dir() and any(out.iterdir())
    old_files = previous_study_files(out) if existing else None
    if existing and old_files is None and not force:
        raise UserError(f"{out} is not empty and holds no previous study; use --force to write into it")
    return old_files


def write_recordings(
    recordings: list, plan: list[tuple[str, int, str]], folder: Path, progress: Optional[ProgressFn] = None
) -> list[dict[str, Any]]:
    """Write each planned (relative path, recording index, kind) into `folder`; one dict per file written."""
    files = []
    for k, (rel, i, kind) in enumerate(plan):
        meta, ego, traffic = recordings[i]
        report(progress, k, len(plan), f"writing {rel}")
        path = folder / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        (write_mcap if kind == "mcap" else write_csv)(path, meta, ego, traffic)
        files.append(
            {
                "path": rel,
                "session_id": meta["session_id"],
                "driver_id": meta["driver_id"],
                "format": kind if kind == "mcap" else ("csv.gz" if rel.endswith(".gz") else "csv"),
                "bytes": path.stat().st_size,
            }
        )
    report(progress, len(plan), len(plan), "written")
    return files


def write_study_files(
    study: Any,
    out: Path,
    fmt: str,
    readme: Callable[[Any, str, list], str],
    force: bool = False,
    gzip_csv: bool = True,
    progress: Optional[ProgressFn] = None,
) -> tuple[list[dict[str, Any]], int, int]:
    """Write a study's logs, ground truth and README into `out`, all or nothing.

    `study` needs ``recordings`` and ``ground_truth``; `readme(study, fmt, files)`
    renders its README. Returns (files, total bytes, log bytes).
    """
    out = Path(out)
    plan = planned_files(study, fmt, gzip_csv)
    old_files = check_destination(out, force)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    try:
        files = write_recordings(study.recordings, plan, tmp, progress)
        log_bytes = sum(f["bytes"] for f in files)
        gt = dict(study.ground_truth, format=fmt, files=files)
        (tmp / GROUND_TRUTH).write_text(json.dumps(gt, indent=1, default=_json_default) + "\n")
        (tmp / README).write_text(readme(study, fmt, files))
        total_bytes = log_bytes + (tmp / GROUND_TRUTH).stat().st_size + (tmp / README).stat().st_size
        _move_into_place(tmp, out, [f["path"] for f in files] + [GROUND_TRUTH, README], old_files or [])
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return files, total_bytes, log_bytes


def write_study(
    study: Study,
    out: Path,
    fmt: str = "mixed",
    force: bool = False,
    gzip_csv: bool = True,
    progress: Optional[ProgressFn] = None,
) -> dict[str, Any]:
    """Write `study` into `out`; returns a JSON-ready summary (files, bytes)."""
    out = Path(out)
    files, total_bytes, data_bytes = write_study_files(study, out, fmt, render_readme, force, gzip_csv, progress)
    cases: dict[str, int] = {}
    for d in study.decisions:
        cases[d["case"]] = cases.get(d["case"], 0) + 1
    return {
        "out": str(out.resolve()),
        "seed": study.seed,
        "format": fmt,
        "drivers": len(study.ground_truth["drivers"]),
        "recordings": len(study.recordings),
        "decisions": len(study.decisions),
        "cases": cases,
        "files": len(files) + 2,
        "bytes": total_bytes,
        "log_bytes": data_bytes,
    }


def _move_into_place(tmp: Path, out: Path, new_files: list[str], old_files: list[str]) -> None:
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        if out.exists():
            out.rmdir()
        os.rename(tmp, out)
        return
    for rel in set(old_files) - set(new_files):
        (out / rel).unlink(missing_ok=True)
    for rel in new_files:
        dest = out / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp / rel, dest)
    for sub in {Path(r).parent for r in old_files} - {Path(".")}:
        if (out / sub).is_dir() and not any((out / sub).iterdir()):
            (out / sub).rmdir()
    shutil.rmtree(tmp, ignore_errors=True)


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "item"):
        return obj.item()
    if isinstance(obj, tuple):
        return list(obj)
    return str(obj)
