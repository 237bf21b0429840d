"""Ingest a batch of log files into a workspace: find, read, validate, store, report.

`ingest_paths` never stops at a bad file: each file gets a `FileResult` with a
status and, when refused, a one-line reason; refused files are remembered in the
workspace (`Workspace.record_rejected`). Recordings are keyed by content hash, so
the same bytes are stored once. A session (driver_id, session_id) is stored once
too: the CSV and the MCAP of the same session are one recording, the second is a
'duplicate'. Concurrent ingests are safe: a session is claimed under a flock that
dies with its process before its recording is written (see `_claim_session`).

Reading and validating a file (`parse_log`: bytes in, canonical tables out) is
pure and runs on the chosen backend (`--backend ray`: on Ray's workers, which are
sent the file's bytes); everything that touches the workspace (dedup, session
claims, atomic writes, rejections) stays in this process (`_Batch.store`).
"""

from __future__ import annotations

import hashlib
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterator

import pandas as pd

from ingest.csv_reader import read_csv_log
from ingest.mapping import Mapping, load_mapping
from ingest.limits import IngestLimits, check_file_size
from ingest.mcap_reader import read_mcap_log
from ingest.rawlog import RawLog, Rejected, check_log_bytes, first_line
from ingest.rosbag2 import BagInfo, bag_parts, is_bag_folder, read_split_bag
from ingest.validate import Canonical, canonicalise, traffic_frame
from laneprint.errors import UserError
from laneprint.parallel import check_backend, iter_tasks
from laneprint.progress import ProgressFn, report
from laneprint.schemas import SchemaError
from laneprint.workspace import Workspace, atomic_write_bytes, content_id, encode_traffic

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
    notes: list[str] = field(default_factory=list)  # about the workspace (a damaged file left out)

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
        return {
            "workspace": self.workspace,
            "counts": self.counts,
            "files": [asdict(f) for f in self.files],
            "notes": self.notes,
        }


def log_format(path: Path) -> str | None:
    """'csv', 'csv.gz' or 'mcap' from the file name (a split rosbag2 folder is 'mcap'); None when it is not a log."""
    name = path.name.lower()
    if name.endswith(".csv.gz"):
        return "csv.gz"
    if name.endswith(".csv"):
        return "csv"
    if name.endswith(".mcap"):
        return "mcap"
    return "mcap" if is_bag_folder(path) else None


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
    skipped. A split rosbag2 folder (metadata.yaml + parts) is one log. An explicitly
    named path that is missing or not a log is rejected.
    """
    out: list[tuple[Path, str | None]] = []
    for p in paths:
        p = Path(p)
        if p.is_dir() and is_bag_folder(p):
            out.append((p, None))
        elif p.is_dir():
            bags = {m.parent for m in p.rglob("metadata.yaml") if is_bag_folder(m.parent)}
            bags_listed: set[Path] = set()
            inside = p.resolve()
            for f in sorted(x for x in p.rglob("*") if x.is_file()):
                if any(part.startswith(".") for part in f.relative_to(p).parts):
                    continue
                real = f.resolve()
                if not real.is_relative_to(inside):  # a link out of the folder: not followed without a word
                    out.append(
                        (
                            f,
                            f"a symbolic link out of {p.name or p} (to {real}): not followed; "
                            f"name that file itself to ingest it",
                        )
                    )
                    continue
                bag = next((b for b in f.parents if b in bags), None)
                if bag is not None:  # a part of a split bag: the bag is one log, listed once
                    if bag not in bags_listed:
                        bags_listed.add(bag)
                        out.append((bag, None))
                    continue
                out.append((f, None if log_format(f) else "skip: not a log file"))
        elif p.is_file():
            out.append(
                (p, None if log_format(p) else f"not a log file: expected a .csv, .csv.gz or .mcap name (got {p.name})")
            )
        else:
            out.append((p, "no such file or folder"))
    return out


def read_log(
    data: bytes, fmt: str, mapping: Mapping, limits: IngestLimits | None = None, bag: BagInfo | None = None
) -> RawLog:
    """Parse the bytes of one log within `limits`; `Rejected` with a reason when they cannot be read.

    `bag`: the bytes are the parts of a split rosbag2 folder, one after the other (`bag.sizes`).
    """
    limits = limits or IngestLimits()
    if bag is not None:
        return read_split_bag(data, bag, mapping, limits)
    if fmt == "mcap":
        return read_mcap_log(data, mapping, limits)
    check_log_bytes(data)
    return read_csv_log(data, fmt, mapping, limits)


@dataclass(frozen=True)
class ParseJob:
    """One file's bytes and what reading them takes: the input of `parse_log`, a worker's task."""

    data: bytes
    fmt: str  # 'csv' | 'csv.gz' | 'mcap'
    session_default: str  # the session id when the file carries none (its name)
    mapping: Mapping
    driver: str | None  # --driver
    limits: IngestLimits = IngestLimits()  # what reading the file may cost
    bag: BagInfo | None = None  # a split rosbag2 folder: `data` is its parts in order


@dataclass
class Parsed:
    """A file read and validated (`rec`), or why it was refused (`reason`)."""

    rec: Canonical | None = None
    reason: str = ""


def parse_log(job: ParseJob) -> Parsed:
    """Read and validate one file's bytes into canonical tables; pure (no workspace, no file system)."""
    try:
        raw = read_log(job.data, job.fmt, job.mapping, job.limits, job.bag)
        traffic = traffic_frame(raw)
        # the traffic's Parquet encoding (pyarrow, mostly without the GIL) starts now and runs beside the
        # checks and the store's other writes (measured: 10-20 % off a 10-minute, 20-vehicle CSV's ingest
        # wall time), on a thread of this call's own (a module-wide pool would be dead in a forked child)
        encoder = ThreadPoolExecutor(1, thread_name_prefix="laneprint-encode")
        encoding = encoder.submit(encode_traffic, traffic)
        encoder.shutdown(wait=False)  # the encoding runs on; nothing else is given to this pool
        rec = canonicalise(raw, job.mapping, job.session_default, job.driver, traffic)
        if rec.traffic is traffic:  # not when the checks dropped samples
            rec.traffic_parquet = encoding
        return Parsed(rec)
    except Rejected as exc:
        return Parsed(reason=str(exc))
    except (ValueError, TypeError, KeyError, IndexError, OverflowError, MemoryError) as exc:
        # a file shape no check anticipated: refuse it, keep the batch going
        return Parsed(reason=f"unexpected content ({type(exc).__name__}: {first_line(exc)}); please report this file")


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

    def __init__(self, ws: Workspace, mapping: Mapping, driver: str | None, limits: IngestLimits | None = None) -> None:
        self.ws = ws
        self.limits = limits or IngestLimits()
        self.mapping = mapping
        self.driver = driver
        cat = ws.recordings()
        self.sessions: dict[tuple[str, str], tuple[str, str]] = {
            (str(r.driver_id), str(r.session_id)): (str(r.recording_id), str(r.source_name)) for r in cat.itertuples()
        }

    def reject(self, path: Path, fmt: str, rid: str, reason: str) -> FileResult:
        try:
            self.ws.record_rejected(
                {
                    "content_hash": rid,
                    "source_name": path.name,
                    "source_path": str(path.resolve()),
                    "format": fmt,
                    "reason": reason,
                    "rejected_at": _now(),
                }
            )
        except OSError:  # the workspace cannot be written (full, read-only): the report says why all the same
            pass
        return FileResult(str(path), "rejected", fmt, recording_id=rid, reason=reason)

    def not_stored(self, path: Path, rid: str, exc: OSError) -> FileResult:
        """The result of a file whose recording could not be written (a full disk, a read-only folder):
        nothing of it is left in the workspace (writes are staged and renamed into place)."""
        where = f" ({Path(exc.filename).name})" if getattr(exc, "filename", None) else ""
        return self.reject(
            path,
            log_format(path) or "",
            rid,
            f"not stored: the workspace cannot be written: "
            f"{exc.strerror or exc}{where}; free space or fix "
            f"the permissions and ingest it again",
        )

    def prepare(self, path: Path) -> FileResult | tuple[ParseJob, str]:
        """Read a file's bytes: its `ParseJob` and content hash, or its result when it needs no parsing."""
        fmt = log_format(path) or ""
        bag = None
        try:
            if path.is_dir():
                bag, data = self.read_bag(path)
            else:
                check_file_size(path.stat().st_size, self.limits)
                data = path.read_bytes()
        except Rejected as exc:
            return self.reject(path, fmt, "", str(exc))
        except OSError as exc:
            return self.reject(path, fmt, "", f"cannot read the file: {exc.strerror or exc}")
        rid = content_id(data)
        if self.ws.has_recording(rid):
            return self.same_bytes(path, fmt, rid)
        session = session_stem(path) if bag is None else path.name
        return ParseJob(data, fmt, session, self.mapping, self.driver, self.limits, bag), rid

    def read_bag(self, folder: Path) -> tuple[BagInfo, bytes]:
        """A split rosbag2 folder's info (with each part's size) and its parts' bytes in order."""
        info, paths = bag_parts(folder)
        for p in paths:
            check_file_size(p.stat().st_size, self.limits)
        parts = [p.read_bytes() for p in paths]
        return replace(info, sizes=tuple(map(len, parts))), b"".join(parts)

    @staticmethod
    def same_bytes(path: Path, fmt: str, rid: str) -> FileResult:
        return FileResult(
            str(path), "duplicate", fmt, recording_id=rid, reason=f"same bytes already ingested as recording {rid}"
        )

    def store(self, path: Path, rid: str, parsed: Parsed) -> FileResult:
        """Keep a parsed file: reject it, call it a duplicate (bytes or session), or write its recording."""
        fmt = log_format(path) or ""
        if self.ws.has_recording(rid):  # an identical file earlier in this batch
            return self.same_bytes(path, fmt, rid)
        if parsed.rec is None:
            return self.reject(path, fmt, rid, parsed.reason)
        rec = parsed.rec
        driver_id, session_id = rec.meta["driver_id"], rec.meta["session_id"]
        result = FileResult(
            str(path),
            "warning" if rec.warnings else "ingested",
            fmt,
            rid,
            driver_id,
            session_id,
            len(rec.ego),
            rec.n_presses,
            warnings=rec.warnings,
        )
        earlier = self.sessions.get((driver_id, session_id))
        if earlier and earlier[0] != rid:
            result.status = "duplicate"
            result.reason = (
                f"driver {driver_id} session {session_id} is already in the workspace as recording "
                f"{earlier[0]} ({earlier[1]})"
            )
            return result
        with _claim_session(self.ws, driver_id, session_id, rid) as holder:
            if holder:
                result.status = "duplicate"
                result.reason = (
                    f"driver {driver_id} session {session_id} is already in the workspace as recording {holder}"
                )
                return result
            return self._store(path, fmt, rid, rec, result)

    def _store(self, path: Path, fmt: str, rid: str, rec: Any, result: FileResult) -> FileResult:
        """Write the claimed recording; `result` updated (or a rejection when it does not fit)."""
        driver_id, session_id = result.driver_id, result.session_id
        meta = {
            "recording_id": rid,
            "driver_id": driver_id,
            "session_id": session_id,
            "speed_limit_kph": rec.meta["speed_limit_kph"],
            "simulator": rec.meta["simulator"],
            "source_name": path.name,
            "source_path": str(path.resolve()),
            "format": fmt,
            "n_samples": len(rec.ego),
            "duration_s": float(rec.ego["t_s"].iloc[-1] - rec.ego["t_s"].iloc[0]),
            "n_presses": rec.n_presses,
            "n_vehicles": rec.n_vehicles,
            "status": "warning" if rec.warnings else "ok",
            "warnings": "; ".join(rec.warnings),
            "ingested_at": _now(),
        }
        try:
            stored = self.ws.write_recording(meta, rec.ego, rec.traffic, rec.encoded_traffic)
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


def ingest_paths(
    paths: list[Path],
    workspace: Workspace,
    driver_id: str | None = None,
    mapping: Path | None = None,
    progress: ProgressFn | None = None,
    backend: str = "local",
    ray_address: str | None = None,
    limits: IngestLimits | None = None,
) -> IngestReport:
    """Ingest every log under `paths` into `workspace`; a report with one result per file.

    Files are read and validated by `parse_log` on `backend` (`laneprint.parallel`:
    this process, or Ray workers that get each file's bytes) and stored here, in file
    order, so the result does not depend on the backend. Raises `UserError` only when
    nothing can be done at all (no path exists, a bad mapping file, a workspace that
    is a file, a backend that cannot start, a bad LANEPRINT_MAX_* value).
    `limits` bound what one file may cost (default: `IngestLimits.from_env()`).
    """
    paths = check_paths(paths)
    the_mapping = load_mapping(mapping)
    check_backend(backend, ray_address)
    ws = workspace.check_writable()
    limits = limits or IngestLimits.from_env()
    batch = _Batch(ws, the_mapping, driver_id.strip() if driver_id and driver_id.strip() else None, limits)
    notes = [f"{path}: damaged, left out of the catalogue ({why})" for path, why in ws.damaged.items()]
    found = discover(paths)
    results: list[FileResult | None] = [None] * len(found)
    to_read = []
    for i, (path, why) in enumerate(found):
        if why is None:
            to_read.append((i, path))
        elif why.startswith("skip:"):
            results[i] = FileResult(str(path), "skipped", reason=why[5:].strip())
        elif path.exists():
            results[i] = batch.reject(path, log_format(path) or path.suffix.lstrip("."), "", why)
        else:
            results[i] = FileResult(str(path), "rejected", reason=why)
    done = 0

    def finish(i: int, result: FileResult) -> None:
        nonlocal done
        results[i] = result
        done += 1
        report(progress, done, len(to_read), Path(result.source).name)

    queued: deque[tuple[int, Path, str]] = deque()  # files handed to the tasks, in order

    def jobs() -> Iterator[ParseJob]:
        """Read each file as the tasks ask for it; a file that needs no parsing is finished here."""
        for i, path in to_read:
            got = batch.prepare(path)
            if isinstance(got, FileResult):
                finish(i, got)
            else:
                queued.append((i, path, got[1]))
                yield got[0]

    report(progress, 0, len(to_read), "ingest")
    for parsed in iter_tasks(parse_log, jobs(), backend=backend, ray_address=ray_address):
        i, path, rid = queued.popleft()
        try:
            result = batch.store(path, rid, parsed)
        except OSError as exc:  # this file's recording cannot be written; the next ones are tried
            result = batch.not_stored(path, rid, exc)
        finish(i, result)
    return IngestReport([r for r in results if r is not None], str(ws.root), notes)


def catalogue_row(ws: Workspace, recording_id: str) -> pd.Series:
    """The RECORDINGS row of one recording (for tests and the dashboard)."""
    cat = ws.recordings()
    return cat[cat["recording_id"] == recording_id].iloc[0]
