"""Fleets in the dashboard: the launch command, a launched fleet followed to its fleet.json, the
Training page's live panel and the Results page's fleet view (AppTest)."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest
from streamlit.testing.v1 import AppTest

from dashboard import jobs
from dashboard_support import page_path, write_fake_fleet
from laneprint.workspace import Workspace


def run_page(name: str) -> AppTest:
    at = AppTest.from_file(page_path(name), default_timeout=60).run()
    assert not at.exception, [e.value for e in at.exception]
    return at


@pytest.fixture
def copy_ws(sample_ws, tmp_path, monkeypatch):
    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    return ws


def test_fleet_command_line(tmp_path):
    cmd = jobs.fleet_command(jobs.FleetRequest("drivers", 400, seeds=3), tmp_path)
    assert cmd[:4] == [sys.executable, "-m", "laneprint.app.cli", "train"]
    assert cmd[4:] == ["--drivers", "all", "--seeds", "3", "--episodes", "400", "--workspace", str(tmp_path)]
    cmd = jobs.fleet_command(jobs.FleetRequest("styles", 10, names=("Normal", "Defensive"), backend="ray"), tmp_path)
    assert cmd[4:] == [
        "--styles",
        "Normal,Defensive",
        "--seeds",
        "1",
        "--episodes",
        "10",
        "--backend",
        "ray",
        "--workspace",
        str(tmp_path),
    ]
    with pytest.raises(ValueError):
        jobs.fleet_command(jobs.FleetRequest("driver", 10), tmp_path)


FAKE_TRAINER = """
import json, os, signal, sys, time
root = sys.argv[1]
def stop(*a):
    write("cancelled"); sys.exit(0)
def write(state):
    os.makedirs(os.path.join(root, "fleets", "fake"), exist_ok=True)
    tmp = os.path.join(root, "fleets", "fake", ".fleet.json")
    json.dump({"fleet_id": "fake", "created_at": "2026-11-30T12:00:00+00:00", "targets": [], "seeds": [0],
               "runs": [], "backend": "local", "state": state, "pid": os.getpid(), "message": state}, open(tmp, "w"))
    os.replace(tmp, os.path.join(root, "fleets", "fake", "fleet.json"))
signal.signal(signal.SIGTERM, stop)
time.sleep(0.5)
write("running")
time.sleep(60)
"""


def test_a_launched_fleet_is_found_by_its_pid_and_cancelled(tmp_path, monkeypatch):
    """A stand-in trainer (it writes fleet.json with its pid, as the fleet trainer does) launched as a job."""
    ws = Workspace(tmp_path / "ws").ensure()
    script = tmp_path / "laneprint_fake_fleet.py"
    script.write_text(FAKE_TRAINER)
    monkeypatch.setattr(jobs, "fleet_command", lambda req, root: [sys.executable, str(script), str(root)])
    job_id = jobs.launch_fleet(ws, jobs.FleetRequest("drivers", 10))
    try:
        assert jobs.fleet_job_status(ws, job_id)["state"] == "starting"
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and jobs.fleet_job_status(ws, job_id)["state"] == "starting":
            time.sleep(0.1)
        st = jobs.fleet_job_status(ws, job_id)
        assert (st["state"], st["fleet_id"]) == ("running", "fake")
        assert json.loads((jobs.fleet_jobs_dir(ws) / f"{job_id}.json").read_text())["fleet_id"] == "fake"
        assert jobs.active_fleet_jobs(ws) == [job_id]
        assert jobs.cancel_fleet(ws, job_id)
        while time.monotonic() < deadline and jobs.fleet_job_status(ws, job_id)["state"] == "running":
            time.sleep(0.1)
        assert jobs.fleet_job_status(ws, job_id)["state"] == "cancelled"
        assert not jobs.cancel_fleet(ws, job_id)
    finally:
        pid = json.loads((jobs.fleet_jobs_dir(ws) / f"{job_id}.json").read_text())["pid"]
        if jobs.pid_alive(pid):
            os.killpg(pid, signal.SIGKILL)


def test_a_fleet_that_dies_before_its_fleet_json_fails_with_its_output(tmp_path, monkeypatch):
    ws = Workspace(tmp_path / "ws").ensure()
    monkeypatch.setattr(
        jobs,
        "fleet_command",
        lambda req, root: [sys.executable, "-c", "import sys; sys.exit('error: no such option: --drivers')"],
    )
    job_id = jobs.launch_fleet(ws, jobs.FleetRequest("drivers", 10))
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and jobs.fleet_job_status(ws, job_id)["state"] == "starting":
        time.sleep(0.1)
    st = jobs.fleet_job_status(ws, job_id)
    assert st["state"] == "failed" and "no such option: --drivers" in st["log"]


def test_training_page_launches_a_fleet(copy_ws):
    at = run_page("training")
    assert any("No fleet launched" in c.value for c in at.caption)
    at.radio(key="fleet_kind").set_value("drivers")
    at.number_input(key="fleet_seeds").set_value(2)
    at.number_input(key="fleet_episodes").set_value(50)
    next(b for b in at.button if b.label == "Train fleet").click().run()
    assert not at.exception, [e.value for e in at.exception]
    (job_id,) = at.session_state["fleets_launched"]
    job = json.loads((jobs.fleet_jobs_dir(copy_ws) / f"{job_id}.json").read_text())
    try:
        assert job["command"] == jobs.fleet_command(jobs.FleetRequest("drivers", 50, seeds=2), copy_ws.root)
        assert any("6 drivers x 2 seed(s) = 12 agents" in c.value for c in at.caption)
    finally:
        if jobs.pid_alive(job["pid"]):
            os.killpg(job["pid"], signal.SIGTERM)


def test_training_page_follows_a_running_fleet(copy_ws):
    proc = subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(60)", "laneprint-fake-fleet"], start_new_session=True
    )
    try:
        runs = write_fake_fleet(
            copy_ws, "live", ["D01", "D02", "D03", "D04"], state="running", pid=proc.pid, evaluated=3
        )
        jobs.fleet_jobs_dir(copy_ws).mkdir(parents=True)
        (jobs.fleet_jobs_dir(copy_ws) / "j1.json").write_text(
            json.dumps({"job_id": "j1", "pid": proc.pid, "request": {}, "launched_at": "2026-11-30T10:00:00+00:00"})
        )
        at = run_page("training")
        bar = next(p for p in at.get("progress") if "fleet live" in p.proto.text)
        assert "3/4 agents done, 160/200 episodes; 2 of 3 evaluated meet their target" in bar.proto.text
        table = next(d.value for d in at.dataframe if "agent BA [%]" in d.value.columns)
        assert table["run_id"].tolist() == runs and table["episodes"].tolist() == ["50/50"] * 3 + ["10/50"]
        assert table["meets target"].tolist()[:3] == [False, True, True]
        # the fleet's running run is not drawn as a single run with its curves
        assert not any(b.key == f"cancel_{runs[3]}" for b in at.button)
        assert any(b.key == "fleet_cancel_j1" for b in at.button)
    finally:
        proc.kill()
        proc.wait()


def test_results_page_fleet_view(copy_ws):
    drivers = [f"D{i:02d}" for i in range(1, 7)]
    write_fake_fleet(copy_ws, "f1", drivers, seeds=(0, 1))
    at = run_page("results")
    assert at.selectbox(key="fleet_pick").value == "f1"
    assert "f1: 6 drivers x 2 seeds, 12/12 done (done)" in at.selectbox(key="fleet_pick").options
    agents = next(d for d in at.dataframe if "agent BA [%]" in d.value.columns).value
    assert len(agents) == 12 and agents["greedy BA [%]"].eq(60.0).all()
    assert agents["agent - greedy BA [points]"].max() == pytest.approx(32.0)
    assert any("10 of 12 evaluated agents meet their target" in c.value for c in at.caption)
    specs = [json.loads(c.proto.spec) for c in at.get("plotly_chart")]
    fig = next(
        f
        for f in specs
        if "balanced accuracy on the target" in f["layout"].get("xaxis", {}).get("title", {}).get("text", "")
    )
    assert [t["name"] for t in fig["data"]] == ["agent (open: misses its target)", "greedy", "imitation"]
    assert list(fig["data"][0]["y"]) == drivers  # sorted by the agent's balanced accuracy
    assert fig["data"][0]["marker"]["symbol"][:2] == ["circle-open", "circle"]  # D01's agent misses the target


@pytest.mark.slow
def test_a_real_fleet_from_the_dashboard(copy_ws):
    """`laneprint train --drivers all` launched as the Training page does, followed to its evaluated agents."""
    from rl.fleet import store as fleet_store

    job_id = jobs.launch_fleet(copy_ws, jobs.FleetRequest("drivers", 60))
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and jobs.fleet_job_status(copy_ws, job_id)["state"] in jobs.ACTIVE_STATES:
        time.sleep(0.5)
    status = jobs.fleet_job_status(copy_ws, job_id)
    assert status["state"] == "done", status
    table = fleet_store.fleet_table(copy_ws, status["fleet_id"])
    assert sorted(table["target"]) == ["D01", "D02", "D03", "D04", "D05", "D06"]
    assert (table["state"] == "done").all() and (table["episode"] == table["episodes"]).all()
    assert table["agent_balanced_accuracy"].notna().all() and table["greedy_balanced_accuracy"].notna().all()
