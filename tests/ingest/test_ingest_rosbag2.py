"""Split rosbag2 folders (metadata.yaml + <name>_N.mcap parts) are ingested as one recording."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from typer.testing import CliRunner

from ingest.rosbag2 import read_bag_info
from ingest.writers import write_mcap
from laneprint.app.cli import app
from laneprint.workspace import Workspace

METADATA = """\
rosbag2_bagfile_information:
  version: 8
  storage_identifier: mcap
  duration:
    nanoseconds: {duration}
  starting_time:
    nanoseconds_since_epoch: {start}
  message_count: {count}
  relative_file_paths:
{files}
  compression_format: ""
  compression_mode: ""
"""


def write_split_bag(folder: Path, recording, cuts_s=(1.3, 2.6)) -> list[str]:
    """The recording as `ros2 bag record` splits it: parts cut at `cuts_s`, each with its own channel ids
    (registered in another order per part), the session metadata in the first part, and metadata.yaml."""
    folder.mkdir(parents=True)
    whole = folder.parent / "whole.mcap"
    write_mcap(whole, *recording)
    reader = make_reader(io.BytesIO(whole.read_bytes()))
    session = list(reader.iter_metadata())
    msgs = list(reader.iter_messages(log_time_order=True))
    edges = [0, *(round(c * 1e9) for c in cuts_s), 1 << 62]
    names = []
    for k in range(len(edges) - 1):
        names.append(f"drive_{k}.mcap")
        w = Writer(str(folder / names[-1]))
        w.start(profile="ros2", library="rosbag2")
        part = [m for m in msgs if edges[k] <= m[2].log_time < edges[k + 1]]
        topics = sorted({c.topic for _, c, _ in msgs}, reverse=k % 2 == 1)
        ids = {}
        for topic in topics:
            schema, channel = next((s, c) for s, c, _ in msgs if c.topic == topic)
            ids[topic] = w.register_channel(
                topic, channel.message_encoding, w.register_schema(schema.name, schema.encoding, schema.data)
            )
        if k == 0:
            for md in session:
                w.add_metadata(md.name, md.metadata)
        for _, channel, m in part:
            w.add_message(ids[channel.topic], m.log_time, m.data, m.publish_time)
        w.finish()
    times = [m.log_time for _, _, m in msgs]
    (folder / "metadata.yaml").write_text(
        METADATA.format(
            duration=max(times) - min(times),
            start=min(times),
            count=len(msgs),
            files="".join(f"    - {n}\n" for n in names),
        )
    )
    whole.unlink()
    return names


def ingest_cli(ws, *paths) -> list[dict]:
    result = CliRunner().invoke(app, ["ingest", *map(str, paths), "-w", str(ws), "--json"])
    assert result.exit_code == 0 and "Traceback" not in result.output, result.output
    return json.loads(result.stdout)["files"]


def test_split_bag_folder_is_one_recording_equal_to_the_single_file(tmp_path, recording):
    write_split_bag(tmp_path / "bag", recording)
    (tmp_path / "single").mkdir()
    write_mcap(tmp_path / "single" / "whole.mcap", *recording)
    (bag,) = ingest_cli(tmp_path / "ws", tmp_path / "bag")
    assert (bag["status"], bag["format"], bag["n_samples"], bag["n_presses"], bag["warnings"]) == (
        "ingested",
        "mcap",
        200,
        2,
        [],
    ), bag["reason"]
    assert Path(bag["source"]) == tmp_path / "bag" and bag["session_id"] == "D07_s80_01"
    (single,) = ingest_cli(tmp_path / "ws1", tmp_path / "single" / "whole.mcap")
    got = Workspace(tmp_path / "ws").load_recording(bag["recording_id"])
    want = Workspace(tmp_path / "ws1").load_recording(single["recording_id"])
    pd.testing.assert_frame_equal(got[1], want[1])
    pd.testing.assert_frame_equal(got[2], want[2])


def test_a_folder_holding_a_bag_lists_the_bag_once(tmp_path, recording):
    meta, ego, traffic = recording
    write_split_bag(tmp_path / "logs" / "bags" / "rosbag2_2026_01_01", (dict(meta, session_id=None), ego, traffic))
    write_mcap(tmp_path / "logs" / "other.mcap", dict(meta, session_id="other"), ego, traffic)
    reports = ingest_cli(tmp_path / "ws", tmp_path / "logs")
    assert [(Path(r["source"]).name, r["status"], r["session_id"]) for r in reports] == [
        ("rosbag2_2026_01_01", "ingested", "rosbag2_2026_01_01"),
        ("other.mcap", "ingested", "other"),
    ]


def test_a_missing_part_is_refused_naming_it(tmp_path, recording):
    write_split_bag(tmp_path / "bag", recording)
    (tmp_path / "bag" / "drive_1.mcap").unlink()
    (bag,) = ingest_cli(tmp_path / "ws", tmp_path / "bag")
    assert bag["status"] == "rejected"
    assert bag["reason"] == (
        "split rosbag2: drive_1.mcap listed in metadata.yaml is missing from the folder "
        "(2 of 3 parts present); fetch or copy every part"
    )


def test_a_part_cut_short_is_named_and_a_wrong_count_warns(tmp_path, recording):
    write_split_bag(tmp_path / "bag", recording)
    part = tmp_path / "bag" / "drive_2.mcap"
    part.write_bytes(part.read_bytes()[:300])
    (bag,) = ingest_cli(tmp_path / "ws", tmp_path / "bag")
    assert bag["reason"].startswith("split rosbag2 part drive_2.mcap: truncated MCAP: stream ended inside a record")
    write_split_bag(tmp_path / "bag2", recording)
    meta = tmp_path / "bag2" / "metadata.yaml"
    meta.write_text(meta.read_text().replace("message_count: ", "message_count: 1"))
    (bag2,) = ingest_cli(tmp_path / "ws", tmp_path / "bag2")
    assert bag2["status"] == "warning" and "a part may be cut short" in bag2["warnings"][0]


def test_parts_in_number_order_when_metadata_lists_none(tmp_path):
    (tmp_path / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  storage_identifier: mcap\n")
    for n in (0, 1, 2, 10):
        (tmp_path / f"b_{n}.mcap").write_bytes(b"")
    assert read_bag_info(tmp_path).files == ("b_0.mcap", "b_1.mcap", "b_2.mcap", "b_10.mcap")


@pytest.mark.parametrize(
    "line, reason",
    [
        ("storage_identifier: sqlite3", "rosbag2 storage 'sqlite3': laneprint reads MCAP storage"),
        ("compression_mode: file", "rosbag2 compression_mode 'file'"),
    ],
)
def test_bags_laneprint_cannot_read_say_so(tmp_path, line, reason):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "metadata.yaml").write_text(f"rosbag2_bagfile_information:\n  {line}\n")
    (bag,) = ingest_cli(tmp_path / "ws", tmp_path / "bag")
    assert bag["status"] == "rejected" and bag["reason"].startswith(reason)
