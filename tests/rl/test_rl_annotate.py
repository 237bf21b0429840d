"""`laneprint annotate`: the recording written again with the decisions, valid MCAP that ingests as before."""

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.workspace import Workspace
from rl.deploy.annotate import SCHEMAS, TOPIC_AGENT, TOPIC_DRIVER, TOPIC_GREEDY, TOPIC_SCENE, target_lanes

SAMPLE = Path(__file__).resolve().parents[2] / "sample_logs" / "D01_S60.mcap"


def ingest(path: Path, root: Path) -> dict:
    res = CliRunner().invoke(app, ["ingest", str(path), "-w", str(root), "--json"])
    assert res.exit_code == 0, res.output
    ws = Workspace(root)
    return ws.recordings().iloc[-1].to_dict()


def read_all(path: Path) -> tuple[dict[str, list[dict]], dict[str, str], dict[str, dict]]:
    """Every message by topic (JSON-decoded) with CRCs checked, each topic's schema encoding, the metadata."""
    by_topic: dict[str, list[dict]] = {}
    encodings = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        for schema, channel, msg in reader.iter_messages(log_time_order=True):
            encodings[channel.topic] = f"{schema.encoding}/{channel.message_encoding}"
            body = json.loads(msg.data)
            if channel.topic.startswith("/laneprint/"):
                assert msg.log_time == round(body["t_s"] * 1e9)
            by_topic.setdefault(channel.topic, []).append(body)
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return by_topic, encodings, metadata


@pytest.mark.slow
def test_annotated_log_is_valid_mcap_and_ingests_like_the_original(trained_run, tmp_path):
    ws, run_id = trained_run
    original = ingest(SAMPLE, ws.root)
    out = tmp_path / "annotated.mcap"
    res = CliRunner().invoke(
        app, ["annotate", run_id, original["session_id"], "--out", str(out), "-w", str(ws.root), "--json"]
    )
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["recording_id"] == original["recording_id"]

    msgs, encodings, metadata = read_all(out)
    n = summary["steps"]
    assert n == int(np.floor(original["duration_s"] / 0.5 + 1e-9)) + 1
    assert {t: len(msgs[t]) for t in SCHEMAS} == dict.fromkeys(SCHEMAS, n)
    assert all(encodings[t] == "jsonschema/json" for t in SCHEMAS)
    assert metadata["session"]["driver_id"] == original["driver_id"]
    assert metadata["laneprint_annotation"]["run_id"] == run_id

    # the rule for steps without a leader: no decision, no numbers
    status = Counter(m["status"] for m in msgs[TOPIC_AGENT])
    assert (
        status["ok"] > 0
        and status["no_leader"] > 0
        and status == {k: v for k, v in summary["steps_by_status"].items() if v}
    )
    for agent, greedy, scene in zip(msgs[TOPIC_AGENT], msgs[TOPIC_GREEDY], msgs[TOPIC_SCENE]):
        assert agent["status"] == greedy["status"] == scene["status"]
        if agent["status"] == "ok":
            assert agent["decision"] == ("change" if agent["q_change"] >= agent["q_keep"] else "keep")
            assert agent["action"] == (0 if agent["decision"] == "change" else 1)
            assert greedy["decision"] == ("change" if greedy["r_change"] > greedy["r_keep"] else "keep")
            assert scene["f_id"] and scene["target_lane"] == 1 - scene["ego_lane"]  # two lanes
        else:
            assert agent["decision"] == greedy["decision"] == "none"
            assert not {"action", "q_change", "q_keep", "q_margin"} & set(agent)
            assert "t_f" not in scene  # a leader beyond the sensing range may be named (f_id), never measured
    presses = [m for m in msgs[TOPIC_DRIVER] if m["decision"] == "change"]
    assert len(presses) == original["n_presses"] == summary["presses"]
    assert all(0 <= m["t_s"] - m["press_t_s"] < 0.5 for m in presses)

    # round trip: the annotated file ingests like the original (extra channels ignored)
    again = ingest(out, tmp_path / "ws2")
    for key in ("driver_id", "session_id", "speed_limit_kph", "n_samples", "n_presses", "n_vehicles", "duration_s"):
        assert again[key] == original[key], key
    _, ego0, traffic0 = ws.load_recording(original["recording_id"])
    _, ego1, traffic1 = Workspace(tmp_path / "ws2").load_recording(again["recording_id"])
    pd.testing.assert_frame_equal(ego1[ego0.columns], ego0, check_exact=False, atol=1e-9)
    pd.testing.assert_frame_equal(traffic1, traffic0, check_exact=False, atol=1e-9)


def test_target_lane_rule():
    assert target_lanes(np.array([0, 1, 1, 2, 0]), top_lane=2).tolist() == [1, 2, 2, 1, 1]
    assert target_lanes(np.array([0]), top_lane=0).tolist() == [-1]


def test_annotate_refuses_bad_input(trained_run, tmp_path):
    ws, run_id = trained_run
    runner = CliRunner()
    res = runner.invoke(app, ["annotate", run_id, "nope", "--out", str(tmp_path / "a.mcap"), "-w", str(ws.root)])
    assert res.exit_code == 1 and "no recording 'nope'" in res.output
    res = runner.invoke(app, ["annotate", run_id, "x", "--out", str(tmp_path / "a.json"), "-w", str(ws.root)])
    assert res.exit_code == 1 and "ending in .mcap" in res.output
    res = runner.invoke(app, ["annotate", "nope", "x", "--out", str(tmp_path / "a.mcap"), "-w", str(ws.root)])
    assert res.exit_code == 1 and "no run 'nope'" in res.output
