"""Every bad-input class: the file is refused with a precise reason, the rest of the batch lands."""

from __future__ import annotations

import gzip
import json
import os

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import IndexType, Writer

from ingest.pipeline import ingest_paths
from ingest.writers import write_csv, write_mcap
from laneprint.workspace import Workspace


def _batch(tmp_path, recording, bad_name, make_bad, **kwargs):
    """Write a good log and a bad one into one folder, ingest the folder, return (good, bad) results."""
    meta, ego, traffic = recording
    logs = tmp_path / "logs"
    logs.mkdir(exist_ok=True)
    write_csv(logs / "good.csv", dict(meta, session_id="good"), ego, traffic)
    make_bad(logs / bad_name)
    ws = Workspace(tmp_path / "ws")
    report = ingest_paths([logs], ws, **kwargs)
    by_name = {os.path.basename(f.source): f for f in report.files}
    good, bad = by_name["good.csv"], by_name[bad_name]
    assert good.status == "ingested", good.reason
    assert ws.has_recording(good.recording_id)
    if bad.status == "rejected":
        assert len(ws.recordings()) == 1  # nothing of the bad file was stored
        assert any(r == bad.reason for r in ws.rejected()["reason"])
    return good, bad


def _csv_text(tmp_path, recording, **meta_changes):
    meta, ego, traffic = recording
    p = tmp_path / "src.csv"
    write_csv(p, dict(meta, **meta_changes), ego, traffic)
    return p.read_text().splitlines()


def _write_lines(path, lines):
    path.write_text("\n".join(lines) + "\n")


def test_truncated_mcap(tmp_path, recording):
    def bad(p):
        write_mcap(tmp_path / "full.mcap", dict(recording[0], session_id="t"), *recording[1:])
        data = (tmp_path / "full.mcap").read_bytes()
        p.write_bytes(data[: len(data) // 2])

    _, res = _batch(tmp_path, recording, "cut.mcap", bad)
    assert res.status == "rejected"
    assert res.reason.startswith("truncated MCAP: stream ended inside a record at byte ")
    assert "mcap recover" in res.reason


def test_garbage_bytes_named_mcap(tmp_path, recording):
    rng = np.random.default_rng(0)
    _, res = _batch(tmp_path, recording, "noise.mcap", lambda p: p.write_bytes(rng.bytes(3000)))
    assert res.status == "rejected"
    assert res.reason == "not an MCAP file: it does not start with the MCAP magic bytes"


def test_empty_file(tmp_path, recording):
    _, res = _batch(tmp_path, recording, "empty.csv", lambda p: p.write_bytes(b""))
    assert (res.status, res.reason) == ("rejected", "empty file (0 bytes)")


def test_unknown_message_encoding(tmp_path, recording):
    def bad(p):
        with open(p, "wb") as fh:
            w = Writer(fh)
            w.start()
            sid = w.register_schema("Ego", "flatbuffer", b"\x00")
            ego = w.register_channel("/ego/state", "flatbuffer", sid)
            w.register_channel("/traffic/vehicles", "json", 0)
            w.add_message(ego, 0, b"\x08\x01", 0)
            w.finish()

    _, res = _batch(tmp_path, recording, "flat.mcap", bad)
    assert res.status == "rejected"
    assert res.reason.startswith(
        "unsupported message encoding 'flatbuffer' on topic /ego/state: laneprint decodes "
        "json, cdr (ROS 2, ros2msg schemas) and protobuf messages"
    )


def test_missing_required_column_names_the_mapping_key(tmp_path, recording):
    lines = _csv_text(tmp_path, recording, session_id="m")
    header = lines[0].split(",")
    header[header.index("ego_v")] = "speed"
    _, res = _batch(tmp_path, recording, "nov.csv", lambda p: _write_lines(p, [",".join(header)] + lines[1:]))
    assert res.status == "rejected"
    assert res.reason == (
        'missing required column(s) ego_v: name your column with ego_v = "<your column>" '
        "under [csv.columns] in a --mapping file"
    )


def test_missing_required_topic(tmp_path, recording):
    def bad(p):
        with open(p, "wb") as fh:
            w = Writer(fh)
            w.start()
            ego = w.register_channel("/ego/state", "json", 0)
            w.add_message(ego, 0, b'{"x":1,"v":20,"lane":0}', 0)
            w.finish()

    _, res = _batch(tmp_path, recording, "notraffic.mcap", bad)
    assert res.status == "rejected"
    assert res.reason.startswith(
        "missing required topic /traffic/vehicles; topics in the file: /ego/state; "
        'map it with "/traffic/vehicles" = "<your topic>" under [mcap.topics]'
    )


def test_time_not_increasing(tmp_path, recording):
    lines = _csv_text(tmp_path, recording, session_id="back")
    lines[11], lines[12] = lines[12], lines[11]  # data rows 10 and 11 (file lines 12 and 13)
    _, res = _batch(tmp_path, recording, "back.csv", lambda p: _write_lines(p, lines))
    assert res.status == "rejected"
    assert res.reason.startswith("time not strictly increasing at line 13: t=0.2 s after 0.22 s")


def test_duplicated_time(tmp_path, recording):
    lines = _csv_text(tmp_path, recording, session_id="dup")
    lines.insert(31, lines[31])
    _, res = _batch(tmp_path, recording, "dup.csv", lambda p: _write_lines(p, lines))
    assert res.status == "rejected"
    assert res.reason.startswith("duplicated time t=0.6 s at line 32 and line 33")


def test_gap_in_required_signal(tmp_path, recording):
    meta, ego, traffic = recording
    holed = ego.copy()
    holed.loc[50:59, "ego_v_mps"] = np.nan
    _, res = _batch(
        tmp_path, recording, "gap.csv", lambda p: write_csv(p, dict(meta, session_id="gap"), holed, traffic)
    )
    assert res.status == "rejected"
    assert res.reason.startswith(
        "gap in required signal ego_v: 10 empty value(s) from line 52 to line 61 (t=1.000-1.180 s)"
    )


def test_speeds_in_kmh(tmp_path, recording):
    meta, ego, traffic = recording
    kmh = ego.assign(ego_v_mps=ego["ego_v_mps"] * 3.6)
    _, res = _batch(
        tmp_path, recording, "kmh.mcap", lambda p: write_mcap(p, dict(meta, session_id="kmh"), kmh, traffic)
    )
    assert res.status == "rejected"
    assert res.reason.startswith("ego speed looks like km/h, not m/s (median 90.")
    assert 'set speed = "km/h" under [units]' in res.reason


def test_no_driver_id_then_driver_option(tmp_path, recording):
    meta, ego, traffic = recording
    make = lambda p: write_csv(p, dict(meta, driver_id=None, session_id="anon"), ego, traffic)  # noqa: E731
    _, res = _batch(tmp_path, recording, "anon.csv", make)
    assert res.status == "rejected"
    assert res.reason.startswith("no driver id:") and "--driver ID" in res.reason
    # the same file with --driver lands, and its rejection is forgotten
    ws = Workspace(tmp_path / "ws")
    again = ingest_paths([tmp_path / "logs" / "anon.csv"], ws, driver_id="P9")
    assert (again.files[0].status, again.files[0].driver_id) == ("ingested", "P9")
    assert ws.rejected().empty


def test_driver_option_does_not_override_a_files_own_id(tmp_path, recording):
    write_csv(tmp_path / "own.csv", *recording)
    res = ingest_paths([tmp_path / "own.csv"], Workspace(tmp_path / "ws"), driver_id="P9").files[0]
    assert (res.status, res.driver_id) == ("warning", "D07")
    assert res.warnings == ["file says driver 'D07'; --driver 'P9' ignored for it"]


def test_malformed_csv(tmp_path, recording):
    lines = _csv_text(tmp_path, recording, session_id="bad")
    lines[20] = lines[20] + ",1,2,3"
    _, res = _batch(tmp_path, recording, "ragged.csv", lambda p: _write_lines(p, lines))
    assert res.status == "rejected"
    assert res.reason == "malformed CSV: line 21 has 32 fields, the header has 29"


def test_not_gzip_and_binary_csv(tmp_path, recording):
    _, res = _batch(tmp_path, recording, "plain.csv.gz", lambda p: p.write_text("t,ego_x\n0,1\n"))
    assert res.reason.startswith("not gzip-compressed although the name ends in .gz")
    (tmp_path / "ws2").mkdir()
    bin_csv = tmp_path / "bin.csv"
    bin_csv.write_bytes(b"\x89MCAP0\r\n\x00\x01garbage")
    res2 = ingest_paths([bin_csv], Workspace(tmp_path / "ws2")).files[0]
    assert res2.reason == "not a text CSV file (binary byte at offset 8)"


def test_no_button_presses_is_kept_with_a_warning(tmp_path, recording):
    meta, ego, traffic = recording
    calm = ego.assign(lc_button=False, lc_direction=None)
    good, res = _batch(
        tmp_path, recording, "calm.mcap", lambda p: write_mcap(p, dict(meta, session_id="calm"), calm, traffic)
    )
    assert res.status == "warning" and res.n_presses == 0
    assert res.warnings == ["no lane-change button presses: the recording holds no decisions"]
    row = Workspace(tmp_path / "ws").recordings().set_index("session_id").loc["calm"]
    assert row["status"] == "warning" and row["warnings"].startswith("no lane-change button presses")


def _copy_mcap(src, dst, session: dict, **writer_options) -> None:
    """Re-write every message of `src` into `dst` with other writer options and session metadata."""
    with open(src, "rb") as fh, open(dst, "wb") as out:
        w = Writer(out, **writer_options)
        w.start()
        ids = {}
        for schema, channel, msg in make_reader(fh).iter_messages():
            if channel.topic not in ids:
                sid = w.register_schema(schema.name, schema.encoding, schema.data)
                ids[channel.topic] = w.register_channel(channel.topic, "json", sid)
            w.add_message(ids[channel.topic], msg.log_time, msg.data, msg.publish_time)
        w.add_metadata("session", session)
        w.finish()


def test_unindexed_mcap_is_read_by_streaming(tmp_path, recording):
    meta, ego, traffic = recording
    src = tmp_path / "src.mcap"
    write_mcap(src, meta, ego, traffic)
    with open(src, "rb") as fh:
        session = dict(next(iter(make_reader(fh).iter_metadata())).metadata, session_id="flat")

    def bad(p):  # the same messages without chunks, index or summary
        _copy_mcap(
            src,
            p,
            session,
            use_chunking=False,
            index_types=IndexType.NONE,
            repeat_channels=False,
            repeat_schemas=False,
            use_statistics=False,
            use_summary_offsets=False,
        )

    _, res = _batch(tmp_path, recording, "flat.mcap", bad)
    assert (res.status, res.session_id, res.n_samples, res.n_presses) == ("ingested", "flat", 200, 2)


def test_mcap_ending_without_footer_at_a_record_boundary(tmp_path, recording):
    meta, ego, traffic = recording

    def bad(p):
        with open(p, "wb") as out:
            w = Writer(out, use_chunking=False)
            w.start()
            ch = w.register_channel("/ego/state", "json", 0)
            w.add_message(ch, 0, b'{"x":1,"v":20,"lane":0}', 0)
        # no finish(): the recorder died

    _, res = _batch(tmp_path, recording, "unfinished.mcap", bad)
    assert res.status == "rejected"
    assert res.reason.startswith("truncated MCAP: the file ends after the last complete record (byte ")


def test_explicit_non_log_path_is_rejected_folder_extras_are_skipped(tmp_path, recording):
    logs = tmp_path / "logs"
    logs.mkdir()
    write_csv(logs / "a.csv", *recording)
    (logs / "README.md").write_text("notes")
    (logs / "ground_truth.json").write_text(json.dumps({}))
    ws = Workspace(tmp_path / "ws")
    report = ingest_paths([logs, logs / "README.md", tmp_path / "missing.csv"], ws)
    assert report.counts == {"ingested": 1, "warning": 0, "duplicate": 0, "rejected": 2, "skipped": 2}
    rejected = {os.path.basename(f.source): f.reason for f in report.files if f.status == "rejected"}
    assert rejected == {
        "README.md": "not a log file: expected a .csv, .csv.gz or .mcap name (got README.md)",
        "missing.csv": "no such file or folder",
    }


def test_nothing_exists_is_a_user_error(tmp_path):
    from laneprint.errors import UserError

    with pytest.raises(UserError, match="no such file or folder"):
        ingest_paths([tmp_path / "nope"], Workspace(tmp_path / "ws"))


def test_gzipped_csv_with_traffic_value_missing(tmp_path, recording):
    lines = _csv_text(tmp_path, recording, session_id="hole")
    header = lines[0].split(",")
    row = lines[5].split(",")
    row[header.index("a_v")] = ""
    lines[5] = ",".join(row)
    _, res = _batch(
        tmp_path, recording, "hole.csv.gz", lambda p: p.write_bytes(gzip.compress(("\n".join(lines) + "\n").encode()))
    )
    assert (
        res.reason
        == "traffic vehicle 'a': a_v is empty at line 6 while a_x is given (a present vehicle needs x, v and lane)"
    )


def test_mcap_traffic_lane_out_of_range_and_vehicle_without_id(tmp_path, recording):
    meta, ego, traffic = recording
    odd = traffic.assign(lane=traffic["lane"].where(traffic["vehicle_id"] != "b", 42))
    _, res = _batch(tmp_path, recording, "lane.mcap", lambda p: write_mcap(p, dict(meta, session_id="l"), ego, odd))
    n_b = int((traffic["vehicle_id"] == "b").sum())
    assert res.status == "warning"  # a traffic vehicle is optional: its impossible samples are dropped
    assert res.warnings[0] == (
        f"traffic: dropped {n_b} of {len(traffic)} vehicle sample(s) of 1 vehicle(s) with "
        f"impossible values (first: vehicle 'b' field 'lane' 42 is outside the road "
        f"(lanes 0..20) at t=1.000 s)"
    )
    stored = Workspace(tmp_path / "ws").load_recording(res.recording_id)[2]
    assert set(stored["vehicle_id"]) == {"a", "c12"}

    def no_id(p):
        with open(p, "wb") as fh:
            w = Writer(fh)
            w.start()
            e = w.register_channel("/ego/state", "json", 0)
            tr = w.register_channel("/traffic/vehicles", "json", 0)
            w.add_metadata("session", {"driver_id": "D1"})
            for i in range(3):
                w.add_message(e, i * 10**8, b'{"x":1,"v":20,"lane":0}', 0)
                w.add_message(tr, i * 10**8, b'{"vehicles":[{"x":5,"v":20,"lane":1}]}', 0)
            w.finish()

    (tmp_path / "two").mkdir()
    _, res = _batch(tmp_path / "two", recording, "noid.mcap", no_id)
    assert res.reason.startswith("/traffic/vehicles: a vehicle without 'id' in message 0 (log_time 0 ns)")


def test_mcap_invalid_json_names_the_message(tmp_path, recording):
    def bad(p):
        with open(p, "wb") as fh:
            w = Writer(fh)
            w.start()
            e = w.register_channel("/ego/state", "json", 0)
            w.register_channel("/traffic/vehicles", "json", 0)
            w.add_message(e, 0, b'{"x":1,"v":20,"lane":0}', 0)
            w.add_message(e, 10**8, b'{"x":1,"v":20,', 0)
            w.finish()

    _, res = _batch(tmp_path, recording, "badjson.mcap", bad)
    assert res.reason.startswith("message 1 on /ego/state (log_time 100000000 ns) is not valid JSON")


def test_csv_with_two_drivers_is_rejected_and_varying_limit_warns(tmp_path, recording):
    lines = _csv_text(tmp_path, recording, session_id="two")
    header = lines[0].split(",")
    i_drv, i_lim = header.index("driver_id"), header.index("speed_limit_kph")
    mixed = list(lines)
    row = mixed[100].split(",")
    row[i_drv] = "D08"
    mixed[100] = ",".join(row)
    _, res = _batch(tmp_path, recording, "two.csv", lambda p: _write_lines(p, mixed))
    assert res.reason == "driver_id column has several values (D07, D08): write one file per recording"

    limits = list(lines)
    for k in range(150, len(limits)):
        row = limits[k].split(",")
        row[i_lim] = "90"
        limits[k] = ",".join(row)
    (tmp_path / "b").mkdir()
    _, res2 = _batch(tmp_path / "b", recording, "limits.csv", lambda p: _write_lines(p, limits))
    assert res2.status == "warning"
    assert res2.warnings == ["speed_limit_kph changes within the file; the catalogue leaves it empty"]


def test_mcap_metadata_without_metadata_index_is_still_found(tmp_path, recording):
    meta, ego, traffic = recording
    src = tmp_path / "src.mcap"
    write_mcap(src, meta, ego, traffic)

    def rewrite(p):
        _copy_mcap(src, p, {"driver_id": "D33", "session_id": "noidx"}, index_types=IndexType.CHUNK | IndexType.MESSAGE)

    _, res = _batch(tmp_path, recording, "noidx.mcap", rewrite)
    assert (res.status, res.driver_id, res.session_id) == ("ingested", "D33", "noidx")


def test_time_in_milliseconds_is_refused_by_its_sample_rate(tmp_path, recording):
    meta, ego, traffic = recording
    ms = ego.assign(t_s=ego["t_s"] * 1000)
    _, res = _batch(
        tmp_path,
        recording,
        "ms.csv",
        lambda p: write_csv(p, dict(meta, session_id="ms"), ms, traffic.assign(t_s=traffic["t_s"] * 1000)),
    )
    assert res.status == "rejected"
    assert res.reason.startswith(
        'sample rate 0.05 Hz (median step 20 s of t) is outside 1-1000 Hz; if t is not in seconds, set time = "ms"'
    )


def test_positions_in_feet_warn_about_units(tmp_path, recording):
    meta, ego, traffic = recording
    ft = ego.assign(ego_x_m=ego["ego_x_m"] / 0.3048)
    _, res = _batch(tmp_path, recording, "ft.csv", lambda p: write_csv(p, dict(meta, session_id="ft"), ft, traffic))
    assert res.status == "warning"
    assert res.warnings[0].startswith("ego speed (median 25.1) is 0.305x the rate at which ego_x changes")
