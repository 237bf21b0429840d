"""The workspace store: Parquet files in folders, queried through DuckDB.

Layout under the workspace root (default `./workspace`)::

    recordings/<recording_id>/meta.parquet   one RECORDINGS row
    recordings/<recording_id>/ego.parquet    EGO table
    recordings/<recording_id>/traffic.parquet TRAFFIC table
    rejected/<key>.json                      one REJECTED row per refused file
    <stage>/<table>.parquet                  a stage's result tables (e.g. analysis/)
    <stage>/meta.json                        the stage's config, code version, data fingerprint
    runs/<run_id>/...                        training runs (see rl/)

Every write is atomic: files are written under `.tmp/` and renamed into place,
so a reader (the dashboard, a second process) never sees half a recording or half
an analysis. A recording folder is created by one `rename`; when two ingests of the
same bytes race, one rename wins and the other reports a duplicate. A stage folder is
swapped with its new version in one `renameat2(RENAME_EXCHANGE)`. The catalogue
is a DuckDB view over the folders, so there is no shared database file to lock.

A temporary file or folder is flock-ed by its writer until it is renamed into place
(`laneprint.locks`), so one left unlocked is the leftover of a killed process and
`laneprint check --repair` may remove it, while a live writer's is left alone.
"""

from __future__ import annotations

import ctypes
import errno
import hashlib
import json
import os
import shutil
import tempfile
import uuid
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

import duckdb
import numpy as np
import xxhash
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from laneprint.errors import UserError
from laneprint.files import (  # noqa: F401 - kept importable from here
    ANALYSIS_FINGERPRINT_TABLES,
    TMP_SUFFIX,
    analysis_fingerprint,
    atomic_write_bytes,
    atomic_write_json,
)
from laneprint.locks import FileLock
from laneprint.schemas import EGO, RECORDINGS, REJECTED, TRAFFIC, Schema, validate

DEFAULT_WORKSPACE = Path("workspace")


def content_id(data: bytes) -> str:
    """A file's recording id: the first 16 hex digits of the XXH3-128 hash of its bytes.

    XXH3 hashes an 18 MB log in 1 ms where SHA-256 (the id of workspaces written before
    2026-12-03, see `legacy_content_id`) took 11 ms, 8 % of a CSV ingest. The id tells identical files
    apart from different ones; nothing relies on it being hard to forge."""
    return xxhash.xxh3_128_hexdigest(data)[:16]


def legacy_content_id(data: bytes) -> str:
    """The recording id workspaces written before 2026-12-03 gave a file (SHA-256)."""
    return hashlib.sha256(data).hexdigest()[:16]


def _plain_strings(df: pd.DataFrame) -> pd.DataFrame:
    """Give every text column pandas' default string dtype, whatever dtype it was stored with,
    so frames from different writers merge and compare without dtype surprises."""
    for col in df.columns:
        if isinstance(df[col].dtype, pd.StringDtype) or df[col].dtype == object:
            df[col] = df[col].astype("str").where(df[col].notna(), None)
    return df


_ARROW_TYPES = {"float": pa.float64(), "int": pa.int64(), "bool": pa.bool_(), "str": pa.string()}


def _to_arrow(df: pd.DataFrame, schema: Schema) -> pa.Table:
    """`df` as an Arrow table, NaN and None as null; object columns typed by `schema` (a column of only
    None would otherwise be stored as type null), others as pyarrow converts them. Without pandas'
    metadata: `pa.Table.from_pandas` infers it by scanning every object column (2 ms for a one-row
    catalogue entry) and readers need none of it. Float columns without a NaN (the test is a minimum,
    which a NaN turns NaN: no temporary array) are taken without a copy."""
    kinds = {c.name: c.kind for c in schema.columns}
    arrays = []
    for name in df.columns:
        col = df[name]
        if col.dtype == np.float64:
            values = col.to_numpy()
            if not (len(values) and np.isnan(values.min())):
                arrays.append(pa.array(values))
                continue
        kind = kinds.get(name) if col.dtype == object else None  # typed columns keep their Arrow type
        arrays.append(pa.array(col, type=_ARROW_TYPES[kind] if kind else None, from_pandas=True))
    return pa.Table.from_arrays(arrays, names=[str(c) for c in df.columns])


def _write_parquet(df: pd.DataFrame, path: Path | pa.NativeFile, schema: Schema) -> None:
    """Write `df` as Parquet the fast way (measured on the traffic of a 10-minute, 20-vehicle log:
    `benchmarks/ingest.py`, README "Ingest speed"): float columns BYTE_STREAM_SPLIT (a third of the
    time of plain or dictionary encoding), integer columns DELTA_BINARY_PACKED (half the time of a
    dictionary), text plain; LZ4 (raw) compression, as fast as snappy and a quarter smaller here; no
    min/max statistics (recordings are read whole: they serve no query, and cost ~15 % of the write);
    data pages of version 2 (a quarter less time than version 1). pyarrow, pandas and DuckDB read it."""
    table = _to_arrow(df, schema)
    encodings = {
        f.name: "BYTE_STREAM_SPLIT" if pa.types.is_floating(f.type) else "DELTA_BINARY_PACKED"
        for f in table.schema
        if pa.types.is_floating(f.type) or pa.types.is_integer(f.type)
    }
    pq.write_table(
        table,
        path,
        use_dictionary=False,
        column_encoding=encodings or None,
        compression="lz4",
        write_statistics=False,
        data_page_version="2.0",
    )


def encode_traffic(traffic: pd.DataFrame) -> bytes:
    """The TRAFFIC table as `write_recording` stores it (validated, then Parquet bytes): lets a caller
    encode it while other work runs (`ingest.pipeline.parse_log` does it beside the ego checks);
    `SchemaError` when it does not fit."""
    buf = pa.BufferOutputStream()
    _write_parquet(validate(traffic, TRAFFIC), buf, TRAFFIC)
    return buf.getvalue().to_pybytes()


def _write_traffic(traffic: pd.DataFrame, path: Path, encoded: Callable[[], bytes | None] | None) -> None:
    data = encoded() if encoded is not None else None
    path.write_bytes(encode_traffic(traffic) if data is None else data)


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def exchange_paths(a: Path, b: Path) -> bool:
    """Swap two existing paths in one atomic step (Linux renameat2); False where unsupported."""
    fn = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    if fn is None:
        return False
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(a))


class DamagedFile(UserError):
    """A file of the workspace that cannot be read (not Parquet, cut short); the message names it."""


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0][:160] if text else ''}"


class Workspace:
    """A folder holding everything laneprint has ingested, analysed and trained."""

    def __init__(self, root: Path | str = DEFAULT_WORKSPACE) -> None:
        from laneprint.workspace_migrations import check_format

        self.root = Path(root).resolve()
        # files the last `recordings()` left out because they cannot be read: path (relative) -> why
        self.damaged: dict[str, str] = {}
        check_format(self)  # a newer format refused, an older one migrated (`laneprint.workspace_migrations`)

    # --- paths -------------------------------------------------------------

    @property
    def recordings_dir(self) -> Path:
        return self.root / "recordings"

    @property
    def rejected_dir(self) -> Path:
        return self.root / "rejected"

    @property
    def runs_dir(self) -> Path:
        return self.root / "runs"

    def stage_dir(self, stage: str) -> Path:
        return self.root / stage

    def ensure(self) -> "Workspace":
        """Create the workspace folders if needed, a new workspace stamped with the current format
        (`laneprint.workspace_migrations`); refuse a path that is a file."""
        from laneprint.workspace_migrations import FORMAT_FILE, has_content, stamp

        if self.root.exists() and not self.root.is_dir():
            raise UserError(f"workspace {self.root} is a file, not a folder")
        new = not has_content(self.root)
        for d in (self.recordings_dir, self.rejected_dir, self.runs_dir, self.root / ".tmp"):
            d.mkdir(parents=True, exist_ok=True)
        if new and not (self.root / FORMAT_FILE).exists():
            stamp(self.root)
        return self

    def check_writable(self) -> "Workspace":
        """`ensure` the workspace and create (then remove) a file in it: `UserError` in one line when it
        cannot be written (a read-only file system, no permission, a full disk)."""
        try:
            self.ensure()
            fd, probe = tempfile.mkstemp(dir=self.root / ".tmp", prefix=".probe.", suffix=TMP_SUFFIX)
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            raise UserError(f"cannot write to workspace {self.root}: {exc.strerror or exc}") from None
        return self

    @property
    def locks_dir(self) -> Path:
        return self.root / ".locks"

    @contextmanager
    def staging(self) -> Iterator[Path]:
        """A fresh folder under `.tmp/`, locked by this process until the block ends (then removed
        if still there): write into it, then rename it (or what is in it) into place."""
        self.ensure()
        d = self.root / ".tmp" / uuid.uuid4().hex
        d.mkdir()
        lock = FileLock(d)
        try:
            lock.acquire(blocking=False)
            yield d
        finally:
            shutil.rmtree(d, ignore_errors=True)
            lock.release()

    def lock(self, name: str) -> FileLock:
        """A named workspace-wide lock (`.locks/<name>.lock`), released when its holder dies."""
        return FileLock(self.locks_dir / f"{name}.lock")

    # --- recordings ----------------------------------------------------------

    def has_recording(self, recording_id: str) -> bool:
        return (self.recordings_dir / recording_id / "meta.parquet").exists()

    def write_recording(
        self,
        meta: dict[str, Any],
        ego: pd.DataFrame,
        traffic: pd.DataFrame,
        encoded_traffic: Callable[[], bytes | None] | None = None,
    ) -> bool:
        """Store one recording atomically. Returns False if it was already there.

        `encoded_traffic`: gives `encode_traffic(traffic)` when the caller has it (or is encoding it), or
        None; called on the thread that writes the traffic, beside the other writes."""
        meta_df = validate(pd.DataFrame([meta]), RECORDINGS)
        validate(ego, EGO)
        rid = meta["recording_id"]
        final = self.recordings_dir / rid
        if final.exists():
            return False
        with self.staging() as tmp:
            # the traffic, by far the longest write, is checked and encoded on a thread of its own
            # (pyarrow releases the GIL while it writes) while the ego and meta are written here
            with ThreadPoolExecutor(1) as pool:
                traffics = pool.submit(_write_traffic, traffic, tmp / "traffic.parquet", encoded_traffic)
                _write_parquet(ego, tmp / "ego.parquet", EGO)
                _write_parquet(meta_df, tmp / "meta.parquet", RECORDINGS)
                traffics.result()
            try:
                os.rename(tmp, final)
            except OSError:  # another process stored the same bytes first
                return False
            return True

    def recordings(self) -> pd.DataFrame:
        """The catalogue: one RECORDINGS row per stored recording, sorted by driver and session."""
        files = sorted(self.recordings_dir.glob("*/meta.parquet"))
        self.damaged = {}
        if files:
            try:
                return self._catalogue(files)
            except duckdb.Error:  # a damaged file: find it, leave it out, and read the others
                files = [f for f in files if self._readable(f)]
        if not files:
            return pd.DataFrame({c: pd.Series(dtype="object") for c in RECORDINGS.names})
        return self._catalogue(files)

    @staticmethod
    def _catalogue(files: list[Path]) -> pd.DataFrame:
        with duckdb.connect() as con:
            return con.execute(
                "SELECT * FROM read_parquet(?, union_by_name=true) ORDER BY driver_id, session_id",
                [[str(f) for f in files]],
            ).df()

    def _readable(self, path: Path) -> bool:
        """True when `path` reads as Parquet; otherwise it is noted in `damaged`."""
        try:
            pq.read_table(path)
            return True
        except (OSError, ValueError) as exc:  # pyarrow's ArrowInvalid is a ValueError, ArrowIOError an OSError
            self.damaged[str(path.relative_to(self.root))] = _first_line(exc)
            return False

    def load_recording(self, recording_id: str) -> tuple[dict[str, Any], pd.DataFrame, pd.DataFrame]:
        """Return (meta, ego, traffic) of one stored recording."""
        d = self.recordings_dir / recording_id
        if not (d / "meta.parquet").exists():
            raise UserError(f"no recording {recording_id!r} in workspace {self.root}")
        try:
            meta = {k: None if pd.isna(v) else v for k, v in pd.read_parquet(d / "meta.parquet").iloc[0].items()}
            return (
                meta,
                _plain_strings(pd.read_parquet(d / "ego.parquet")),
                _plain_strings(pd.read_parquet(d / "traffic.parquet")),
            )
        except (OSError, ValueError, IndexError) as exc:
            raise DamagedFile(
                f"recording {recording_id} cannot be read, a file of it is damaged "
                f"({_first_line(exc)}); `laneprint check` names it"
            ) from None

    def iter_recordings(self) -> Iterator[tuple[dict[str, Any], pd.DataFrame, pd.DataFrame]]:
        """Yield (meta, ego, traffic) for every stored recording, in catalogue order."""
        for rid in self.recordings()["recording_id"]:
            yield self.load_recording(rid)

    # --- rejected files ------------------------------------------------------

    def record_rejected(self, row: dict[str, Any]) -> None:
        """Remember a refused file and its reason (latest attempt per content wins)."""
        validate(pd.DataFrame([row]), REJECTED)
        key = row["content_hash"] or uuid.uuid5(uuid.NAMESPACE_URL, row["source_path"]).hex[:16]
        atomic_write_json(self.rejected_dir / f"{key}.json", row)

    def forget_rejected(self, content_hash: str) -> None:
        """Drop the rejection record of content that has now been ingested."""
        (self.rejected_dir / f"{content_hash}.json").unlink(missing_ok=True)

    def rejected(self) -> pd.DataFrame:
        """All REJECTED rows, newest first."""
        rows = [json.loads(p.read_text()) for p in sorted(self.rejected_dir.glob("*.json"))]
        df = pd.DataFrame(rows, columns=REJECTED.names)
        return df.sort_values("rejected_at", ascending=False, ignore_index=True)

    # --- stage results -------------------------------------------------------

    def write_tables(
        self,
        stage: str,
        tables: dict[str, pd.DataFrame],
        meta: dict[str, Any],
        schemas: dict[str, Schema] | None = None,
    ) -> Path:
        """Replace a stage's result folder with `tables` (+ `meta.json`) in one swap.

        Tables named in `schemas` are validated first; nothing is written if any fails.
        """
        for name, schema in (schemas or {}).items():
            validate(tables[name], schema)
        if stage == "analysis" and "styles" in tables:  # what the analysis decided, whoever stores it
            meta = {**meta, "analysis_fingerprint": analysis_fingerprint(tables)}
        final = self.stage_dir(stage)
        with self.staging() as box:
            tmp = box / stage
            tmp.mkdir()
            for name, df in tables.items():
                df.to_parquet(tmp / f"{name}.parquet", index=False)
            atomic_write_json(tmp / "meta.json", meta)
            with self.lock(f"stage-{stage}"):  # one writer swaps at a time
                self._swap_in(tmp, final)
        return final

    @staticmethod
    def _swap_in(new: Path, final: Path) -> None:
        """Put folder `new` at `final`; the old `final` (if any) ends up at `new`, to be removed."""
        if not final.exists():
            os.rename(new, final)
        elif not exchange_paths(new, final):  # no renameat2: a short moment without the folder
            aside = new.with_name(new.name + "-old")
            os.rename(final, aside)
            os.rename(new, final)
            os.rename(aside, new)

    def has_table(self, stage: str, name: str) -> bool:
        return (self.stage_dir(stage) / f"{name}.parquet").exists()

    def read_table(self, stage: str, name: str) -> pd.DataFrame:
        """Read one result table; a clear error if the stage has not run."""
        path = self.stage_dir(stage) / f"{name}.parquet"
        if not path.exists():
            raise UserError(
                f"no {stage} table {name!r} in {self.root}: run `laneprint {stage if stage != 'analysis' else 'analyze'}` first"
            )
        try:
            return pd.read_parquet(path)
        except (OSError, ValueError) as exc:
            raise DamagedFile(
                f"{stage} table {path.relative_to(self.root)} is damaged ({_first_line(exc)}): "
                f"run `laneprint {stage if stage != 'analysis' else 'analyze'}` again"
            ) from None

    def read_meta(self, stage: str) -> dict[str, Any]:
        path = self.stage_dir(stage) / "meta.json"
        return json.loads(path.read_text()) if path.exists() else {}

    # --- queries -------------------------------------------------------------

    def query(self, sql: str) -> pd.DataFrame:
        """Run SQL over the workspace: views `recordings`, `rejected`, and `<stage>_<table>`."""
        with duckdb.connect() as con:
            recs = self.recordings()
            con.register("recordings", recs)
            con.register("rejected", self.rejected())
            for p in self.root.glob("*/*.parquet"):
                con.execute(f"CREATE VIEW {p.parent.name}_{p.stem} AS SELECT * FROM read_parquet('{p}')")
            return con.execute(sql).df()

    def analysis_fingerprint(self) -> str | None:
        """The fingerprint of the stored analysis (`analysis_fingerprint` of its styles and reference
        lines), None when there is no analysis. Read from `analysis/meta.json`, where `analyze` writes
        it (and the migration to workspace format 1 wrote it for an analysis saved before)."""
        stored = self.read_meta("analysis").get("analysis_fingerprint")
        return str(stored) if stored and self.has_table("analysis", "styles") else None

    def fingerprint(self) -> str:
        """A short hash of which recordings are in the workspace (their ids are content hashes)."""
        import hashlib

        ids = sorted(p.name for p in self.recordings_dir.glob("*") if (p / "meta.parquet").exists())
        return hashlib.sha256("\n".join(ids).encode()).hexdigest()[:16]
