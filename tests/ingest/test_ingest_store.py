"""The recording store writes the same Arrow tables as `pa.Table.from_pandas` (its faster conversion)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from ingest.mapping import IDENTITY
from ingest.pipeline import read_log
from ingest.validate import canonicalise
from ingest.writers import write_csv, write_mcap
from laneprint.workspace import _to_arrow, _write_parquet


def _same_as_from_pandas(df: pd.DataFrame) -> None:
    want = pa.Table.from_pandas(df, preserve_index=False)
    got = _to_arrow(df)
    assert got.schema.equals(want.schema, check_metadata=True)
    assert got.equals(want)
    for name in want.column_names:  # NaN stored as null, as from_pandas does
        assert got.column(name).null_count == want.column(name).null_count, name


@pytest.mark.parametrize("fmt", ["csv", "mcap"])
def test_canonical_tables_convert_as_from_pandas(tmp_path, fmt, recording):
    meta, ego, traffic = recording
    path = tmp_path / f"rec.{fmt}"
    (write_mcap if fmt == "mcap" else write_csv)(path, meta, ego, traffic)
    rec = canonicalise(read_log(path.read_bytes(), fmt, IDENTITY), IDENTITY, "rec", None)
    assert rec.traffic["y_m"].isna().any()  # a float column with empty values takes from_pandas' path
    _same_as_from_pandas(rec.ego)
    _same_as_from_pandas(rec.traffic)


def test_odd_frames_convert_as_from_pandas(tmp_path):
    frames = [
        pd.DataFrame({"a": np.array([], dtype=float), "s": pd.Series([], dtype=object)}),
        pd.DataFrame({"a": [np.nan, np.nan], "b": [1.0, np.inf], "i": [1, 2], "f": [True, False],
                      "s": pd.Series([None, "x"], dtype=object), "z": np.array([1.5, 2.5], dtype=np.float32)}),
    ]
    for df in frames:
        _same_as_from_pandas(df)
    _write_parquet(frames[1], tmp_path / "t.parquet")
    back = pq.read_table(tmp_path / "t.parquet")
    assert back.column("a").null_count == 2 and back.schema.pandas_metadata is not None
