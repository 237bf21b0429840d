"""The writers produce logs of format v1 that plain readers (pyarrow, mcap) understand."""

from __future__ import annotations

import json

import numpy as np
import pytest
import pyarrow.csv as pacsv
from mcap.reader import make_reader

from ingest.writers import ExtraChannel, write_csv, write_mcap


def test_csv_is_wide_with_empty_cells_for_absent_vehicles(tmp_path, recording):
    meta, ego, traffic = recording
    for name in ("r.csv", "r.csv.gz"):
        write_csv(tmp_path / name, meta, ego, traffic)
        table = pacsv.read_csv(tmp_path / name).to_pandas()
        assert len(table) == len(ego)
        assert {"t", "driver_id", "ego_x", "ego_v", "ego_lane", "lc_button", "a_x", "b_length", "c12_lane"} <= set(
            table
        )
        assert "c12_y" not in table  # no lateral position logged for c12
        assert table["driver_id"].unique().tolist() == ["D07"]
        np.testing.assert_allclose(table["ego_x"], ego["ego_x_m"], atol=5e-4)
        present_a = table["a_x"].notna().to_numpy()
        assert present_a.sum() == (traffic["vehicle_id"] == "a").sum()
        assert not present_a[-1] and present_a[0]
        assert int(table["lc_button"].diff().eq(1).sum()) == 2
    assert not list(tmp_path.glob(".*tmp"))


def test_mcap_has_the_four_topics_metadata_and_button_changes(tmp_path, recording):
    meta, ego, traffic = recording
    write_mcap(tmp_path / "r.mcap", meta, ego, traffic)
    with open(tmp_path / "r.mcap", "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
        topics = {c.topic: c.message_encoding for c in summary.channels.values()}
        assert topics == {
            "/ego/state": "json",
            "/traffic/vehicles": "json",
            "/driver/controls": "json",
            "/driver/lane_change_button": "json",
        }
        assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
        (md,) = list(reader.iter_metadata())
        assert md.name == "session" and md.metadata["driver_id"] == "D07" and md.metadata["speed_limit_kph"] == "80"
        button = [
            (m.log_time, json.loads(m.data)) for _, c, m in reader.iter_messages(topics=["/driver/lane_change_button"])
        ]
    assert button == [
        (0, {"pressed": False}),
        (1_000_000_000, {"pressed": True, "direction": "left"}),
        (1_200_000_000, {"pressed": False}),
        (3_000_000_000, {"pressed": True, "direction": "right"}),
        (3_100_000_000, {"pressed": False}),
    ]


def test_mcap_extra_channels_are_interleaved_in_log_time_order(tmp_path, recording):
    meta, ego, traffic = recording
    stamps = [0, 1_500_000_000, 3_990_000_000, 9_000_000_000]  # the last after the final sample
    extra = ExtraChannel(
        "/x/steps",
        "x.Step",
        {"type": "object", "properties": {"k": {"type": "integer"}}},
        stamps,
        [json.dumps({"k": k}).encode() for k in range(len(stamps))],
    )
    write_mcap(tmp_path / "r.mcap", meta, ego, traffic, extra=[extra], extra_metadata={"x": {"a": "1"}})
    with open(tmp_path / "r.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        got = [(c.topic, m.log_time) for _, c, m in reader.iter_messages(log_time_order=False)]
        assert {m.name: m.metadata for m in reader.iter_metadata()}["x"] == {"a": "1"}
    times = [t for _, t in got]
    assert times == sorted(times)  # written in order, not appended at the end
    assert [t for topic, t in got if topic == "/x/steps"] == stamps
    with pytest.raises(ValueError, match="/ego/state"):
        write_mcap(tmp_path / "bad.mcap", meta, ego, traffic, extra=[ExtraChannel("/ego/state", "x", {}, [0], [b"{}"])])
