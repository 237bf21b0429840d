"""The recording store's own Arrow conversion gives the values `pa.Table.from_pandas` gives, typed by
the table's schema, and its Parquet files read back as they were written."""

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
from laneprint.schemas import EGO, TRAFFIC, Column, Schema
from laneprint.workspace import _to_arrow, _write_parquet


def _same_as_from_pandas(df: pd.DataFrame, schema: Schema) -> pa.Table:
    want = pa.Table.from_pandas(df, preserve_index=False)
    got = _to_arrow(df, schema)
    assert got.column_names == want.column_names
    for name in want.column_names:  # NaN stored as null, as from_pandas does
        g, w = got.column(name), want.column(name)
        assert g.null_count == w.null_count, name
        assert g.to_pylist() == w.to_pylist(), name
        if not pa.types.is_null(w.type):
            assert g.type == w.type, name
    return got


@pytest.mark.parametrize("fmt", ["csv", "mcap"])
def test_canonical_tables_convert_as_from_pandas(tmp_path, fmt, recording):
    meta, ego, traffic = recording
    path = tmp_path / f"rec.{fmt}"
    (write_mcap if fmt == "mcap" else write_csv)(path, meta, ego, traffic)
    rec = canonicalise(read_log(path.read_bytes(), fmt, IDENTITY), IDENTITY, "rec", None)
    assert rec.traffic["y_m"].isna().any()  # a float column with empty values takes from_pandas' path
    _same_as_from_pandas(rec.ego, EGO)
    _same_as_from_pandas(rec.traffic, TRAFFIC)


def test_odd_frames_convert_as_from_pandas(tmp_path):
    frames = [
        pd.DataFrame({"a": np.array([], dtype=float), "s": pd.Series([], dtype=object)}),
        pd.DataFrame(
            {
                "a": [np.nan, np.nan],
                "b": [1.0, np.inf],
                "i": [1, 2],
                "f": [True, False],
                "s": pd.Series([None, "x"], dtype=object),
                "z": np.array([1.5, 2.5], dtype=np.float32),
            }
        ),
    ]
    schema = Schema("odd", "", (Column("s", "str", "", nullable=True),))
    for df in frames:
        got = _same_as_from_pandas(df, schema)
        assert got.schema.field("s").type == pa.string()  # not null, even when every value is None
    _write_parquet(frames[1], tmp_path / "t.parquet", schema)
    back = pq.read_table(tmp_path / "t.parquet")
    assert back.column("a").null_count == 2 and back.column("s").to_pylist() == [None, "x"]
