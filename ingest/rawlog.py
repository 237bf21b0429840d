"""What a reader hands to validation: one log's signals as arrays, before checks.

Readers (`csv_reader`, `mcap_reader`) fill a `RawLog` with canonical names and SI
units (the mapping already applied); `validate.canonicalise` checks it and turns it
into the EGO / TRAFFIC tables. A reader that cannot go on raises `Rejected`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


class Rejected(Exception):
    """A log that cannot be ingested; the message is the one-line reason shown to the user."""


@dataclass
class RawLog:
    """Signals of one log, canonical names, SI units; arrays are aligned on the ego samples."""

    format: str  # 'csv', 'csv.gz' or 'mcap'
    meta: dict[str, Any]  # driver_id / session_id / speed_limit_kph / simulator found in the file
    t_abs_s: np.ndarray  # ego sample times as in the file [s] (for messages)
    t_s: np.ndarray  # ego sample times relative to the first sample [s]
    ego: dict[str, np.ndarray]  # EGO columns except t_s (floats with NaN where empty)
    traffic: dict[str, np.ndarray]  # TRAFFIC columns (t_s relative to the first ego sample)
    locate: Callable[[int], str]  # ego sample index -> where it is in the file ("line 12")
    time_name: str  # what the time signal is called in the file, for messages
    names: dict[str, str] = field(default_factory=dict)  # canonical signal -> name in the file
    has_button: bool = True  # whether the log records the lane-change button at all
    warnings: list[str] = field(default_factory=list)
    n_vehicles: int | None = None  # distinct traffic vehicles, when the reader knows it without counting
    vehicle_grid: int = 0  # k when the reader knows the traffic rows are k vehicles in the same order at
    # every sample (`values._vehicle_grid`); 0 when it does not


def first_line(text: str | BaseException, limit: int = 200) -> str:
    """The first line of an error text (or of an exception's message), shortened for a one-line reason."""
    if not str(text).strip():  # a blank text says itself; an exception without a message, its type
        return repr(text) if isinstance(text, str) else type(text).__name__
    line = str(text).strip().splitlines()[0]
    return line if len(line) <= limit else line[: limit - 3] + "..."


LFS_POINTER = b"version https://git-lfs.github.com/spec/"


def check_log_bytes(data: bytes) -> None:
    """`Rejected` for bytes that cannot be a log of any format: none at all, or a Git LFS pointer."""
    if not data:
        raise Rejected("empty file (0 bytes)")
    check_lfs_pointer(data)


def check_lfs_pointer(data: bytes) -> None:
    """`Rejected` when the bytes are a Git LFS pointer (what a clone without LFS holds instead of the file)."""
    if not data.startswith(LFS_POINTER) or len(data) > 1024:
        return
    fields = dict(line.split(" ", 1) for line in data.decode("utf-8", "replace").splitlines() if " " in line)
    size = fields.get("size", "").strip()
    real = f" of {int(size):,} bytes" if size.isdigit() else ""
    raise Rejected(
        f"a Git LFS pointer, not the log itself (the real file{real} was not fetched): "
        f"fetch it with `git lfs pull` in the repository it came from"
    )
