"""MCAP logs of real stacks: ROS 2 (CDR, ros2msg) and protobuf files, read by `[mcap.signals]`.

The files are written by the libraries' own writers (`mcap_ros2.writer.Writer`,
`mcap_protobuf.writer.Writer`) from the conftest recording, ingested through the
`laneprint ingest PATH --mapping FILE` command, and compared with what was written.
The files and mappings are the worked examples of docs/your-own-study.md (`tests/support/stack_examples.py`).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.writer import Writer as McapWriter
from mcap_protobuf.schema import build_file_descriptor_set
from mcap_ros2.writer import Writer as Ros2Writer
from typer.testing import CliRunner

from ingest.mapping import load_mapping
from tests.support.stack_examples import (
    ODOMETRY_MSGDEF,
    PROTOBUF_MAPPING,
    ROS2_MAPPING,
    T0_NS,
    msgdef,
    protobuf_classes,
    write_protobuf,
    write_ros2,
)
from ingest.writers import write_mcap
from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.workspace import Workspace


# ---- helpers -----------------------------------------------------------------------------------------


def ingest_cli(tmp_path, log, mapping_text: str | None) -> dict:
    """Run `laneprint ingest LOG [--mapping FILE] --json` and return the one file's report."""
    args = ["ingest", str(log), "-w", str(tmp_path / "ws"), "--json"]
    if mapping_text is not None:
        (tmp_path / "map.toml").write_text(mapping_text)
        args += ["--mapping", str(tmp_path / "map.toml")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    (report,) = json.loads(result.stdout)["files"]
    return report


def assert_same_recording(tmp_path, report, recording, ids=None) -> None:
    """What was stored equals what was written (floats to 1e-9, ids through `ids`)."""
    assert report["status"] == "ingested", report["reason"]
    _, ego, traffic = recording
    assert (report["driver_id"], report["session_id"], report["n_samples"], report["n_presses"]) == (
        "D07",
        "D07_s80_01",
        200,
        2,
    )
    _, got_ego, got_traffic = Workspace(tmp_path / "ws").load_recording(report["recording_id"])
    np.testing.assert_allclose(got_ego["t_s"], ego["t_s"], rtol=0, atol=1e-9)
    for col in ("ego_x_m", "ego_y_m", "ego_v_mps", "steer_rad"):
        np.testing.assert_allclose(got_ego[col], ego[col], rtol=0, atol=1e-9, err_msg=col)
    np.testing.assert_array_equal(got_ego["ego_lane"], ego["ego_lane"])
    np.testing.assert_array_equal(got_ego["lc_button"], ego["lc_button"])
    assert got_ego["throttle"].isna().all() and got_ego["brake"].isna().all()  # not logged
    presses = got_ego.index[got_ego["lc_direction"].notna()]
    assert got_ego.loc[presses, "t_s"].round(6).tolist() == [1.0, 3.0]
    assert got_ego.loc[presses, "lc_direction"].tolist() == ["left", "right"]
    want = traffic.assign(vehicle_id=traffic["vehicle_id"].map(ids or (lambda v: v)).astype(str))
    want = want.sort_values(["t_s", "vehicle_id"], ignore_index=True)
    got = got_traffic.sort_values(["t_s", "vehicle_id"], ignore_index=True)
    assert len(got) == len(want) == 325
    assert got["vehicle_id"].tolist() == want["vehicle_id"].tolist()
    for col in ("t_s", "x_m", "v_mps", "length_m"):
        np.testing.assert_allclose(got[col], want[col].astype(float), rtol=0, atol=1e-9, err_msg=col)
    np.testing.assert_allclose(got["y_m"], want["y_m"].astype(float), rtol=0, atol=1e-9)  # NaN where absent
    np.testing.assert_array_equal(got["lane"], want["lane"])


# ---- the worked examples -----------------------------------------------------------------------------


def test_ros2_file_ingests_through_the_mapping(tmp_path, recording):
    log = tmp_path / "ros2_drive.mcap"
    write_ros2(log, *recording)
    plain = ingest_cli(tmp_path, log, None)
    assert plain["status"] == "rejected"
    assert plain["reason"].startswith(
        "missing required topic /ego/state (ego_x); topics in the file: /hmi/lane_change_button, "
    )
    report = ingest_cli(tmp_path, log, ROS2_MAPPING)
    assert_same_recording(tmp_path, report, recording)
    assert report["format"] == "mcap" and report["warnings"] == []


def test_protobuf_file_ingests_on_its_header_stamps(tmp_path, recording):
    log = tmp_path / "proto_drive.mcap"
    track_ids = write_protobuf(log, *recording)
    assert track_ids == {"a": 1, "b": 2, "c12": 3}
    report = ingest_cli(tmp_path, log, PROTOBUF_MAPPING)
    assert_same_recording(tmp_path, report, recording, ids=track_ids)
    # on log_time the recorder's jitter shows: same samples, other times
    (tmp_path / "b").mkdir()
    on_log_time = ingest_cli(tmp_path / "b", log, PROTOBUF_MAPPING.replace('time = "stamp"', 'time = "log_time"'))
    assert on_log_time["status"] == "ingested", on_log_time["reason"]
    _, ego, _ = Workspace(tmp_path / "b" / "ws").load_recording(on_log_time["recording_id"])
    assert len(ego) == 200 and np.abs(ego["t_s"] - recording[1]["t_s"]).max() > 1e-4


def test_lanes_from_y_for_a_stack_that_logs_none(tmp_path, recording):
    meta, ego, traffic = recording
    traffic = traffic.assign(y_m=traffic["y_m"].fillna(3.5))  # c12 in lane 1 (no y in the fixture)
    log = tmp_path / "ros2_no_lanes.mcap"
    write_ros2(log, meta, ego, traffic)
    mapping = (
        ROS2_MAPPING.replace('ego_lane = { topic = "/localization/lane", path = "data" }\n', "")
        .replace('lane = "lane"\n', "")
        .replace("[mcap.signals]\n", "[mcap.signals]\nlane_from_y = { width_m = 3.5, lane0_y_m = 0.0 }\n")
    )
    assert "ego_lane" not in mapping and 'lane = "lane"' not in mapping
    assert_same_recording(tmp_path, ingest_cli(tmp_path, log, mapping), (meta, ego, traffic))
    shifted = mapping.replace("lane0_y_m = 0.0", "lane0_y_m = 3.5")  # lane 0 one lane further left: ego in lane -1
    (tmp_path / "b").mkdir()
    report = ingest_cli(tmp_path / "b", log, shifted)
    assert report["reason"].startswith("lane_from_y of /odom.pose.pose.position.y at message 0 of /odom ")
    assert "-1 is outside the road (lanes 0..20)" in report["reason"]


def test_json_file_reads_through_signals_too(tmp_path, recording):
    log = tmp_path / "v1.mcap"
    write_mcap(log, *recording)
    report = ingest_cli(
        tmp_path,
        log,
        """\
[mcap.signals]
ego_x = { topic = "/ego/state", path = "x" }
ego_v = { topic = "/ego/state", path = "v" }
ego_lane = { topic = "/ego/state", path = "lane" }
lc_button = { topic = "/driver/lane_change_button", path = "pressed" }
[mcap.signals.traffic]
topic = "/traffic/vehicles"
list = "vehicles"
id = "id"
x = "x"
v = "v"
lane = "lane"
""",
    )
    assert report["status"] == "ingested", report["reason"]
    assert (report["n_samples"], report["n_presses"]) == (200, 2)


V1_MSGDEFS = {  # the v1 topics and fields of LOG_FORMAT.md as ROS 2 messages
    "/ego/state": ("laneprint_msgs/msg/EgoState", "float64 x\nfloat64 y\nfloat64 v\nint32 lane\nfloat64 length\n"),
    "/traffic/vehicles": (
        "laneprint_msgs/msg/Vehicles",
        msgdef(
            "laneprint_msgs/Vehicle[] vehicles\n",
            ["laneprint_msgs/Vehicle"],
            {"laneprint_msgs/Vehicle": "string id\nfloat64 x\nfloat64 y\nfloat64 v\nint32 lane\nfloat64 length\n"},
        ),
    ),
    "/driver/controls": ("laneprint_msgs/msg/Controls", "float64 steer\n"),
    "/driver/lane_change_button": ("laneprint_msgs/msg/LaneChangeButton", "bool pressed\nstring direction\n"),
}


def test_ros2_file_with_the_v1_topics_and_fields_needs_no_mapping(tmp_path, recording):
    meta, ego, traffic = recording
    log = tmp_path / "v1_ros2.mcap"
    with open(log, "wb") as fh:
        w = Ros2Writer(fh)
        schemas = {topic: w.register_msgdef(name, text) for topic, (name, text) in V1_MSGDEFS.items()}
        w.add_metadata("session", {k: str(v) for k, v in meta.items()})
        pressed = False
        for row in ego.itertuples():
            t = T0_NS + round(row.t_s * 1e9)
            w.write_message(
                "/ego/state",
                schemas["/ego/state"],
                {"x": row.ego_x_m, "y": row.ego_y_m, "v": row.ego_v_mps, "lane": int(row.ego_lane), "length": 4.5},
                log_time=t,
            )
            cars = traffic[traffic["t_s"] == row.t_s]
            w.write_message(
                "/traffic/vehicles",
                schemas["/traffic/vehicles"],
                {
                    "vehicles": [
                        {
                            "id": c.vehicle_id,
                            "x": c.x_m,
                            "y": c.y_m,
                            "v": c.v_mps,
                            "lane": int(c.lane),
                            "length": c.length_m,
                        }
                        for c in cars.itertuples()
                    ]
                },
                log_time=t,
            )
            w.write_message("/driver/controls", schemas["/driver/controls"], {"steer": row.steer_rad}, log_time=t)
            if bool(row.lc_button) != pressed:
                pressed = bool(row.lc_button)
                w.write_message(
                    "/driver/lane_change_button",
                    schemas["/driver/lane_change_button"],
                    {"pressed": pressed, "direction": row.lc_direction if pressed else ""},
                    log_time=t,
                )
        w.finish()
    assert_same_recording(tmp_path, ingest_cli(tmp_path, log, None), recording)


# ---- refusals ----------------------------------------------------------------------------------------


def _raw_file(
    path, message_encoding: str, schema_encoding: str, schema_name: str, schema_data: bytes, data: bytes
) -> None:
    """One /odom channel whose encodings the test chooses, plus an empty-schema traffic topic."""
    with open(path, "wb") as fh:
        w = McapWriter(fh)
        w.start(profile="ros2")
        sid = w.register_schema(schema_name, schema_encoding, schema_data)
        ch = w.register_channel("/odom", message_encoding, sid)
        w.add_message(ch, T0_NS, data, T0_NS)
        w.finish()


def _ego_pb():
    return protobuf_classes()["sim.EgoState"]


@pytest.mark.parametrize(
    "case, expected",
    [
        (
            "cdr+protobuf",
            "topic /odom: message encoding 'cdr' does not match its schema encoding 'protobuf' "
            "(sim.EgoState); cdr messages need a 'ros2msg' schema",
        ),
        (
            "protobuf+ros2msg",
            "topic /odom: message encoding 'protobuf' does not match its schema encoding 'ros2msg' "
            "(nav_msgs/msg/Odometry); protobuf messages need a 'protobuf' schema",
        ),
        ("garbled msgdef", "topic /odom: cannot read its ros2msg schema 'nav_msgs/msg/Odometry' for cdr messages ("),
        (
            "garbled descriptor set",
            "topic /odom: cannot read its protobuf schema 'sim.EgoState' for protobuf messages (",
        ),
        ("cdr without schema", "topic /odom: message encoding 'cdr' does not match its no schema; "),
    ],
)
def test_inconsistent_or_unreadable_schema_is_refused(tmp_path, case, expected):
    fds = build_file_descriptor_set(_ego_pb()).SerializeToString()
    msg = _ego_pb()(x=1.0).SerializeToString()
    args = {
        "cdr+protobuf": ("cdr", "protobuf", "sim.EgoState", fds, msg),
        "protobuf+ros2msg": ("protobuf", "ros2msg", "nav_msgs/msg/Odometry", ODOMETRY_MSGDEF.encode(), msg),
        "garbled msgdef": (
            "cdr",
            "ros2msg",
            "nav_msgs/msg/Odometry",
            ODOMETRY_MSGDEF.replace("float64 x", "flaot64[ x").encode(),
            b"\x00\x01\x00\x00",
        ),
        "garbled descriptor set": ("protobuf", "protobuf", "sim.EgoState", fds[: len(fds) // 2], msg),
        "cdr without schema": ("cdr", "", "", b"", b"\x00\x01\x00\x00"),
    }[case]
    log = tmp_path / "bad.mcap"
    if case == "cdr without schema":
        with open(log, "wb") as fh:
            w = McapWriter(fh)
            w.start()
            ch = w.register_channel("/odom", "cdr", 0)
            w.add_message(ch, T0_NS, args[4], T0_NS)
            w.finish()
    else:
        _raw_file(log, *args)
    report = ingest_cli(tmp_path, log, ROS2_MAPPING)
    assert report["status"] == "rejected"
    assert report["reason"].startswith(expected), report["reason"]
    assert "\n" not in report["reason"]


def test_undecodable_message_names_topic_index_and_encoding(tmp_path, recording):
    log = tmp_path / "cut.mcap"
    _raw_file(log, "cdr", "ros2msg", "nav_msgs/msg/Odometry", ODOMETRY_MSGDEF.encode(), b"\x00\x01\x00\x00\x07")
    report = ingest_cli(tmp_path, log, ROS2_MAPPING)
    assert report["reason"].startswith(
        "message 0 on /odom (log_time 1700000000000000000 ns) does not decode as cdr nav_msgs/msg/Odometry: "
    )


@pytest.fixture(scope="module")
def ros2_log(tmp_path_factory, module_recording):
    """One ROS 2 file shared by the bad-path cases (writing it takes ~1 s)."""
    log = tmp_path_factory.mktemp("ros2") / "ros2_drive.mcap"
    write_ros2(log, *module_recording)
    return log


@pytest.mark.parametrize(
    "old, new, expected",
    [
        (
            '"twist.twist.linear.x"',
            '"twist.twist.linar.x"',
            "topic /odom: no field 'twist.twist.linar.x' in its nav_msgs/msg/Odometry messages "
            "(fields at twist.twist: linear, angular); fix the path under [mcap.signals] in the --mapping file",
        ),
        (
            '"twist.twist.linear.x"',
            '"twist.twist.linear"',
            "topic /odom: field 'twist.twist.linear' holds a geometry_msgs/Vector3 message, not a number (message 0)",
        ),
        (
            '"twist.twist.linear.x"',
            '"twist.covariance"',
            "topic /odom: field 'twist.covariance' holds a list, not a number (message 0)",
        ),
        (
            'x = "position.x"',
            'x = "pos.x"',
            "topic /perception/objects: no field 'objects[].pos.x' in its sim_msgs/msg/ObjectArray messages "
            "(fields of objects[]: id, position, speed, lane, length)",
        ),
        (
            'list = "objects"',
            'list = "header"',
            "topic /perception/objects: list = 'header' holds a std_msgs/Header message, not a list of objects",
        ),
        (
            'time = "log_time"',
            'time = "header.stamp"',
            "topic /localization/lane: no field 'header.stamp' in its std_msgs/msg/Int32 messages (fields of the "
            "message: data)",
        ),
        (
            'topic = "/odom", path = "pose.pose.position.x"',
            'topic = "/odometry", path = "pose.pose.position.x"',
            "missing required topic /odometry (ego_x); topics in the file: /hmi/lane_change_button, ",
        ),
    ],
)
def test_bad_field_path_names_topic_and_path(tmp_path, ros2_log, old, new, expected):
    assert old in ROS2_MAPPING
    report = ingest_cli(tmp_path, ros2_log, ROS2_MAPPING.replace(old, new, 1))
    assert report["status"] == "rejected"
    assert report["reason"].startswith(expected), report["reason"]


@pytest.mark.parametrize(
    "text, message",
    [
        ('[mcap.signals]\nego_speed = { topic = "/odom", path = "v" }\n', "unknown key(s) ego_speed in [mcap.signals]"),
        (
            '[mcap.signals]\nego_x = { topic = "/odom", path = "x" }\n',
            "[mcap.signals] needs ego_v, ego_lane, traffic (the required signals)",
        ),
        ('[mcap.signals]\nego_x = "/odom.x"\n', "[mcap.signals] ego_x must be a table, e.g. ego_x = { topic = "),
        (
            '[mcap.topics]\n"/ego/state" = "/odom"\n' + ROS2_MAPPING.replace("[mcap.signals]\n", "[mcap.signals]\n", 1),
            "[mcap.signals] names every topic and field itself; drop [mcap.topics] / [mcap.fields]",
        ),
        (ROS2_MAPPING.replace('path = "data" }', 'path = "data..x" }', 1), "must be a field path like"),
        (ROS2_MAPPING.replace('list = "objects"\n', ""), "[mcap.signals.traffic] needs list"),
        (ROS2_MAPPING.replace('lane = "lane"\n', ""), "[mcap.signals.traffic] needs lane (lane: or y with lane_from_y"),
        ("[mcap.signals]\nlane_from_y = { width_m = 0 }\n", "lane_from_y must be { width_m = <lane width, m, > 0>"),
    ],
)
def test_bad_signals_table_is_one_user_error(tmp_path, text, message):
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(UserError) as err:
        load_mapping(tmp_path / "bad.toml")
    assert message in str(err.value)


def test_yaml_signals_read_like_toml(tmp_path):
    (tmp_path / "ros2.toml").write_text(ROS2_MAPPING)
    (tmp_path / "ros2.yaml").write_text("""\
mcap:
  signals:
    time: log_time
    ego_x: {topic: /odom, path: pose.pose.position.x}
    ego_y: {topic: /odom, path: pose.pose.position.y}
    ego_v: {topic: /odom, path: twist.twist.linear.x}
    ego_lane: {topic: /localization/lane, path: data}
    steer: {topic: /vehicle/steering_angle, path: data}
    lc_button: {topic: /hmi/lane_change_button, path: data}
    lc_direction: {topic: /hmi/lane_change_direction, path: data, left: 1, right: -1}
    traffic: {topic: /perception/objects, list: objects, id: id, x: position.x, y: position.y, v: speed,
              lane: lane, length: length}
""")
    toml, yaml = (load_mapping(tmp_path / name).mcap_signals for name in ("ros2.toml", "ros2.yaml"))
    assert toml == yaml and toml.topics()[:2] == ["/odom", "/localization/lane"]


# ---- ROS 2 decoders: rosbags, with mcap_ros2 behind it ---------------------------------------------------


def _parse_both(log, mapping_path, monkeypatch):
    """`parse_log` of one file as laneprint reads it, and with mcap_ros2's decoder alone."""
    from ingest import mcap_decoding
    from ingest.pipeline import ParseJob, parse_log

    job = ParseJob(log.read_bytes(), "mcap", log.stem, load_mapping(mapping_path), None)
    fast = parse_log(job)
    with monkeypatch.context() as m:
        m.setattr(
            mcap_decoding.FastRos2DecoderFactory,
            "decoder_for",
            lambda self, enc, schema: self.slow.decoder_for(enc, schema),
        )
        slow = parse_log(job)
    return fast, slow


def _assert_same(fast, slow) -> None:
    assert fast.reason == slow.reason
    if slow.rec is None:
        assert fast.rec is None
        return
    assert fast.rec.meta == slow.rec.meta and fast.rec.warnings == slow.rec.warnings
    assert fast.rec.ego.equals(slow.rec.ego) and fast.rec.traffic.equals(slow.rec.traffic)


def test_rosbags_decodes_cdr_as_mcap_ros2_does(tmp_path, ros2_log, monkeypatch):
    from mcap.records import Schema

    from ingest.mcap_decoding import FastRos2DecoderFactory

    schema = Schema(id=1, name="nav_msgs/msg/Odometry", encoding="ros2msg", data=ODOMETRY_MSGDEF.encode())
    assert getattr(FastRos2DecoderFactory().decoder_for("cdr", schema), "fast", False)  # rosbags reads it
    (tmp_path / "ros2.toml").write_text(ROS2_MAPPING)
    fast, slow = _parse_both(ros2_log, tmp_path / "ros2.toml", monkeypatch)
    assert fast.rec is not None and len(fast.rec.traffic) > 0
    _assert_same(fast, slow)
    # refusals: a field path to a message or an array, a list that is not one: mcap_ros2's reasons
    for old, new in (
        ('"twist.twist.linear.x"', '"twist.twist.linear"'),
        ('"twist.twist.linear.x"', '"twist.covariance"'),
        ('list = "objects"', 'list = "header"'),
        ('id = "id"', 'id = "position"'),
    ):
        (tmp_path / "bad.toml").write_text(ROS2_MAPPING.replace(old, new, 1))
        fast, slow = _parse_both(ros2_log, tmp_path / "bad.toml", monkeypatch)
        _assert_same(fast, slow)
