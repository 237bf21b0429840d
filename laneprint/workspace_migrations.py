"""The workspace's format version, and the migrations of older workspaces in one place.

`workspace.json` at a workspace's root holds `{"format": N}`. `Workspace.ensure` writes it when it
creates a workspace; opening one (`Workspace(root)`) checks it (`check_format`):

- the current format: nothing to do;
- a newer one: refused in one line (`NewerWorkspace`): this laneprint does not know what it would read;
- an older one, or none in a workspace with content (written before the format was versioned:
  format 0): migrated here, one step per format (`MIGRATIONS`), under the workspace's `format` lock,
  then stamped with the current format. Code elsewhere reads the current format only.

Format 1 (2026-12): the analysis's `meta.json` carries the `analysis_fingerprint` of its tables (for an
analysis saved before it did: that of its tables as they were, which the runs made on it recorded), and
its reference lines carry their `direction` (an analysis made before directions fitted every press: 'both').
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any, Callable, Optional

from laneprint.errors import UserError
from laneprint.files import ANALYSIS_FINGERPRINT_TABLES, analysis_fingerprint, atomic_write_bytes, atomic_write_json

#: A workspace (`laneprint.workspace.Workspace`: not imported here, it opens through these migrations)
Workspace = Any

#: The format this laneprint writes.
FORMAT = 1
FORMAT_FILE = "workspace.json"


class NewerWorkspace(UserError):
    """The workspace was written by a newer laneprint."""


def read_format(root: Path) -> Optional[int]:
    """The format stamped in the workspace at `root`; None when there is no stamp."""
    path = root / FORMAT_FILE
    try:
        fmt = json.loads(path.read_text())["format"]
    except (FileNotFoundError, NotADirectoryError):  # no stamp, or no folder (a file: `ensure` says so)
        return None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UserError(
            f'{path} is not a laneprint workspace stamp ({exc}): put {{"format": {FORMAT}}} in it, or remove it'
        ) from None
    if not isinstance(fmt, int) or isinstance(fmt, bool):
        raise UserError(f"{path}: format must be a whole number, not {fmt!r}")
    return fmt


def stamp(root: Path) -> None:
    """Write the current format into the workspace at `root`."""

    atomic_write_json(root / FORMAT_FILE, {"format": FORMAT})


def has_content(root: Path) -> bool:
    """True when the folder holds anything of a workspace (a fresh or empty one needs no migration)."""
    return root.is_dir() and any(not p.name.startswith(".") and p.name != FORMAT_FILE for p in root.iterdir())


def check_format(ws: "Workspace") -> None:
    """Refuse a workspace of a newer format; migrate an older one (see the module doc)."""
    fmt = read_format(ws.root)
    if fmt == FORMAT:
        return
    if fmt is not None and fmt > FORMAT:
        raise NewerWorkspace(
            f"workspace {ws.root} was written by a newer laneprint (format {fmt}; this one reads "
            f"formats up to {FORMAT}): upgrade laneprint to use it"
        )
    if fmt is None and not has_content(ws.root):
        return
    try:
        with ws.lock("format"):
            fmt = read_format(ws.root) or 0  # another process may have migrated it meanwhile
            for step in range(fmt, FORMAT):
                MIGRATIONS[step](ws)
            if fmt < FORMAT:
                stamp(ws.root)
    except OSError as exc:
        raise UserError(
            f"workspace {ws.root} is of an older format ({fmt or 0}) and must be migrated to format "
            f"{FORMAT}, which needs writing to it: {exc.strerror or exc}"
        ) from None


def _to_1(ws: "Workspace") -> None:
    """Format 0 -> 1: the reference lines' direction ('both' before directions) and the analysis's fingerprint."""
    import pandas as pd

    folder = ws.stage_dir("analysis")
    meta_path = folder / "meta.json"
    if (folder / "styles.parquet").exists():  # first: the fingerprint runs recorded is that of the tables as they were
        meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
        if not meta.get("analysis_fingerprint"):
            tables = {
                n: pd.read_parquet(folder / f"{n}.parquet")
                for n in ANALYSIS_FINGERPRINT_TABLES
                if (folder / f"{n}.parquet").exists()
            }
            atomic_write_json(meta_path, {**meta, "analysis_fingerprint": analysis_fingerprint(tables)})
    lines = folder / "reference_lines.parquet"
    if lines.exists():
        df = pd.read_parquet(lines)
        if "direction" not in df:
            df["direction"] = "both"
            buf = io.BytesIO()
            df.to_parquet(buf, index=False)
            atomic_write_bytes(lines, buf.getvalue())


#: format N -> the step that makes a workspace of format N one of format N + 1
MIGRATIONS: dict[int, Callable[["Workspace"], None]] = {0: _to_1}
