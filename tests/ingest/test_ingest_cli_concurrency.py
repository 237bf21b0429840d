"""The `laneprint ingest` command on a folder of broken files, and two ingests racing."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ingest.writers import write_csv, write_mcap
from laneprint.app.cli import app
from laneprint.workspace import Workspace


def _broken_folder(root: Path, recording) -> Path:
    meta, ego, traffic = recording
    logs = root / "broken"
    logs.mkdir()
    write_csv(logs / "good.csv", meta, ego, traffic)
    write_mcap(root / "full.mcap", dict(meta, session_id="cut"), ego, traffic)
    data = (root / "full.mcap").read_bytes()
    (logs / "cut.mcap").write_bytes(data[:700])
    (logs / "empty.csv").write_bytes(b"")
    (logs / "noise.mcap").write_bytes(b"hello, not an mcap")
    (logs / "nodriver.csv").write_text("t,ego_x,ego_v,ego_lane\n0,1,20,0\n0.1,3,20,0\n")
    (logs / "README.md").write_text("not a log")
    return logs


def test_cli_on_broken_files_names_each_problem_and_exits_0(tmp_path, recording):
    logs = _broken_folder(tmp_path, recording)
    runner = CliRunner()
    ws = str(tmp_path / "ws")
    human = runner.invoke(app, ["ingest", str(logs), "-w", ws])
    assert human.exit_code == 0, human.output
    assert "Traceback" not in human.output
    for name in ("good.csv", "cut.mcap", "empty.csv", "noise.mcap", "nodriver.csv"):
        assert name in human.output
    assert "1 ingested" in human.output and "4 rejected" in human.output and "1 skipped" in human.output

    as_json = runner.invoke(app, ["ingest", str(logs), "-w", ws, "--json"])
    assert as_json.exit_code == 0
    doc = json.loads(as_json.stdout)
    reasons = {Path(f["source"]).name: (f["status"], f["reason"]) for f in doc["files"]}
    assert reasons["good.csv"][0] == "duplicate"
    assert reasons["cut.mcap"][1].startswith("truncated MCAP: stream ended inside a record at byte")
    assert reasons["empty.csv"][1] == "empty file (0 bytes)"
    assert reasons["noise.mcap"][1].startswith("not an MCAP file")
    assert reasons["nodriver.csv"][1].startswith("no driver id")
    assert reasons["README.md"][0] == "skipped"


def test_cli_errors_are_one_line_with_exit_1(tmp_path):
    runner = CliRunner()
    missing = runner.invoke(app, ["ingest", str(tmp_path / "nope"), "-w", str(tmp_path / "ws")])
    assert missing.exit_code == 1 and "Traceback" not in missing.output
    assert "error: no such file or folder" in missing.output
    (tmp_path / "only").mkdir()
    (tmp_path / "only" / "notes.txt").write_text("x")
    empty = runner.invoke(app, ["ingest", str(tmp_path / "only"), "-w", str(tmp_path / "ws")])
    assert empty.exit_code == 1 and "no log files found" in empty.output
    (tmp_path / "m.toml").write_text("[nope]\n")
    bad_map = runner.invoke(app, ["ingest", str(tmp_path / "only"), "--mapping", str(tmp_path / "m.toml")])
    assert bad_map.exit_code == 1 and "mapping: unknown key(s) nope" in bad_map.output


_WORKER = textwrap.dedent("""
    import json, sys
    from pathlib import Path
    from ingest.pipeline import ingest_paths
    from laneprint.workspace import Workspace
    paths = [Path(p) for p in json.loads(sys.argv[2])]
    print(json.dumps(ingest_paths(paths, Workspace(sys.argv[1])).counts))
""")


@pytest.mark.slow
def test_two_ingests_at_once_store_each_session_once(tmp_path, recording):
    meta, ego, traffic = recording
    logs = tmp_path / "logs"
    logs.mkdir()
    paths = []
    for k in range(6):
        m = dict(meta, session_id=f"s{k}")
        write_csv(logs / f"s{k}.csv", m, ego, traffic)
        write_mcap(logs / f"s{k}.mcap", m, ego, traffic)
        paths += [logs / f"s{k}.csv", logs / f"s{k}.mcap"]
    ws = tmp_path / "ws"
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _WORKER, str(ws), json.dumps([str(p) for p in order])],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for order in (paths, paths[::-1])
    ]
    outs = [p.communicate(timeout=120) for p in procs]
    for (_out, err), p in zip(outs, procs):
        assert p.returncode == 0, err
    counts = [json.loads(out) for out, _ in outs]
    assert sum(c["ingested"] for c in counts) == 6
    assert all(c["ingested"] + c["duplicate"] == 12 and c["rejected"] == 0 for c in counts)
    cat = Workspace(ws).recordings()
    assert sorted(cat["session_id"]) == [f"s{k}" for k in range(6)]
    assert not [p for p in (ws / ".tmp").iterdir()]  # no half-written recording left behind
