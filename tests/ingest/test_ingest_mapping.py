"""Mapping files adapt logs with other column/topic/field names and units."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.writer import Writer

from ingest.mapping import load_mapping
from ingest.pipeline import ingest_paths
from laneprint.errors import UserError
from laneprint.workspace import Workspace

CSV_MAPPING = r"""
[csv.columns]
t = "Time_ms"
ego_x = "EgoPosX"
ego_v = "EgoSpeed"
ego_lane = "EgoLane"
driver_id = "Subject"
lc_button = "Blinker"

[csv.traffic]
pattern = '^veh(?P<id>\d+)\.(?P<field>pos|speed|lane)$'
[csv.traffic.fields]
x = "pos"
v = "speed"

[units]
speed = "km/h"
time = "ms"

[metadata]
speed_limit_kph = 70
simulator = "rig B"
"""

CSV_MAPPING_YAML = r"""
csv:
  columns: {t: Time_ms, ego_x: EgoPosX, ego_v: EgoSpeed, ego_lane: EgoLane, driver_id: Subject, lc_button: Blinker}
  traffic:
    pattern: '^veh(?P<id>\d+)\.(?P<field>pos|speed|lane)$'
    fields: {x: pos, v: speed}
units: {speed: km/h, time: ms}
metadata: {speed_limit_kph: 70, simulator: rig B}
"""

OTHER_CSV = """Time_ms,Subject,EgoPosX,EgoSpeed,EgoLane,Blinker,veh3.pos,veh3.speed,veh3.lane,notes
1000,P1,10.0,72.0,0,0,50.0,36.0,1,x
1100,P1,12.0,72.0,0,1,51.0,36.0,1,
1200,P1,14.0,72.0,0,1,,,,
1300,P1,16.0,72.0,1,0,,,,
"""


@pytest.mark.parametrize("name, text", [("map.toml", CSV_MAPPING), ("map.yaml", CSV_MAPPING_YAML)])
def test_csv_with_other_names_and_units(tmp_path, name, text):
    if name.endswith(".yaml"):
        pytest.importorskip("yaml")
    (tmp_path / "other.csv").write_text(OTHER_CSV)
    (tmp_path / name).write_text(text)
    ws = Workspace(tmp_path / "ws")
    plain = ingest_paths([tmp_path / "other.csv"], ws).files[0]
    assert plain.status == "rejected" and "missing required column(s) t, ego_x, ego_v, ego_lane" in plain.reason
    res = ingest_paths([tmp_path / "other.csv"], ws, mapping=tmp_path / name).files[0]
    assert res.status == "ingested", res.reason
    meta, ego, traffic = ws.load_recording(res.recording_id)
    assert (meta["driver_id"], meta["speed_limit_kph"], meta["simulator"], meta["n_presses"]) == (
        "P1",
        70.0,
        "rig B",
        1,
    )
    np.testing.assert_allclose(ego["t_s"], [0.0, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(ego["ego_v_mps"], [20.0] * 4)
    assert ego["ego_lane"].tolist() == [0, 0, 0, 1]
    assert traffic["vehicle_id"].tolist() == ["3", "3"]
    np.testing.assert_allclose(traffic["v_mps"], [10.0, 10.0])
    np.testing.assert_allclose(traffic["x_m"], [50.0, 51.0])
    assert ws.rejected().empty  # the earlier rejection of the same bytes is forgotten


MCAP_MAPPING = """
[mcap]
metadata_name = "info"
[mcap.metadata_keys]
driver_id = "subject"
[mcap.topics]
"/ego/state" = "/vehicle/ego"
"/traffic/vehicles" = "/objects"
"/driver/lane_change_button" = "/hmi/lc"
[mcap.fields."/ego/state"]
x = "pos.x"
v = "speed"
lane = "lane_index"
[mcap.fields."/traffic/vehicles"]
vehicles = "objects"
id = "track_id"
x = "px"
[mcap.fields."/driver/lane_change_button"]
pressed = "active"
"""


def test_mcap_with_other_topics_and_fields(tmp_path):
    path = tmp_path / "other.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        ego = w.register_channel("/vehicle/ego", "json", 0)
        obj = w.register_channel("/objects", "json", 0)
        hmi = w.register_channel("/hmi/lc", "json", 0)
        w.add_metadata("info", {"subject": "S4"})
        for i in range(5):
            t = 5_000_000_000 + i * 20_000_000
            w.add_message(ego, t, json.dumps({"pos": {"x": 1.0 + 0.4 * i}, "speed": 20, "lane_index": 0}).encode(), t)
            w.add_message(
                obj, t, json.dumps({"objects": [{"track_id": 7, "px": 30.5, "v": 18.0, "lane": 1}]}).encode(), t
            )
        w.add_message(hmi, 5_040_000_000, b'{"active": true}', 0)
        w.add_message(hmi, 5_060_000_000, b'{"active": false}', 0)
        w.finish()
    (tmp_path / "m.toml").write_text(MCAP_MAPPING)
    ws = Workspace(tmp_path / "ws")
    res = ingest_paths([path], ws, mapping=tmp_path / "m.toml").files[0]
    assert res.status == "ingested", res.reason
    assert (res.driver_id, res.session_id, res.n_presses) == ("S4", "other", 1)
    _, ego_df, traffic = ws.load_recording(res.recording_id)
    np.testing.assert_allclose(ego_df["ego_x_m"], [1, 1.4, 1.8, 2.2, 2.6])
    assert ego_df["lc_button"].tolist() == [False, False, True, False, False]
    assert traffic["vehicle_id"].unique().tolist() == ["7"]
    np.testing.assert_allclose(traffic["t_s"], [0, 0.02, 0.04, 0.06, 0.08])


@pytest.mark.parametrize(
    "text, message",
    [
        ('[csv.columns]\nego_speed = "v"\n', "unknown key(s) ego_speed in [csv.columns]"),
        ('[units]\nspeed = "knots"\n', "[units] speed = 'knots' is not one of"),
        ('[csv.traffic]\npattern = "(?P<id>.+)"\n', "needs named groups"),
        ("[csv\n", "invalid TOML"),
    ],
)
def test_bad_mapping_is_one_user_error(tmp_path, text, message):
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(UserError) as err:
        load_mapping(tmp_path / "bad.toml")
    assert message in str(err.value)


def test_semicolon_csv_gets_a_hint_then_reads_with_a_delimiter(tmp_path):
    (tmp_path / "semi.csv").write_text(
        "\ufefft;driver_id;ego_x;ego_v;ego_lane;lc_button\r\n0;D1;1;20;0;0\r\n0.1;D1;3;20;0;1\r\n"
    )
    ws = Workspace(tmp_path / "ws")
    res = ingest_paths([tmp_path / "semi.csv"], ws).files[0]
    assert res.status == "rejected"
    assert res.reason.endswith('the file looks ;-separated; set delimiter = ";" under [csv] in a --mapping file')
    (tmp_path / "semi.toml").write_text('[csv]\ndelimiter = ";"\n')
    res = ingest_paths([tmp_path / "semi.csv"], ws, mapping=tmp_path / "semi.toml").files[0]
    assert (res.status, res.n_samples, res.n_presses) == ("ingested", 2, 1)
