"""Logs as other tools leave them: Git LFS pointers, ROS 2 UUID object ids, lanes from y on a border."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from mcap_ros2.writer import Writer as Ros2Writer
from typer.testing import CliRunner

from ingest.mcap_signals import LaneFromY
from ingest.object_ids import id_text
from ingest.writers import write_csv, write_mcap
from laneprint.app.cli import app
from laneprint.workspace import Workspace


def ingest_cli(ws, paths, mapping=None) -> list[dict]:
    """`laneprint ingest PATHS -w WS --json [--mapping FILE]`: the per-file reports."""
    args = ["ingest", *map(str, paths), "-w", str(ws), "--json"] + (["--mapping", str(mapping)] if mapping else [])
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0 and "Traceback" not in result.output, result.output
    return json.loads(result.stdout)["files"]


# ---- Git LFS pointers ------------------------------------------------------------------------------


def test_lfs_pointer_is_refused_with_the_fetch_hint_and_the_batch_goes_on(tmp_path, recording):
    logs = tmp_path / "logs"
    logs.mkdir()
    write_csv(logs / "good.csv", *recording)
    pointer = (
        "version https://git-lfs.github.com/spec/v1\n"
        "oid sha256:358413d53e6fb2753efb3eac682bc9d776bb2afb1de5e395817efd8f16303fbc\nsize 20344\n"
    )
    for name in ("drive.mcap", "drive.csv.gz", "drive.csv"):
        (logs / name).write_text(pointer)
    reports = {r["source"].rsplit("/", 1)[-1]: r for r in ingest_cli(tmp_path / "ws", [logs])}
    assert reports["good.csv"]["status"] == "ingested"
    for name in ("drive.mcap", "drive.csv.gz", "drive.csv"):
        assert reports[name]["status"] == "rejected"
        assert reports[name]["reason"] == (
            "a Git LFS pointer, not the log itself (the real file of 20,344 bytes "
            "was not fetched): fetch it with `git lfs pull` in the repository it "
            "came from"
        )


# ---- ROS 2 UUIDs as object ids ---------------------------------------------------------------------

UUID_MSGDEF = (
    "sim_msgs/Object[] objects\n" + "=" * 80 + "\nMSG: sim_msgs/Object\n"
    "unique_identifier_msgs/UUID object_id\nfloat64 x\nfloat64 v\nuint8 lane\n"
    + "=" * 80
    + "\nMSG: unique_identifier_msgs/UUID\nuint8[16] uuid\n"
)
UUID_MAPPING = """\
[mcap.signals]
ego_x = {{ topic = "/ego", path = "x" }}
ego_v = {{ topic = "/ego", path = "v" }}
ego_lane = {{ topic = "/ego", path = "lane" }}
lc_button = {{ topic = "/ego", path = "pressed" }}
[mcap.signals.traffic]
topic = "/objects"
list = "objects"
id = "{id}"
x = "x"
v = "v"
lane = "lane"
"""


def uuid(name: str) -> bytes:
    return name.encode().ljust(16, b"\0")


def write_uuid_bag(path, recording) -> None:
    """A ROS 2 (CDR) file whose objects are identified by unique_identifier_msgs/UUID, as Autoware's are."""
    meta, ego, traffic = recording
    by_t = {t: g for t, g in traffic.groupby("t_s")}
    with open(path, "wb") as fh:
        w = Ros2Writer(fh)
        ego_schema = w.register_msgdef("sim_msgs/msg/Ego", "float64 x\nfloat64 v\nint32 lane\nbool pressed\n")
        objects = w.register_msgdef("sim_msgs/msg/Objects", UUID_MSGDEF)
        w.add_metadata("session", {k: str(v) for k, v in meta.items()})
        for row in ego.itertuples():
            t = round(row.t_s * 1e9)
            w.write_message(
                "/ego",
                ego_schema,
                {"x": row.ego_x_m, "v": row.ego_v_mps, "lane": int(row.ego_lane), "pressed": bool(row.lc_button)},
                log_time=t,
            )
            cars = by_t.get(row.t_s)
            w.write_message(
                "/objects",
                objects,
                {
                    "objects": []
                    if cars is None
                    else [
                        {"object_id": {"uuid": list(uuid(c.vehicle_id))}, "x": c.x_m, "v": c.v_mps, "lane": int(c.lane)}
                        for c in cars.itertuples()
                    ]
                },
                log_time=t,
            )
        w.finish()


@pytest.mark.parametrize("path", ["object_id", "object_id.uuid"])
def test_ros2_uuid_object_ids_are_stored_as_hex(tmp_path, recording, path):
    log = tmp_path / "uuid.mcap"
    write_uuid_bag(log, recording)
    (tmp_path / "map.toml").write_text(UUID_MAPPING.format(id=path))
    (report,) = ingest_cli(tmp_path / "ws", [log], tmp_path / "map.toml")
    assert report["status"] == "ingested", report["reason"]
    _, _, traffic = Workspace(tmp_path / "ws").load_recording(report["recording_id"])
    assert sorted(traffic["vehicle_id"].unique()) == sorted(uuid(v).hex() for v in ("a", "b", "c12"))
    assert (traffic["vehicle_id"] == "61000000000000000000000000000000").sum() == 125  # "a", 2.5 s at 50 Hz


@pytest.mark.parametrize(
    "value, text",
    [
        ("car7", "car7"),
        (7, "7"),
        (7.0, "7"),
        (7.5, "7.5"),
        (None, None),
        (b"V001" + bytes(12), "56303031000000000000000000000000"),
        ([1, 2, 255], "0102ff"),
        (SimpleNamespace(uuid=b"\x0a\x0b"), "0a0b"),
        (SimpleNamespace(data="car7"), "car7"),
        (SimpleNamespace(data=7), "7"),  # std_msgs/String, UInt32
        ({"uuid": [97, 0, 255]}, "6100ff"),
        ({"id": "car7"}, "car7"),  # JSON objects of one field
    ],
)
def test_object_id_text_is_canonical(value, text):
    if isinstance(value, SimpleNamespace):  # a decoded ROS 2 message of one field: one slot
        ((field, inner),) = vars(value).items()
        value = type("Msg", (SimpleNamespace,), {"__slots__": [field]})(**{field: inner})
    assert id_text(value) == text


# ---- lanes from y on a border ----------------------------------------------------------------------


def border_recording() -> tuple[dict, pd.DataFrame, pd.DataFrame]:
    """The ego and car "a" cross a lane border (3.5 m lanes) with one sample exactly on it (y = 1.75);
    car "b" starts on the border. Lanes as a simulator gives them: a lane is left once its border is crossed."""
    n, hz = 200, 50
    t = np.arange(n) / hz
    k = np.arange(n)
    ego_y = np.round(np.clip((k - 50) * 0.07, 0.0, 3.5), 3)  # left change from t=1 s; y = 1.75 at k = 75
    ego = pd.DataFrame(
        {
            "t_s": t,
            "ego_x_m": 100 + 25.0 * t,
            "ego_y_m": ego_y,
            "ego_v_mps": 25.0,
            "ego_lane": (ego_y > 1.75).astype(np.int64),
            "ego_length_m": 4.5,
            "steer_rad": 0.0,
            "throttle": 0.3,
            "brake": 0.0,
            "lc_button": (k >= 40) & (k < 45),
            "lc_direction": [("left" if i == 40 else None) for i in k],
        }
    )
    a_y = np.round(np.clip(3.5 - (k - 100) * 0.07, 0.0, 3.5), 3)  # right change from t=2 s; y = 1.75 at k = 125
    b_y = np.where(k < 10, 1.75, 3.5)
    traffic = pd.concat(
        [
            pd.DataFrame(
                {
                    "t_s": t,
                    "vehicle_id": "a",
                    "x_m": 150 + 22.0 * t,
                    "y_m": a_y,
                    "v_mps": 22.0,
                    "lane": (a_y >= 1.75).astype(np.int64),
                    "length_m": 4.5,
                }
            ),
            pd.DataFrame(
                {
                    "t_s": t,
                    "vehicle_id": "b",
                    "x_m": 60 + 27.0 * t,
                    "y_m": b_y,
                    "v_mps": 27.0,
                    "lane": 1,
                    "length_m": 4.5,
                }
            ),
        ]
    ).sort_values(["t_s", "vehicle_id"], ignore_index=True)
    meta = {"driver_id": "D07", "session_id": "border", "speed_limit_kph": 80, "simulator": "test rig"}
    return meta, ego, traffic


LANES_FROM_Y = """\
[mcap.signals]
lane_from_y = { width_m = 3.5, lane0_y_m = 0.0 }
ego_x = { topic = "/ego/state", path = "x" }
ego_y = { topic = "/ego/state", path = "y" }
ego_v = { topic = "/ego/state", path = "v" }
lc_button = { topic = "/driver/lane_change_button", path = "pressed" }
lc_direction = { topic = "/driver/lane_change_button", path = "direction" }
[mcap.signals.traffic]
topic = "/traffic/vehicles"
list = "vehicles"
id = "id"
x = "x"
y = "y"
v = "v"
"""


def test_lanes_from_y_agree_with_the_csv_lanes_on_a_border(tmp_path):
    meta, ego, traffic = border_recording()
    write_csv(tmp_path / "border.csv", meta, ego, traffic)
    write_mcap(tmp_path / "border.mcap", meta, ego, traffic)
    (tmp_path / "map.toml").write_text(LANES_FROM_Y)
    (from_csv,) = ingest_cli(tmp_path / "ws_csv", [tmp_path / "border.csv"])
    (from_y,) = ingest_cli(tmp_path / "ws_mcap", [tmp_path / "border.mcap"], tmp_path / "map.toml")
    assert from_csv["status"] == from_y["status"] == "ingested", (from_csv["reason"], from_y["reason"])
    _, ego_csv, tr_csv = Workspace(tmp_path / "ws_csv").load_recording(from_csv["recording_id"])
    _, ego_y, tr_y = Workspace(tmp_path / "ws_mcap").load_recording(from_y["recording_id"])
    assert ego_y["ego_lane"].tolist() == ego_csv["ego_lane"].tolist() == ego["ego_lane"].tolist()
    key = ["t_s", "vehicle_id"]
    tr_csv, tr_y = (tr.sort_values(key, ignore_index=True) for tr in (tr_csv, tr_y))
    assert tr_y["lane"].tolist() == tr_csv["lane"].tolist() == traffic["lane"].tolist()
    assert ego_y.loc[75, ["ego_y_m", "ego_lane"]].tolist() == [1.75, 0]  # on the border: still lane 0
    a = tr_y[tr_y["vehicle_id"] == "a"].reset_index(drop=True)
    assert a.loc[125, ["y_m", "lane"]].tolist() == [1.75, 1]  # on the border: still lane 1 (round half even: 0)


def test_lane_from_y_border_rule():
    lanes = LaneFromY(width_m=3.5).lanes
    assert lanes(np.array([0.0, 1.75, 3.5, 1.75, 0.0])).tolist() == [0, 0, 1, 1, 0]  # keeps the previous lane
    assert lanes(np.array([1.75, 1.75, 3.5])).tolist() == [1, 1, 1]  # a track starting on it: its next lane
    assert lanes(np.array([5.25, 5.25])).tolist() == [1, 1]  # never off it: the lower lane
    assert np.isnan(lanes(np.array([np.nan, 1.75])))[0]
    tracks = np.array([0, 1, 0, 1])  # two vehicles interleaved in time
    assert lanes(np.array([3.5, 0.0, 1.75, 1.75]), tracks).tolist() == [1, 0, 1, 0]
