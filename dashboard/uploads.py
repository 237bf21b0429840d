"""Saving browser uploads under the workspace, safely, before they are ingested.

An upload's name comes from the user's browser and is not trusted: only its last
path component is kept, reduced to letters, digits and `._-`, and the resolved target is
checked to lie inside `workspace/uploads/`. Bytes are copied to disk in chunks
(`shutil.copyfileobj`), counted as they come: more than the limit is refused whatever
size the browser declared.
Each file goes to `uploads/<content hash>/<safe name>`, so the original file name
(the session id when the log has none) is kept and the same bytes land in the
same place however often they are uploaded.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import unicodedata
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

LOG_SUFFIXES = (".csv", ".csv.gz", ".mcap")
_CHUNK = 1 << 20
_UNSAFE = re.compile(r"[^\w.-]+")  # letters and digits of every script stay: Cyrillic names stay apart


def safe_filename(name: str) -> str:
    """A file name that cannot leave its folder: last path part (NFC), letters and digits of any script,
    '.', '_' and '-' (everything else, controls and bidi overrides too, becomes '_'), no leading dots, at
    most 120 characters; a log suffix is kept ('.csv' alone is 'upload.csv')."""
    base = unicodedata.normalize("NFC", re.split(r"[\\/]", name or "")[-1])
    suffix = next((s for s in sorted(LOG_SUFFIXES, key=len, reverse=True) if base.lower().endswith(s)), "")
    stem = _UNSAFE.sub("_", base[: len(base) - len(suffix)]).lstrip(".")
    stem = stem[-(120 - len(suffix)) :] if len(stem) + len(suffix) > 120 else stem
    return (stem if stem.strip("._-") else "upload") + base[len(base) - len(suffix) :]


def has_log_suffix(name: str) -> bool:
    """True for .csv, .csv.gz and .mcap names (case-insensitive)."""
    return name.lower().endswith(LOG_SUFFIXES)


@dataclass(frozen=True)
class SavedUpload:
    """One upload after saving: `path` is set when it was written, else `reason` says why not."""

    name: str
    size: int
    path: Path | None = None
    reason: str = ""


class _TooLarge(Exception):
    pass


class _HashingSink:
    """A file being written that hashes what it gets and refuses more than `limit` bytes."""

    def __init__(self, path: Path, limit: int) -> None:
        self.path, self.limit, self.written = path, limit, 0
        self.digest = hashlib.sha256()

    def __enter__(self) -> "_HashingSink":
        self._fh = open(self.path, "wb")
        return self

    def __exit__(self, *exc: object) -> None:
        self._fh.close()

    def write(self, chunk: bytes) -> int:
        self.written += len(chunk)
        if self.written > self.limit:  # the browser's declared size is not trusted
            raise _TooLarge
        self.digest.update(chunk)
        return self._fh.write(chunk)


def save_upload(name: str, size: int, stream: BinaryIO, uploads_dir: Path, max_bytes: int) -> SavedUpload:
    """Copy one upload to `uploads_dir/<hash>/<safe name>`, or refuse it with a reason.

    Refuses names that are not logs, empty files and files over `max_bytes` without
    writing anything; what the bytes hold is the ingest's to judge.
    """
    if not has_log_suffix(name):
        return SavedUpload(name, size, reason="not a log: expected a .csv, .csv.gz or .mcap file")
    if size == 0:
        return SavedUpload(name, size, reason="empty file (0 bytes): nothing to ingest")
    if size > max_bytes:
        return SavedUpload(
            name,
            size,
            reason=(
                f"too large for the browser upload ({size / 2**20:.0f} MB > {max_bytes / 2**20:.0f} MB): "
                f"ingest it from the command line with `laneprint ingest PATH`"
            ),
        )
    uploads_dir = uploads_dir.resolve()
    staging = uploads_dir / ".partial"
    staging.mkdir(parents=True, exist_ok=True)
    tmp = staging / uuid.uuid4().hex
    sink = _HashingSink(tmp, max_bytes)
    if stream.seekable():  # an UploadedFile read before; a stream that cannot seek is read from where it is
        stream.seek(0)
    try:
        with sink:
            shutil.copyfileobj(stream, sink, _CHUNK)  # never the whole upload in memory at once
    except _TooLarge:
        tmp.unlink(missing_ok=True)
        return SavedUpload(
            name,
            sink.written,
            reason=(
                f"too large for the browser upload (more than {max_bytes / 2**20:.0f} MB): "
                f"ingest it from the command line with `laneprint ingest PATH`"
            ),
        )
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    digest = sink.digest
    folder = uploads_dir / digest.hexdigest()[:16]
    target = (folder / safe_filename(name)).resolve()
    if not target.is_relative_to(uploads_dir):  # cannot happen after safe_filename; kept as a guard
        tmp.unlink(missing_ok=True)
        return SavedUpload(name, size, reason="refused: file name points outside the workspace")
    folder.mkdir(exist_ok=True)
    os.replace(tmp, target)
    return SavedUpload(name, size, path=target)


def discard(path: Path, uploads_dir: Path) -> None:
    """Delete a saved upload (and its folder when empty); refuses paths outside `uploads_dir`."""
    path, uploads_dir = path.resolve(), uploads_dir.resolve()
    if not path.is_relative_to(uploads_dir) or path == uploads_dir:
        return
    path.unlink(missing_ok=True)
    try:
        path.parent.rmdir()
    except OSError:
        pass
