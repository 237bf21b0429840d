"""A CSV cut into parts parsed side by side reads exactly like one parse of the whole file."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from ingest import csv_reader
from ingest.csv_reader import read_csv_log
from ingest.mapping import IDENTITY
from ingest.rawlog import Rejected
from ingest.writers import write_csv


@pytest.fixture
def csv_bytes(tmp_path, recording):
    write_csv(tmp_path / "r.csv", *recording)
    return (tmp_path / "r.csv").read_bytes()


def _read(data: bytes, parts: int, monkeypatch) -> object:
    """read_csv_log with the file cut into `parts` parts (1: no cut); the RawLog or the Rejected."""
    monkeypatch.setattr(csv_reader, "PART_MIN_BYTES", 1 if parts > 1 else 1 << 40)
    monkeypatch.setattr(csv_reader.pa, "cpu_count", lambda: parts)
    try:
        return read_csv_log(data, "csv", IDENTITY)
    except Rejected as exc:
        return exc


@pytest.mark.parametrize("parts", [2, 3, 7])
def test_parts_read_like_the_whole_file(csv_bytes, parts, monkeypatch):
    whole = _read(csv_bytes, 1, monkeypatch)
    cut = _read(csv_bytes, parts, monkeypatch)
    assert len(cut.t_s) == len(whole.t_s) == 200
    np.testing.assert_array_equal(cut.t_abs_s, whole.t_abs_s)
    for key, values in whole.ego.items():
        np.testing.assert_array_equal(cut.ego[key], values, err_msg=key)
    for key, values in whole.traffic.items():
        if isinstance(values, pa.Array):
            assert cut.traffic[key].to_pylist() == values.to_pylist()
        else:
            np.testing.assert_array_equal(cut.traffic[key], values, err_msg=key)
    assert (cut.meta, cut.n_vehicles) == (whole.meta, 3)


def test_errors_in_a_later_part_name_the_files_line(csv_bytes, monkeypatch):
    lines = csv_bytes.decode().splitlines()
    header = lines[0].split(",")
    row = lines[180].split(",")
    row[header.index("ego_v")] = "fast"
    bad_value = "\n".join(lines[:180] + [",".join(row)] + lines[181:]) + "\n"
    reason = str(_read(bad_value.encode(), 2, monkeypatch))
    assert reason == str(_read(bad_value.encode(), 1, monkeypatch))
    assert reason.startswith("column 'ego_v' line 181: 'fast' is not a number")

    ragged = "\n".join(lines[:150] + [lines[150] + ",1"] + lines[151:]) + "\n"
    assert str(_read(ragged.encode(), 3, monkeypatch)) == "malformed CSV: line 151 has 30 fields, the header has 29"


def test_vehicle_ids_of_a_grid_are_the_ids_repeated_per_sample():
    """The ids of a log whose vehicles are present at every sample, built from Arrow buffers."""
    ids = ["a", "V12", "é-7", ""]
    got = csv_reader._tiled(ids, 3)
    assert got.type == pa.string()
    assert got.to_pylist() == ids * 3
    assert csv_reader._tiled(ids, 0).to_pylist() == []
