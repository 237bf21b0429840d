"""The worked examples of ingest/README.md: a drive logged by a ROS 2 stack and by a protobuf stack.

`write_ros2` and `write_protobuf` write a recording (the canonical EGO / TRAFFIC frames)
as such a stack would, with the libraries' own writers (`mcap_ros2.writer.Writer` from
message definitions, `mcap_protobuf.writer.Writer` from protobuf classes);
`ROS2_MAPPING` and `PROTOBUF_MAPPING` are the mapping files that read them back.
Used by the tests and by `benchmarks/ingest_stacks.py`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2
from mcap_protobuf.writer import Writer as ProtobufWriter
from mcap_ros2.writer import Writer as Ros2Writer

T0_NS = 1_700_000_000_000_000_000  # log_time of the first sample

# ---- ROS 2 -------------------------------------------------------------------------------------------

# ROS 2 message definitions: each type's own text, by name
ROS2_DEFS = {
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "geometry_msgs/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/Pose": "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance\n",
    "geometry_msgs/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "sim_msgs/Object": "string id\ngeometry_msgs/Point position\nfloat64 speed\nuint8 lane\nfloat64 length\n",
}


def msgdef(own: str, deps: list[str], defs: dict[str, str] = ROS2_DEFS) -> str:
    """A schema as rosbag2 stores it: the type's own definition, then each dependency after a ==== line."""
    return own + "".join(f"{'=' * 80}\nMSG: {name}\n{defs[name]}" for name in deps)


ODOMETRY_MSGDEF = msgdef(
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
    "geometry_msgs/TwistWithCovariance twist\n",
    [
        "std_msgs/Header",
        "builtin_interfaces/Time",
        "geometry_msgs/PoseWithCovariance",
        "geometry_msgs/Pose",
        "geometry_msgs/Point",
        "geometry_msgs/Quaternion",
        "geometry_msgs/TwistWithCovariance",
        "geometry_msgs/Twist",
        "geometry_msgs/Vector3",
    ],
)
OBJECT_ARRAY_MSGDEF = msgdef(
    "std_msgs/Header header\nsim_msgs/Object[] objects\n",
    ["std_msgs/Header", "builtin_interfaces/Time", "sim_msgs/Object", "geometry_msgs/Point"],
)

ROS2_MAPPING = """\
[mcap.signals]
time = "log_time"
ego_x = { topic = "/odom", path = "pose.pose.position.x" }
ego_y = { topic = "/odom", path = "pose.pose.position.y" }
ego_v = { topic = "/odom", path = "twist.twist.linear.x" }
ego_lane = { topic = "/localization/lane", path = "data" }
steer = { topic = "/vehicle/steering_angle", path = "data" }
lc_button = { topic = "/hmi/lane_change_button", path = "data" }
lc_direction = { topic = "/hmi/lane_change_direction", path = "data", left = 1, right = -1 }

[mcap.signals.traffic]
topic = "/perception/objects"
list = "objects"
id = "id"
x = "position.x"
y = "position.y"
v = "speed"
lane = "lane"
length = "length"
"""


def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def write_ros2(path: Any, meta: dict, ego: pd.DataFrame, traffic: pd.DataFrame) -> None:
    """A recording as a ROS 2 stack would log it (odometry, lane, steering, objects, HMI), on log_time."""
    by_t = {t: g for t, g in traffic.groupby("t_s")}
    with open(path, "wb") as fh:
        w = Ros2Writer(fh)
        odom = w.register_msgdef("nav_msgs/msg/Odometry", ODOMETRY_MSGDEF)
        objects = w.register_msgdef("sim_msgs/msg/ObjectArray", OBJECT_ARRAY_MSGDEF)
        int32 = w.register_msgdef("std_msgs/msg/Int32", "int32 data\n")
        float64 = w.register_msgdef("std_msgs/msg/Float64", "float64 data\n")
        boolean = w.register_msgdef("std_msgs/msg/Bool", "bool data\n")
        int8 = w.register_msgdef("std_msgs/msg/Int8", "int8 data\n")
        w.add_metadata("session", {k: str(v) for k, v in meta.items()})
        pressed = False
        for i, row in enumerate(ego.itertuples()):
            t = T0_NS + round(row.t_s * 1e9)
            header = {"stamp": _stamp(t), "frame_id": "map"}
            w.write_message(
                "/odom",
                odom,
                {
                    "header": header,
                    "child_frame_id": "base_link",
                    "pose": {
                        "pose": {"position": {"x": row.ego_x_m, "y": row.ego_y_m, "z": 0.0}, "orientation": {"w": 1.0}},
                        "covariance": [0.0] * 36,
                    },
                    "twist": {
                        "twist": {
                            "linear": {"x": row.ego_v_mps, "y": 0.0, "z": 0.0},
                            "angular": {"x": 0.0, "y": 0.0, "z": 0.0},
                        },
                        "covariance": [0.0] * 36,
                    },
                },
                log_time=t,
            )
            if i % 5 == 0:  # the lane at 10 Hz
                w.write_message("/localization/lane", int32, {"data": int(row.ego_lane)}, log_time=t)
            w.write_message("/vehicle/steering_angle", float64, {"data": row.steer_rad}, log_time=t)
            cars = by_t.get(row.t_s)
            w.write_message(
                "/perception/objects",
                objects,
                {
                    "header": header,
                    "objects": []
                    if cars is None
                    else [
                        {
                            "id": c.vehicle_id,
                            "position": {"x": c.x_m, "y": np.nan if c.y_m is None else c.y_m, "z": 0.0},
                            "speed": c.v_mps,
                            "lane": int(c.lane),
                            "length": c.length_m,
                        }
                        for c in cars.itertuples()
                    ],
                },
                log_time=t,
            )
            if bool(row.lc_button) != pressed:  # the HMI publishes the button on every change
                pressed = bool(row.lc_button)
                if pressed:
                    w.write_message(
                        "/hmi/lane_change_direction",
                        int8,
                        {"data": 1 if row.lc_direction == "left" else -1},
                        log_time=t,
                    )
                w.write_message("/hmi/lane_change_button", boolean, {"data": pressed}, log_time=t)
        w.finish()


# ---- protobuf ----------------------------------------------------------------------------------------

_F = descriptor_pb2.FieldDescriptorProto


def _message(name: str, fields: list[tuple[str, int, str]]) -> descriptor_pb2.DescriptorProto:
    """A message type; a field is (name, type, message type name for TYPE_MESSAGE/TYPE_ENUM or '')."""
    msg = descriptor_pb2.DescriptorProto(name=name)
    for number, (fname, ftype, type_name) in enumerate(fields, start=1):
        label = _F.LABEL_REPEATED if fname == "objects" else _F.LABEL_OPTIONAL
        field = msg.field.add(name=fname, number=number, type=ftype, label=label)
        if type_name:
            field.type_name = type_name
    return msg


def protobuf_classes() -> dict[str, type]:
    """sim.EgoState, sim.ObjectList, sim.LaneChangeButton (the .proto of ingest/README.md), built at run time."""
    fd = descriptor_pb2.FileDescriptorProto(
        name="sim/driving.proto", package="sim", syntax="proto3", dependency=["google/protobuf/timestamp.proto"]
    )
    ts = ("stamp", _F.TYPE_MESSAGE, ".google.protobuf.Timestamp")
    d = _F.TYPE_DOUBLE
    fd.message_type.append(
        _message(
            "EgoState",
            [ts, ("x", d, ""), ("y", d, ""), ("speed_kph", d, ""), ("lane", _F.TYPE_INT32, ""), ("steer", d, "")],
        )
    )
    objects = _message("ObjectList", [ts, ("objects", _F.TYPE_MESSAGE, ".sim.ObjectList.Object")])
    objects.nested_type.append(
        _message(
            "Object",
            [
                ("track_id", _F.TYPE_UINT32, ""),
                ("x", d, ""),
                ("y", d, ""),
                ("speed_kph", d, ""),
                ("lane", _F.TYPE_INT32, ""),
                ("length", d, ""),
            ],
        )
    )
    fd.message_type.append(objects)
    button = _message(
        "LaneChangeButton",
        [ts, ("pressed", _F.TYPE_BOOL, ""), ("direction", _F.TYPE_ENUM, ".sim.LaneChangeButton.Direction")],
    )
    button.enum_type.add(name="Direction").value.extend(
        descriptor_pb2.EnumValueDescriptorProto(name=n, number=i) for i, n in enumerate(("NONE", "LEFT", "RIGHT"))
    )
    fd.message_type.append(button)
    pool = descriptor_pool.DescriptorPool()
    pool.AddSerializedFile(timestamp_pb2.DESCRIPTOR.serialized_pb)
    pool.Add(fd)
    return message_factory.GetMessageClassesForFiles([fd.name], pool)


PROTOBUF_MAPPING = """\
[mcap]
metadata_name = "trial"
[mcap.metadata_keys]
driver_id = "participant"

[mcap.signals]
time = "stamp"
ego_x = { topic = "/ego", path = "x" }
ego_y = { topic = "/ego", path = "y" }
ego_v = { topic = "/ego", path = "speed_kph" }
ego_lane = { topic = "/ego", path = "lane" }
steer = { topic = "/ego", path = "steer" }
lc_button = { topic = "/hmi/lane_change", path = "pressed" }
lc_direction = { topic = "/hmi/lane_change", path = "direction", left = 1, right = 2 }

[mcap.signals.traffic]
topic = "/objects"
list = "objects"
id = "track_id"
x = "x"
y = "y"
v = "speed_kph"
lane = "lane"
length = "length"

[units]
speed = "km/h"
"""

STAMP0_NS = 100_000_000_000  # simulation time of the first sample: 100 s


def write_protobuf(path: Any, meta: dict, ego: pd.DataFrame, traffic: pd.DataFrame, seed: int = 0) -> dict[str, int]:
    """A recording as protobuf messages stamped with simulation time; log_time is a wall clock with
    a recorder delay of 0-4 ms (random, from `seed`), so only the stamps give the exact sample times.

    Vehicles get numeric track ids 1, 2, ... in order of appearance; returns vehicle id -> track id.
    """
    track_ids = {vid: k for k, vid in enumerate(pd.unique(traffic["vehicle_id"]), start=1)}
    classes = protobuf_classes()
    ego_cls, list_cls, button_cls = (classes[f"sim.{n}"] for n in ("EgoState", "ObjectList", "LaneChangeButton"))
    rng = np.random.default_rng(seed)
    by_t = {t: g for t, g in traffic.groupby("t_s")}

    def stamp(ns: int) -> dict:  # a google.protobuf.Timestamp of the classes' own pool
        return {"seconds": ns // 1_000_000_000, "nanos": ns % 1_000_000_000}

    with open(path, "wb") as fh:
        w = ProtobufWriter(fh)
        w.add_metadata("trial", {"participant": meta["driver_id"], "session_id": meta["session_id"]})
        pressed = False
        for row in ego.itertuples():
            sim_ns = STAMP0_NS + round(row.t_s * 1e9)
            log_ns = T0_NS + round(row.t_s * 1e9) + int(rng.integers(0, 4_000_000))  # recorder delay up to 4 ms
            w.write_message(
                "/ego",
                ego_cls(
                    stamp=stamp(sim_ns),
                    x=row.ego_x_m,
                    y=row.ego_y_m,
                    speed_kph=row.ego_v_mps * 3.6,
                    lane=int(row.ego_lane),
                    steer=row.steer_rad,
                ),
                log_time=log_ns,
                publish_time=log_ns,
            )
            msg = list_cls(stamp=stamp(sim_ns))
            for c in by_t[row.t_s].itertuples() if row.t_s in by_t else ():
                msg.objects.add(
                    track_id=track_ids[c.vehicle_id],
                    x=c.x_m,
                    y=np.nan if c.y_m is None else c.y_m,
                    speed_kph=c.v_mps * 3.6,
                    lane=int(c.lane),
                    length=c.length_m,
                )
            w.write_message("/objects", msg, log_time=log_ns, publish_time=log_ns)
            if bool(row.lc_button) != pressed:
                pressed = bool(row.lc_button)
                direction = {"left": 1, "right": 2}.get(row.lc_direction, 0) if pressed else 0
                w.write_message(
                    "/hmi/lane_change",
                    button_cls(stamp=stamp(sim_ns), pressed=pressed, direction=direction),
                    log_time=log_ns,
                    publish_time=log_ns,
                )
        w.finish()
    return track_ids
