import signal
import subprocess
import sys

from dashboard_support import write_fake_run
from dashboard import jobs
from laneprint.workspace import Workspace, atomic_write_json


def test_train_command_line(tmp_path):
    req = jobs.TrainRequest("driver", "D03", 40, seed=7, reward="timing", lines="paper")
    cmd = jobs.train_command(req, tmp_path, "r1")
    assert cmd[:4] == [sys.executable, "-m", "laneprint.app.cli", "train"]
    assert cmd[4:] == [
        "--driver",
        "D03",
        "--episodes",
        "40",
        "--seed",
        "7",
        "--run-id",
        "r1",
        "--workspace",
        str(tmp_path),
        "--reward",
        "timing",
        "--lines",
        "paper",
    ]
    rid = jobs.new_run_id(jobs.TrainRequest("style", "Very Normal/..", 1))
    assert rid.startswith("Very_Normal___-") and "/" not in rid


def test_status_of_dead_and_unknown_runs(tmp_path):
    ws = Workspace(tmp_path).ensure()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    write_fake_run(ws, "lost", state="running", pid=dead.pid)
    assert jobs.run_status(ws, "lost")["state"] == "interrupted"
    # launched, died before writing status.json
    jobs.jobs_dir(ws).mkdir(parents=True)
    atomic_write_json(jobs.jobs_dir(ws) / "early.json", {"pid": dead.pid, "request": {"episodes": 5}})
    (jobs.jobs_dir(ws) / "early.log").write_text("Traceback ...\nUserError: no reference lines\n")
    st = jobs.run_status(ws, "early")
    assert st["state"] == "failed" and "no reference lines" in st["log"]
    write_fake_run(ws, "fine")
    assert jobs.run_status(ws, "fine")["state"] == "done"
    table = jobs.runs_table(ws)
    assert set(table["run_id"]) == {"lost", "early", "fine"}
    table = table.set_index("run_id")
    assert table.loc["fine", "recall"] == 0.96 and table.loc["lost", "state"] == "interrupted"
    assert table.loc["early", "state"] == "failed"


def test_cancel_sends_sigterm_to_a_running_run(tmp_path):
    ws = Workspace(tmp_path).ensure()
    write_fake_run(ws, "r", state="running")
    code = (
        "import signal, sys, time\nfrom laneprint.locks import FileLock\nFileLock(sys.argv[2]).acquire()\n"
        "signal.signal(signal.SIGTERM, lambda *a: sys.exit(42))\nprint('ready', flush=True)\ntime.sleep(30)"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "laneprint-fake-trainer", str(ws.runs_dir / "r" / "run.lock")],
        start_new_session=True,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout.readline().strip() == "ready"  # holds the run's lock, handler installed
        write_fake_run(ws, "r", state="running", pid=proc.pid)
        assert jobs.run_status(ws, "r")["state"] == "running"
        assert jobs.cancel(ws, "r")
        assert proc.wait(timeout=10) == 42
        assert not jobs.cancel(ws, "r")  # nothing left to cancel
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait()


def test_a_reused_pid_is_not_a_run(tmp_path):
    """A status that names the pid of some other program: the run is interrupted, and Cancel signals nothing."""
    ws = Workspace(tmp_path).ensure()
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"], start_new_session=True)
    try:
        write_fake_run(ws, "r", state="running", pid=other.pid)
        assert jobs.run_status(ws, "r")["state"] == "interrupted"
        assert not jobs.cancel(ws, "r")
        assert other.poll() is None
    finally:
        other.kill()
        other.wait()


def test_check_target_says_why_the_trainer_would_refuse(tmp_path):
    from dashboard.training import check_target

    ws = Workspace(tmp_path).ensure()
    assert check_target(ws, jobs.TrainRequest("style", "Normal", 10, lines="paper")) == ""
    assert "needs style" in check_target(ws, jobs.TrainRequest("driver", "D01", 10, lines="paper"))
    assert "no analysis" in check_target(ws, jobs.TrainRequest("style", "Normal", 10, lines="analysis"))


def test_the_form_offers_the_trainers_default_learner_first():
    """The Training form's learners follow `train`: 'auto' first on the decisions reward, only the DQN
    for the paper's formulations (which the trees cannot fit, so `train` would refuse them)."""
    from dashboard.training import learners

    assert learners("decisions", "analysis") == ["auto", "dqn", "trees"]
    assert learners("timing", "paper") == ["dqn"]
    assert learners("paper", "analysis") == ["dqn"]
