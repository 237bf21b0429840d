"""Write a recording as CSV / CSV.gz / MCAP, ingest it, get the same signals and button stamps back."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ingest.pipeline import ingest_paths
from ingest.writers import write_csv, write_mcap
from laneprint.workspace import Workspace

WRITERS = {"csv": write_csv, "csv.gz": write_csv, "mcap": write_mcap}


@pytest.mark.parametrize("fmt", ["csv", "csv.gz", "mcap"])
def test_round_trip_gives_the_same_signals_and_presses(tmp_path, recording, fmt):
    meta, ego, traffic = recording
    path = tmp_path / f"rec.{fmt}"
    WRITERS[fmt](path, meta, ego, traffic)
    ws = Workspace(tmp_path / "ws")
    report = ingest_paths([path], ws)
    (res,) = report.files
    assert res.status == "ingested", res.reason
    assert (res.driver_id, res.session_id, res.n_samples, res.n_presses) == ("D07", "D07_s80_01", 200, 2)

    got_meta, got_ego, got_traffic = ws.load_recording(res.recording_id)
    assert got_meta["format"] == fmt and got_meta["speed_limit_kph"] == 80.0 and got_meta["simulator"] == "test rig"
    assert got_meta["n_vehicles"] == 3 and got_meta["duration_s"] == pytest.approx(3.98)
    np.testing.assert_allclose(got_ego["t_s"], ego["t_s"], rtol=0, atol=1e-9)
    for col in ("ego_x_m", "ego_y_m", "ego_v_mps", "ego_length_m"):
        np.testing.assert_array_equal(got_ego[col].to_numpy(), np.round(ego[col].to_numpy(float), 3), err_msg=col)
    for col in ("steer_rad", "throttle", "brake"):
        np.testing.assert_array_equal(got_ego[col].to_numpy(), np.round(ego[col].to_numpy(float), 4), err_msg=col)
    np.testing.assert_array_equal(got_ego["ego_lane"], ego["ego_lane"])
    np.testing.assert_array_equal(got_ego["lc_button"], ego["lc_button"])
    presses = got_ego.index[got_ego["lc_button"] & ~got_ego["lc_button"].shift(fill_value=False)]
    assert got_ego.loc[presses, "t_s"].round(6).tolist() == [1.0, 3.0]
    assert got_ego.loc[presses, "lc_direction"].tolist() == ["left", "right"]
    assert got_ego["lc_direction"].notna().sum() == 2

    want = traffic.sort_values(["t_s", "vehicle_id"], ignore_index=True)
    got = got_traffic.sort_values(["t_s", "vehicle_id"], ignore_index=True)
    assert len(got) == len(want) == 125 + 150 + 50  # a: 2.5 s, b: 3 s, c12: 1 s at 50 Hz
    assert got["vehicle_id"].tolist() == want["vehicle_id"].tolist()
    np.testing.assert_allclose(got["t_s"], want["t_s"], rtol=0, atol=1e-9)
    for col in ("x_m", "v_mps", "length_m"):
        np.testing.assert_array_equal(got[col].to_numpy(), np.round(want[col].to_numpy(float), 3), err_msg=col)
    np.testing.assert_array_equal(got["y_m"].isna(), want["y_m"].isna())
    np.testing.assert_array_equal(got["lane"], want["lane"])
    assert set(got.loc[got["vehicle_id"] == "b", "length_m"]) == {5.2}


def test_same_bytes_twice_is_a_duplicate_and_changes_nothing(tmp_path, recording):
    path = tmp_path / "rec.csv"
    write_csv(path, *recording)
    ws = Workspace(tmp_path / "ws")
    first = ingest_paths([path], ws)
    before = sorted(p.relative_to(ws.root) for p in ws.root.rglob("*") if ".tmp" not in p.parts)
    again = ingest_paths([path], ws)
    after = sorted(p.relative_to(ws.root) for p in ws.root.rglob("*") if ".tmp" not in p.parts)
    assert again.files[0].status == "duplicate"
    assert again.files[0].recording_id == first.files[0].recording_id
    assert "already ingested" in again.files[0].reason
    assert before == after and len(ws.recordings()) == 1


def test_same_bytes_under_another_name_is_a_duplicate(tmp_path, recording, monkeypatch):
    import ingest.pipeline as pipeline

    path = tmp_path / "rec.csv"
    write_csv(path, *recording)
    ws = Workspace(tmp_path / "ws")
    first = ingest_paths([path], ws).files[0]
    copy = tmp_path / "copy" / "renamed.csv"
    copy.parent.mkdir()
    copy.write_bytes(path.read_bytes())
    again = ingest_paths([copy], ws).files[0]
    assert (again.status, again.recording_id) == ("duplicate", first.recording_id)
    assert again.reason == f"same bytes already ingested as recording {first.recording_id}"
    # the bytes are hashed before anything else: the same bytes again are not parsed at all
    monkeypatch.setattr(pipeline, "parse_log", lambda job: pytest.fail("parsed a file already stored"))
    assert ingest_paths([path], ws).files[0].status == "duplicate"
    assert len(ws.recordings()) == 1


def test_csv_and_mcap_of_one_session_count_once(tmp_path, recording):
    write_csv(tmp_path / "s.csv", *recording)
    write_mcap(tmp_path / "s.mcap", *recording)
    ws = Workspace(tmp_path / "ws")
    report = ingest_paths([tmp_path / "s.csv", tmp_path / "s.mcap"], ws)
    assert [f.status for f in report.files] == ["ingested", "duplicate"]
    assert report.files[0].recording_id in report.files[1].reason and "s.csv" in report.files[1].reason
    assert len(ws.recordings()) == 1
    # a later run (fresh catalogue snapshot) agrees
    assert ingest_paths([tmp_path / "s.mcap"], ws).files[0].status == "duplicate"


def test_catalogue_lists_all_formats_and_empty_metadata(tmp_path, recording):
    meta, ego, traffic = recording
    write_csv(tmp_path / "one.csv", dict(meta, session_id=None, simulator=None, speed_limit_kph=None), ego, traffic)
    write_mcap(tmp_path / "two.mcap", dict(meta, session_id=None), ego, traffic)
    ws = Workspace(tmp_path / "ws")
    ingest_paths([tmp_path], ws)
    cat = ws.recordings()
    assert cat["session_id"].tolist() == ["one", "two"]  # file stems
    assert cat["format"].tolist() == ["csv", "mcap"]
    assert pd.isna(cat["speed_limit_kph"].iloc[0]) and cat["speed_limit_kph"].iloc[1] == 80.0


@pytest.mark.parametrize("fmt", ["csv", "mcap"])
def test_a_recording_without_traffic(tmp_path, recording, fmt):
    meta, ego, traffic = recording
    path = tmp_path / f"empty_road.{fmt}"
    WRITERS[fmt](path, meta, ego, traffic.iloc[0:0])
    ws = Workspace(tmp_path / "ws")
    res = ingest_paths([path], ws).files[0]
    assert res.status == "ingested", res.reason
    got_meta, got_ego, got_traffic = ws.load_recording(res.recording_id)
    assert got_meta["n_vehicles"] == 0 and len(got_ego) == 200 and got_traffic.empty
    assert list(got_traffic.columns)[:3] == ["t_s", "vehicle_id", "x_m"]
