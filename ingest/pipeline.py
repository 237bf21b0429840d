"""Ingest a batch of log files into a workspace: find, read, validate, store, report.

`ingest_paths` never stops at a bad file: each file gets a `FileResult` with a
status and, when refused, a one-line reason; refused files are remembered in the
workspace (`Workspace.record_rejected`). Recordings are keyed by content hash, so
the same bytes are stored once. A session (driver_id, session_id) is stored once
too: the CSV and the MCAP of the same session are one recording, the second is a
'duplicate'. Concurrent ingests are safe: a session is claimed under a flock that
dies with its process before its recording is written (see `_claim_session`).
"""

from __future__ import annotations

import hashlib
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterator

import pandas as pd

from ingest.csv_reader import read_csv_log
from ingest.mapping import Mapping, load_mapping
from ingest.mcap_reader import read_mcap_log
from ingest.rawlog import RawLog, Rejected, first_line
from ingest.validate import canonicalise
from laneprint.errors import UserError
from laneprint.progress import ProgressFn, report
from laneprint.schemas import SchemaError
from laneprint.workspace import Workspace, atomic_write_bytes

LOG_SUFFIXES = (".csv.gz", ".csv", ".mcap")
STATUSES = ("ingested", "warning", "duplicate", "rejected", "skipped")


@dataclass
class FileResult:
    """What happened to one file of the batch."""

    source: str  # path as found
    status: str  # 'ingested' | 'warning' (ingested with warnings) | 'duplicate' | 'rejected' | 'skipped'
    format: str = ""
    recording_id: str = ""
    driver_id: str = ""
    session_id: str = ""
    n_samples: int = 0
    n_presses: int = 0
    reason: str = ""  # why rejected / duplicate / skipped
    warnings: list[str] = field(default_factory=list)


@dataclass
class IngestReport:
    """Per-file results of one ingest batch."""

    files: list[FileResult]
    workspace: str

    @property
    def counts(self) -> dict[str, int]:
        c = {s: 0 for s in STATUSES}
        for f in self.files:
            c[f.status] += 1
        return c

    @property
    def stored(self) -> list[FileResult]:
        return [f for f in self.files if f.status in ("ingested", "warning")]

    def to_dict(self) -> dict[str, Any]:
        return {"workspace": self.workspace, "counts": self.counts, "files": [asdict(f) for f in self.files]}


def log_format(path: Path) -> str | None:
    """'csv', 'csv.gz' or 'mcap' from the file name; None when it is not a log."""
    name = path.name.lower()
    if name.endswith(".csv.gz"):
        return "csv.gz"
    if name.endswith(".csv"):
        return "csv"
    if name.endswith(".mcap"):
        return "mcap"
    return None


def session_stem(path: Path) -> str:
    """The file name without its log suffix: the default session id."""
    name = path.name
    for suffix in LOG_SUFFIXES:
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return path.stem


def discover(paths: list[Path]) -> list[tuple[Path, str | None]]:
    """Files to look at: (path, None) to ingest, or (path, reason) for ones to skip/reject up front.

    Folders are walked recursively for .csv/.csv.gz/.mcap; their other files are
    skipped. An explicitly named path that is missing or not a log is rejected.
    """
    out: list[tuple[Path, str | None]] = []
    for p in paths:
        p = Path(p)
        if p.is_dir():
            for f in sorted(x for x in p.rglob("*") if x.is_file()):
                if any(part.startswith(".") for part in f.relative_to(p).parts):
                    continue
                out.append((f, None if log_format(f) else "skip: not a log file"))
        elif p.is_file():
            out.append((p, None if log_format(p) else
                        f"not a log file: expected a .csv, .csv.gz or .mcap name (got {p.name})"))
        else:
            out.append((p, "no such file or folder"))
    return out


def read_log(data: bytes, fmt: str, mapping: Mapping) -> RawLog:
    """Parse the bytes of one log; `Rejected` with a reason when they cannot be read."""
    if not data:
        raise Rejected("empty file (0 bytes)")
    if fmt == "mcap":
        return read_mcap_log(data, mapping)
    return read_csv_log(data, fmt, mapping)


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _session_key(driver_id: str, session_id: str) -> str:
    return hashlib.sha256(f"{driver_id}\0{session_id}".encode()).hexdigest()[:16]


def _claim_path(ws: Workspace, driver_id: str, session_id: str) -> Path:
    return ws.root / ".sessions" / _session_key(driver_id, session_id)


@contextmanager
def _claim_session(ws: Workspace, driver_id: str, session_id: str, rid: str) -> Iterator[str | None]:
    """Claim (driver, session) for recording `rid` while the block runs; yields the other
    recording id holding it, if any (then nothing is claimed).

    Under the session's flock (held for the block, released by the kernel if this
    process dies) a claim file `.sessions/<key>` names the recording being stored. A
    claim whose recording is not in the workspace is the leftover of an ingest that
    died or failed (no live process can be writing it: we hold the lock) and is taken over.
    """
    claim = _claim_path(ws, driver_id, session_id)
    with ws.lock(f"session-{claim.name}"):
        try:
            holder = claim.read_text().strip()
        except FileNotFoundError:
            holder = ""
        if holder and holder != rid and ws.has_recording(holder):
            yield holder
            return
        atomic_write_bytes(claim, rid.encode())
        try:
            yield None
        except BaseException:
            claim.unlink(missing_ok=True)
            raise
        if not ws.has_recording(rid):
            claim.unlink(missing_ok=True)


class _Batch:
    """State shared by the files of one batch: workspace, mapping, known sessions."""

    def __init__(self, ws: Workspace, mapping: Mapping, driver: str | None) -> None:
        self.ws = ws
        self.mapping = mapping
        self.driver = driver
        cat = ws.recordings()
        self.sessions: dict[tuple[str, str], tuple[str, str]] = {
            (str(r.driver_id), str(r.session_id)): (str(r.recording_id), str(r.source_name))
            for r in cat.itertuples()
        }

    def reject(self, path: Path, fmt: str, rid: str, reason: str) -> FileResult:
        self.ws.record_rejected({
            "content_hash": rid, "source_name": path.name, "source_path": str(path.resolve()),
            "format": fmt, "reason": reason, "rejected_at": _now(),
        })
        return FileResult(str(path), "rejected", fmt, recording_id=rid, reason=reason)

    def ingest_file(self, path: Path) -> FileResult:
        fmt = log_format(path) or ""
        try:
            data = path.read_bytes()
        except OSError as exc:
            return self.reject(path, fmt, "", f"cannot read the file: {exc.strerror or exc}")
        rid = hashlib.sha256(data).hexdigest()[:16]
        if self.ws.has_recording(rid):
            return FileResult(str(path), "duplicate", fmt, recording_id=rid,
                              reason=f"same bytes already ingested as recording {rid}")
        try:
            raw = read_log(data, fmt, self.mapping)
            rec = canonicalise(raw, self.mapping, session_stem(path), self.driver)
        except Rejected as exc:
            return self.reject(path, fmt, rid, str(exc))
        except (ValueError, TypeError, KeyError, IndexError, OverflowError, MemoryError) as exc:
            # a file shape no check anticipated: refuse it, keep the batch going
            return self.reject(path, fmt, rid, f"unexpected content ({type(exc).__name__}: {first_line(exc)}); "
                                               f"please report this file")
        driver_id, session_id = rec.meta["driver_id"], rec.meta["session_id"]
        result = FileResult(str(path), "warning" if rec.warnings else "ingested", fmt, rid, driver_id,
                            session_id, len(rec.ego), rec.n_presses, warnings=rec.warnings)
        earlier = self.sessions.get((driver_id, session_id))
        if earlier and earlier[0] != rid:
            result.status = "duplicate"
            result.reason = (f"driver {driver_id} session {session_id} is already in the workspace as recording "
                             f"{earlier[0]} ({earlier[1]})")
            return result
        with _claim_session(self.ws, driver_id, session_id, rid) as holder:
            if holder:
                result.status = "duplicate"
                result.reason = (f"driver {driver_id} session {session_id} is already in the workspace as "
                                 f"recording {holder}")
                return result
            return self._store(path, fmt, rid, rec, result)

    def _store(self, path: Path, fmt: str, rid: str, rec: Any, result: FileResult) -> FileResult:
        """Write the claimed recording; `result` updated (or a rejection when it does not fit)."""
        driver_id, session_id = result.driver_id, result.session_id
        meta = {
            "recording_id": rid, "driver_id": driver_id, "session_id": session_id,
            "speed_limit_kph": rec.meta["speed_limit_kph"], "simulator": rec.meta["simulator"],
            "source_name": path.name, "source_path": str(path.resolve()), "format": fmt,
            "n_samples": len(rec.ego), "duration_s": float(rec.ego["t_s"].iloc[-1] - rec.ego["t_s"].iloc[0]),
            "n_presses": rec.n_presses, "n_vehicles": rec.n_vehicles,
            "status": "warning" if rec.warnings else "ok", "warnings": "; ".join(rec.warnings),
            "ingested_at": _now(),
        }
        try:
            stored = self.ws.write_recording(meta, rec.ego, rec.traffic)
        except SchemaError as exc:
            return self.reject(path, fmt, rid, f"does not fit the recording tables: {exc}")
        if not stored:
            result.status = "duplicate"
            result.reason = f"same bytes already ingested as recording {rid} (by a concurrent ingest)"
            return result
        self.sessions[(driver_id, session_id)] = (rid, path.name)
        self.ws.forget_rejected(rid)
        return result


def check_paths(paths: list[Path]) -> list[Path]:
    """`UserError` when no path is given or none exists (nothing to process at all)."""
    paths = [Path(p) for p in paths]
    if not paths:
        raise UserError("no paths given: name log files or folders to ingest")
    if not any(p.exists() for p in paths):
        missing = ", ".join(str(p) for p in paths[:3]) + (" ..." if len(paths) > 3 else "")
        raise UserError(f"no such file or folder: {missing}")
    return paths


def ingest_paths(paths: list[Path], workspace: Workspace, driver_id: str | None = None,
                 mapping: Path | None = None, progress: ProgressFn | None = None) -> IngestReport:
    """Ingest every log under `paths` into `workspace`; a report with one result per file.

    Raises `UserError` only when nothing can be done at all (no path exists, a bad
    mapping file, a workspace that is a file).
    """
    paths = check_paths(paths)
    the_mapping = load_mapping(mapping)
    try:
        ws = workspace.ensure()
    except OSError as exc:
        raise UserError(f"cannot use workspace {workspace.root}: {exc.strerror or exc}") from None
    batch = _Batch(ws, the_mapping, driver_id.strip() if driver_id and driver_id.strip() else None)
    found = discover(paths)
    total = sum(1 for _, why in found if why is None)
    results: list[FileResult] = []
    done = 0
    report(progress, 0, total, "ingest")
    for path, why in found:
        if why is not None:
            if why.startswith("skip:"):
                results.append(FileResult(str(path), "skipped", reason=why[5:].strip()))
            elif path.exists():
                results.append(batch.reject(path, log_format(path) or path.suffix.lstrip("."), "", why))
            else:
                results.append(FileResult(str(path), "rejected", reason=why))
            continue
        results.append(batch.ingest_file(path))
        done += 1
        report(progress, done, total, path.name)
    return IngestReport(results, str(ws.root))


def catalogue_row(ws: Workspace, recording_id: str) -> pd.Series:
    """The RECORDINGS row of one recording (for tests and the dashboard)."""
    cat = ws.recordings()
    return cat[cat["recording_id"] == recording_id].iloc[0]
