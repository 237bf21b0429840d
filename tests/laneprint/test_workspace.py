"""The workspace store: atomic recordings, catalogue, stage tables, rejections."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from laneprint.errors import UserError
from laneprint.schemas import EGO, RECORDINGS, SchemaError, validate
from laneprint.workspace import Workspace, encode_traffic


def _recording(rid: str = "abcd1234abcd1234", driver: str = "D01"):
    t = np.arange(5) * 0.1
    ego = pd.DataFrame(
        {
            "t_s": t,
            "ego_x_m": 20.0 * t,
            "ego_y_m": np.zeros(5),
            "ego_v_mps": np.full(5, 20.0),
            "ego_lane": np.zeros(5, dtype="int64"),
            "ego_length_m": np.full(5, 4.5),
            "steer_rad": np.zeros(5),
            "throttle": np.zeros(5),
            "brake": np.zeros(5),
            "lc_button": [False, True, True, False, False],
            "lc_direction": [None, "left", "left", None, None],
        }
    )
    traffic = pd.DataFrame(
        {
            "t_s": t,
            "vehicle_id": ["V1"] * 5,
            "x_m": 50 + 10.0 * t,
            "y_m": np.zeros(5),
            "v_mps": np.full(5, 10.0),
            "lane": np.zeros(5, dtype="int64"),
            "length_m": np.full(5, 4.5),
        }
    )
    meta = {
        "recording_id": rid,
        "driver_id": driver,
        "session_id": "S1",
        "speed_limit_kph": 80.0,
        "simulator": None,
        "source_name": "s1.csv",
        "source_path": "/x/s1.csv",
        "format": "csv",
        "n_samples": 5,
        "duration_s": 0.4,
        "n_presses": 1,
        "n_vehicles": 1,
        "status": "ok",
        "warnings": "",
        "ingested_at": "2026-11-22T00:00:00Z",
    }
    return meta, ego, traffic


def test_recording_round_trip_and_catalogue(tmp_path):
    ws = Workspace(tmp_path / "ws").ensure()
    meta, ego, traffic = _recording()
    assert ws.write_recording(meta, ego, traffic) is True
    assert ws.write_recording(meta, ego, traffic) is False  # same content: a duplicate
    cat = ws.recordings()
    assert list(cat["recording_id"]) == [meta["recording_id"]]
    m, e, t = ws.load_recording(meta["recording_id"])
    assert m["driver_id"] == "D01"
    pd.testing.assert_frame_equal(e, ego)
    pd.testing.assert_frame_equal(t, traffic)
    assert not any(ws.root.joinpath(".tmp").iterdir())  # nothing left half written


def test_traffic_encoded_beforehand_is_stored_as_encoded_here(tmp_path):
    """Ingest encodes the traffic beside its checks; what is stored reads back as the table itself."""
    meta, ego, traffic = _recording()
    for i, encoded in enumerate((lambda: encode_traffic(traffic), lambda: None)):  # None: encoded here
        ws = Workspace(tmp_path / f"ws{i}").ensure()
        assert ws.write_recording(meta, ego, traffic, encoded) is True
        pd.testing.assert_frame_equal(ws.load_recording(meta["recording_id"])[2], traffic)
    with pytest.raises(SchemaError, match="x_m"):
        encode_traffic(traffic.drop(columns=["x_m"]))


def test_invalid_recording_is_not_written(tmp_path):
    ws = Workspace(tmp_path / "ws").ensure()
    meta, ego, traffic = _recording()
    with pytest.raises(SchemaError, match="ego_v_mps"):
        ws.write_recording(meta, ego.drop(columns=["ego_v_mps"]), traffic)
    assert ws.recordings().empty
    assert not any(ws.recordings_dir.iterdir())


def test_stage_tables_swap_and_query(tmp_path):
    ws = Workspace(tmp_path / "ws").ensure()
    ws.write_tables("analysis", {"fits": pd.DataFrame({"A": [1.0]})}, {"v": 1})
    ws.write_tables("analysis", {"fits": pd.DataFrame({"A": [2.0, 3.0]})}, {"v": 2})
    assert ws.read_table("analysis", "fits")["A"].tolist() == [2.0, 3.0]
    assert ws.read_meta("analysis") == {"v": 2}
    assert ws.query("SELECT sum(A) AS s FROM analysis_fits")["s"].iloc[0] == 5.0
    with pytest.raises(UserError, match="laneprint analyze"):
        ws.read_table("analysis", "styles")


def test_rejected_rows_and_fingerprint(tmp_path):
    ws = Workspace(tmp_path / "ws").ensure()
    empty_fp = ws.fingerprint()
    ws.record_rejected(
        {
            "content_hash": "ff" * 8,
            "source_name": "bad.mcap",
            "source_path": "/x/bad.mcap",
            "format": "mcap",
            "reason": "truncated MCAP",
            "rejected_at": "2026-11-22T00:00:00Z",
        }
    )
    assert ws.rejected()["reason"].tolist() == ["truncated MCAP"]
    ws.forget_rejected("ff" * 8)
    assert ws.rejected().empty
    ws.write_recording(*_recording())
    assert ws.fingerprint() != empty_fp


def test_workspace_that_is_a_file(tmp_path):
    f = tmp_path / "ws"
    f.write_text("x")
    with pytest.raises(UserError, match="is a file"):
        Workspace(f).ensure()


def test_validate_reports_kind_and_nulls():
    meta, ego, _ = _recording()
    with pytest.raises(SchemaError, match="ego_lane should be int"):
        validate(ego.assign(ego_lane=["a"] * 5), EGO)
    with pytest.raises(SchemaError, match="driver_id has empty values"):
        validate(pd.DataFrame([{**meta, "driver_id": None}]), RECORDINGS)
