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
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from laneprint.errors import UserError
from laneprint.locks import FileLock, lock_fd
from laneprint.schemas import EGO, RECORDINGS, REJECTED, TRAFFIC, Schema, validate

DEFAULT_WORKSPACE = Path("workspace")
TMP_SUFFIX = ".tmp"  # temporary files of atomic_write_bytes: `.<name>.<random>.tmp` beside the target
_TRAFFIC_DICT_COLUMNS = ("lane",)  # vehicle_id plain: its dictionary cost 6 of 44 ms of the write for 3 % of size


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


def _plain_strings(df: pd.DataFrame) -> pd.DataFrame:
    """Give every text column pandas' default string dtype, whatever dtype it was stored with,
    so frames from different writers merge and compare without dtype surprises."""
    for col in df.columns:
        if isinstance(df[col].dtype, pd.StringDtype) or df[col].dtype == object:
            df[col] = df[col].astype("str").where(df[col].notna(), None)
    return df


def _to_arrow(df: pd.DataFrame) -> pa.Table:
    """`df` as `pa.Table.from_pandas(df, preserve_index=False)` gives it (schema, pandas metadata, NaN as
    null), without its NaN scan of float columns that hold no NaN (2.5 ms per 600 000 values, numpy's
    test 0.3 ms): those are taken without a copy."""
    schema = pa.Schema.from_pandas(df, preserve_index=False)
    arrays = []
    for f in schema:
        col = df[f.name]
        values = col.to_numpy() if col.dtype == np.float64 else None
        if values is not None and not np.isnan(values).any():
            arrays.append(pa.array(values))
        else:
            arrays.append(pa.array(col, type=f.type, from_pandas=True))
    return pa.Table.from_arrays(arrays, schema=schema)


def _write_parquet(df: pd.DataFrame, path: Path | pa.NativeFile, dictionary: tuple[str, ...] = ()) -> None:
    """Write `df` as Parquet (snappy): the named columns dictionary-encoded, float columns
    BYTE_STREAM_SPLIT-encoded (measured: a third of the write time of plain or dictionary
    encoding of float columns, for files 5-25 % larger), other columns plain; no min/max
    statistics (recordings are read whole: they serve no query, and cost ~15 % of the write); data
    pages of version 2 (a quarter less time than version 1 for the traffic of a 10-minute, 20-vehicle
    log, the same size; pyarrow, pandas and DuckDB read both)."""
    table = _to_arrow(df)
    floats = [f.name for f in table.schema if pa.types.is_floating(f.type) and f.name not in dictionary]
    pq.write_table(table, path, use_dictionary=[c for c in dictionary if c in table.column_names],
                   column_encoding={c: "BYTE_STREAM_SPLIT" for c in floats} or None,
                   write_statistics=False, data_page_version="2.0")


def encode_traffic(traffic: pd.DataFrame) -> bytes:
    """The TRAFFIC table as `write_recording` stores it (validated, then Parquet bytes): lets a caller
    encode it while other work runs (`ingest.pipeline.parse_log` does it beside the ego checks);
    `SchemaError` when it does not fit."""
    buf = pa.BufferOutputStream()
    _write_parquet(validate(traffic, TRAFFIC), buf, _TRAFFIC_DICT_COLUMNS)
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


class Workspace:
    """A folder holding everything laneprint has ingested, analysed and trained."""

    def __init__(self, root: Path | str = DEFAULT_WORKSPACE) -> None:
        self.root = Path(root).resolve()

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
        """Create the workspace folders if needed; refuse a path that is a file."""
        if self.root.exists() and not self.root.is_dir():
            raise UserError(f"workspace {self.root} is a file, not a folder")
        for d in (self.recordings_dir, self.rejected_dir, self.runs_dir, self.root / ".tmp"):
            d.mkdir(parents=True, exist_ok=True)
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

    def write_recording(self, meta: dict[str, Any], ego: pd.DataFrame, traffic: pd.DataFrame,
                        encoded_traffic: Callable[[], bytes | None] | None = None) -> bool:
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
                _write_parquet(ego, tmp / "ego.parquet", ("ego_lane",))
                meta_df.to_parquet(tmp / "meta.parquet", index=False)
                traffics.result()
            try:
                os.rename(tmp, final)
            except OSError:  # another process stored the same bytes first
                return False
            return True

    def recordings(self) -> pd.DataFrame:
        """The catalogue: one RECORDINGS row per stored recording, sorted by driver and session."""
        files = sorted(self.recordings_dir.glob("*/meta.parquet"))
        if not files:
            return pd.DataFrame({c: pd.Series(dtype="object") for c in RECORDINGS.names})
        with duckdb.connect() as con:
            df = con.execute(
                "SELECT * FROM read_parquet(?, union_by_name=true) ORDER BY driver_id, session_id",
                [[str(f) for f in files]],
            ).df()
        return df

    def load_recording(self, recording_id: str) -> tuple[dict[str, Any], pd.DataFrame, pd.DataFrame]:
        """Return (meta, ego, traffic) of one stored recording."""
        d = self.recordings_dir / recording_id
        if not (d / "meta.parquet").exists():
            raise UserError(f"no recording {recording_id!r} in workspace {self.root}")
        meta = pd.read_parquet(d / "meta.parquet").iloc[0].to_dict()
        return meta, _plain_strings(pd.read_parquet(d / "ego.parquet")), _plain_strings(
            pd.read_parquet(d / "traffic.parquet"))

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

    def write_tables(self, stage: str, tables: dict[str, pd.DataFrame], meta: dict[str, Any],
                     schemas: dict[str, Schema] | None = None) -> Path:
        """Replace a stage's result folder with `tables` (+ `meta.json`) in one swap.

        Tables named in `schemas` are validated first; nothing is written if any fails.
        """
        for name, schema in (schemas or {}).items():
            validate(tables[name], schema)
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
            raise UserError(f"no {stage} table {name!r} in {self.root}: run `laneprint {stage if stage != 'analysis' else 'analyze'}` first")
        return pd.read_parquet(path)

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

    def fingerprint(self) -> str:
        """A short hash of which recordings are in the workspace (their ids are content hashes)."""
        import hashlib

        ids = sorted(p.name for p in self.recordings_dir.glob("*") if (p / "meta.parquet").exists())
        return hashlib.sha256("\n".join(ids).encode()).hexdigest()[:16]
