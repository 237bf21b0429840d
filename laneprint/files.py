"""Files written whole or not at all, and the fingerprint of an analysis: below the workspace, so
that the workspace and its migrations (`laneprint.workspace_migrations`) can both use them."""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

import pandas as pd

from laneprint.locks import lock_fd

TMP_SUFFIX = ".tmp"  # temporary files of atomic_write_bytes: `.<name>.<random>.tmp` beside the target

ANALYSIS_FINGERPRINT_TABLES = ("styles", "reference_lines")


def analysis_fingerprint(tables: dict[str, pd.DataFrame]) -> str:
    """What an analysis decided, as 16 hex digits: a hash of the content of its styles (who is in
    which style, the typical drivers) and its reference lines (what a style's agent is trained
    against). Two analyses with the same styles and lines have the same fingerprint; a re-analysis
    that moves a driver or a line has another. Every run, cross-validation, personalisation and
    report records the fingerprint of the analysis it used (`laneprint.provenance`)."""
    h = hashlib.sha256()
    for name in ANALYSIS_FINGERPRINT_TABLES:
        df = tables.get(name)
        if df is None:
            continue
        df = df.reindex(sorted(df.columns), axis=1)
        h.update(name.encode() + b"\0" + df.to_csv(index=False, float_format="%.9g").encode())
    return h.hexdigest()[:16]


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write `data` to `path` so readers see the old file or the new one, never a mix."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TMP_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as fh:
            lock_fd(fh.fileno())
            fh.write(data)
            fh.flush()
            os.replace(tmp, path)  # while still locked: an unlocked temp file is always a leftover
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_json(path: Path, obj: Any) -> None:
    """Write `obj` as indented JSON, atomically."""
    atomic_write_bytes(path, (json.dumps(obj, indent=2, default=str) + "\n").encode())
