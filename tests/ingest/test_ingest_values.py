"""Values, not only shapes: every signal against what it can physically be, with a reason naming it."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from ingest.mapping import IDENTITY
from ingest.pipeline import ingest_paths
from ingest.values import EGO_REQUIRED_SCHEMA, failures
from ingest.writers import write_csv, write_mcap
from laneprint.workspace import Workspace


def _ingest(tmp_path, name, write):
    """Write one log with `write(path)`, ingest it alone; (result, workspace)."""
    logs = tmp_path / "logs"
    logs.mkdir(exist_ok=True)
    write(logs / name)
    ws = Workspace(tmp_path / "ws")
    (res,) = ingest_paths([logs / name], ws).files
    if res.status == "rejected":
        assert ws.recordings().empty
    return res, ws


def _csv_cell(path, recording, column, line, value):
    """`recording` as CSV with one cell (by column name and 1-based file line) replaced."""
    write_csv(path, *recording)
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    row = lines[line - 1].split(",")
    row[header.index(column)] = value
    lines[line - 1] = ",".join(row)
    path.write_text("\n".join(lines) + "\n")


def test_infinite_ego_speed_in_the_middle_is_refused(tmp_path, recording):
    res, _ = _ingest(tmp_path, "inf.csv", lambda p: _csv_cell(p, recording, "ego_v", 102, "inf"))
    assert res.status == "rejected"
    assert res.reason == (
        "column 'ego_v' at line 102 (t=2.000 s): inf is not a finite number; fix or cut those samples before ingesting"
    )


def test_infinite_ego_speed_in_an_mcap_names_topic_field_and_message(tmp_path, recording):
    meta, ego, traffic = recording
    bad = ego.assign(ego_v_mps=ego["ego_v_mps"].where(ego.index != 100, np.inf))
    res, _ = _ingest(tmp_path, "inf.mcap", lambda p: write_mcap(p, meta, bad, traffic))
    assert res.reason.startswith(
        "/ego/state.v at message 100 of /ego/state (log_time 2000000000 ns) (t=2.000 s): inf is not a finite number"
    )


def test_text_in_a_required_column_names_the_column_and_line(tmp_path, recording):
    res, _ = _ingest(tmp_path, "abc.csv", lambda p: _csv_cell(p, recording, "ego_v", 102, "abc"))
    assert res.reason == "column 'ego_v' line 102: 'abc' is not a number; correct that value or remove the line"


def test_text_in_an_optional_column_is_emptied_with_a_warning(tmp_path, recording):
    res, ws = _ingest(tmp_path, "steer.csv", lambda p: _csv_cell(p, recording, "steer", 12, "off"))
    assert res.status == "warning"
    assert res.warnings[0] == "column 'steer': 1 value(s) are not numbers (first 'off' at line 12); left empty"
    ego = ws.load_recording(res.recording_id)[1]
    assert np.isnan(ego["steer_rad"][10]) and ego["steer_rad"].isna().sum() == 1


def test_text_in_a_traffic_column_drops_that_vehicle_sample(tmp_path, recording):
    res, ws = _ingest(tmp_path, "tv.csv", lambda p: _csv_cell(p, recording, "a_v", 5, "fast"))
    assert res.status == "warning"
    assert res.warnings[0] == (
        "column 'a_v': 1 value(s) are not numbers (first 'fast' at line 5); the vehicle is left out of those samples"
    )
    traffic = ws.load_recording(res.recording_id)[2]
    a = traffic[traffic["vehicle_id"] == "a"]
    assert len(a) == int((recording[2]["vehicle_id"] == "a").sum()) - 1
    assert 0.06 not in set(a["t_s"].round(3))


def test_impossible_optional_values_are_emptied_and_traffic_samples_dropped(tmp_path, recording):
    meta, ego, traffic = recording
    ego = ego.assign(
        ego_length_m=ego["ego_length_m"].where(ego.index != 7, -4.0),
        throttle=ego["throttle"].where(ego.index < 150, 35.0),
    )
    traffic = traffic.assign(v_mps=traffic["v_mps"].where(traffic.index != 3, np.inf))
    res, ws = _ingest(tmp_path, "odd.csv", lambda p: write_csv(p, meta, ego, traffic))
    assert res.status == "warning"
    assert res.warnings[:3] == [
        "column 'ego_length': 1 of 200 value(s) impossible (first -4 m is not a vehicle length (0..60 m) "
        "at line 9); 4.5 m is used there",
        "column 'throttle': 50 of 200 value(s) impossible (first 35 is beyond a pedal position 0-1 (0..1) "
        "at line 152); left empty",
        f"traffic: dropped 1 of {len(traffic)} vehicle sample(s) of 1 vehicle(s) with impossible values "
        "(first: vehicle 'a' v inf is not a finite number at t=0.060 s)",
    ]
    _, stored_ego, stored_traffic = ws.load_recording(res.recording_id)
    assert stored_ego["ego_length_m"][7] == 4.5 and stored_ego["throttle"].isna().sum() == 50
    assert len(stored_traffic) == len(traffic) - 1


def test_ego_jump_lane_outside_the_road_and_sample_rate_are_refused(tmp_path, recording):
    meta, ego, traffic = recording
    jump = ego.assign(ego_x_m=ego["ego_x_m"].where(ego.index != 60, 5000.0))
    res, _ = _ingest(tmp_path, "jump.csv", lambda p: write_csv(p, meta, jump, traffic))
    assert res.reason.startswith(
        "column 'ego_x' jumps 4870 m in 0.02 s at line 62 (t=1.200 s), further than "
        "its speed (25.1 m/s) allows; 2 such jumps; fix or cut those samples"
    )
    lane = ego.assign(ego_lane=ego["ego_lane"].where(ego.index != 30, 25))
    res, _ = _ingest(tmp_path, "lane.mcap", lambda p: write_mcap(p, meta, lane, traffic))
    assert res.reason.startswith("/ego/state.lane at message 30 of /ego/state")
    assert res.reason.endswith("25 is outside the road (lanes 0..20); fix or cut those samples before ingesting")
    fast = ego.assign(t_s=ego["t_s"] / 100)  # 5 kHz
    res, _ = _ingest(tmp_path, "khz.csv", lambda p: write_csv(p, meta, fast, traffic.assign(t_s=traffic["t_s"] / 100)))
    assert res.reason.startswith("sample rate 5e+03 Hz (median step 0.0002 s of t) is outside 1-1000 Hz")


def test_failures_reports_every_failing_row_of_every_column():
    df = pd.DataFrame(
        {"ego_x_m": [0.0, np.inf, 1.0, 2e7], "ego_v_mps": [1.0, 2.0, -50.0, 3.0], "ego_lane": [0.0, 1.5, 21.0, 2.0]}
    )
    bad = failures(df, EGO_REQUIRED_SCHEMA)
    assert {k: v.tolist() for k, v in bad.items()} == {"ego_x_m": [1, 3], "ego_v_mps": [2], "ego_lane": [1, 2]}
    assert failures(df.iloc[[0]], EGO_REQUIRED_SCHEMA) == {}
    assert IDENTITY.column("ego_v") == "ego_v"


def test_a_broken_time_stamp_far_from_the_others_is_refused(tmp_path, recording):
    # found by benchmarks/fuzz.py (seed 0, case 4636): t=-1e308 on the first line made every relative time equal
    res, _ = _ingest(tmp_path, "t.csv", lambda p: _csv_cell(p, recording, "t", 2, "-1e308"))
    assert res.reason == (
        "time 't' jumps 1e+308 s at line 3 (from -1e+308 to 0.02 s), more than 3600 s between two "
        "samples; fix or cut the sample with the broken time before ingesting"
    )


def _sorted_jumps(tr):
    """`_traffic_jumps` through its general path (rows sorted by vehicle), whatever the row layout."""
    from unittest import mock

    import ingest.values as values

    with mock.patch.object(values, "_vehicle_grid", return_value=0):
        return values._traffic_jumps(tr)


def test_traffic_jumps_on_a_vehicle_grid_equal_the_sorted_path():
    from ingest.values import _traffic_jumps, _vehicle_grid

    rng = np.random.default_rng(7)
    m, k = 200, 6
    t = np.repeat(np.arange(m) / 50, k)
    ids = np.tile(np.array([f"v{j}" for j in (3, 1, 4, 0, 5, 2)], dtype=object), m)
    v = np.tile(rng.uniform(10, 30, k), m)
    x = np.tile(rng.uniform(-100, 100, k), m) + t * v
    tr = {"t_s": t, "vehicle_id": ids, "x_m": x, "v_mps": v}
    assert _vehicle_grid(pa.array(ids), len(t)) == k
    assert _traffic_jumps(tr) == _sorted_jumps(tr) == []
    for rows in ([700], [5, 900, 901, 1190]):
        x_j = x.copy()
        x_j[rows] += 50.0
        got = _traffic_jumps({**tr, "x_m": x_j})
        assert got == _sorted_jumps({**tr, "x_m": x_j}) and len(got) == 1
    # v3 is the first vehicle seen; v2 jumps once (row 0 -> 1), v3, v1 and v4 out and back
    assert got[0] == (
        "traffic vehicle 'v3' jumps 50.45 m in 0.02 s at t=3.000 s, further than its speed allows "
        "(7 such jump(s) in 4 vehicle(s)); kept"
    )
    # not a grid: a vehicle missing from one sample, or one id twice in a sample
    assert _vehicle_grid(pa.array(np.delete(ids, 7)), len(t) - 1) == 0
    assert _vehicle_grid(pa.array(np.tile(["a", "b", "a"], 4)), 12) == 0


@pytest.mark.slow
def test_bounds_met_in_numpy_agree_with_pandera():
    from pandera.errors import SchemaErrors

    from ingest.values import EGO_OPTIONAL_SCHEMA, TRAFFIC_SCHEMA, _all_pass

    def pandera_passes(df, schema):
        try:
            schema.validate(df, lazy=True)
            return True
        except SchemaErrors:
            return False

    rng = np.random.default_rng(3)
    values = [
        0.0,
        np.nan,
        np.inf,
        -np.inf,
        -1e7,
        1e7 + 1,
        -10.0,
        -10.01,
        100.0,
        100.1,
        0.5,
        1.5,
        20.0,
        21.0,
        60.0,
        60.1,
        -0.0,
        4 * np.pi,
        -4 * np.pi - 1e-9,
    ]
    seen = set()
    for _ in range(100):
        for schema in (EGO_REQUIRED_SCHEMA, EGO_OPTIONAL_SCHEMA, TRAFFIC_SCHEMA):
            pool = values if rng.random() < 0.5 else [0.0, np.nan, 1.0, -0.0]  # half of the frames all inside
            df = pd.DataFrame({c: rng.choice(pool, 3) for c in schema.columns})
            ok = _all_pass(df, schema)
            assert ok == pandera_passes(df, schema), df
            seen.add(ok)
    assert seen == {True, False}
    ints = pd.DataFrame({"ego_x_m": [1], "ego_v_mps": [1.0], "ego_lane": [1.0]})  # not float: pandera decides
    assert not _all_pass(ints, EGO_REQUIRED_SCHEMA)


def test_a_csv_reader_s_vehicle_grid_warns_of_traffic_jumps_as_the_mcap_path_does(tmp_path, recording):
    from ingest.pipeline import read_log

    meta, ego, _ = recording
    t = ego["t_s"].to_numpy()
    n = len(t)
    traffic = pd.DataFrame(
        {
            "t_s": np.repeat(t, 2),
            "vehicle_id": np.tile(["a", "b"], n),
            "x_m": np.round(np.repeat(100 + 22 * t, 2) + np.tile([0.0, 40.0], n), 3),
            "y_m": np.tile([0.0, 3.5], n),
            "v_mps": 22.0,
            "lane": np.tile([0, 1], n),
            "length_m": 4.5,
        }
    )
    traffic.loc[2 * 50 + 1, "x_m"] += 50.0  # vehicle b jumps at sample 50 and back at 51
    write_csv(tmp_path / "grid.csv", meta, ego, traffic)
    assert read_log((tmp_path / "grid.csv").read_bytes(), "csv", IDENTITY).vehicle_grid == 2  # the reader knows it
    for bad_speed in (False, True):  # with an impossible sample dropped, the rows are no longer a grid
        tr = traffic.assign(v_mps=traffic["v_mps"].where(traffic.index != 20, 500.0)) if bad_speed else traffic
        results = []
        for ext, write in (("csv", write_csv), ("mcap", write_mcap)):
            (tmp_path / f"{ext}{bad_speed}").mkdir()
            results.append(_ingest(tmp_path / f"{ext}{bad_speed}", f"grid.{ext}", lambda p: write(p, meta, ego, tr))[0])
        c, m = results
        jumps = [w for w in c.warnings if "jumps" in w]
        assert jumps == [w for w in m.warnings if "jumps" in w]
        assert jumps == [
            "traffic vehicle 'b' jumps 50.44 m in 0.02 s at t=1.000 s, further than its speed allows "
            "(2 such jump(s) in 1 vehicle(s)); kept"
        ]
        assert any(w.startswith("traffic: dropped 1 of") for w in c.warnings) == bad_speed
