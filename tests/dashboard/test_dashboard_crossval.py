"""Held-out figures in the dashboard: figures and tables from a hand-made `laneprint crossval` result,
the Results and Training pages over a workspace holding one, and the `laneprint crossval --run` jobs."""

import json
import shutil
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest
from streamlit.testing.v1 import AppTest

from dashboard import figures, jobs, views
from dashboard_support import CROSSVAL_ID, crossval_result, page_path, write_fake_crossval
from laneprint.workspace import Workspace, atomic_write_json

IN_SAMPLE = [  # a run evaluation's summary rows: no intervals, and (older runs) no imitation
    {"who": "agent", "balanced_accuracy": 0.9, "recall": 0.96, "specificity": 0.84, "timing_mae_s": 0.5},
    {"who": "greedy", "balanced_accuracy": 0.7, "recall": 1.0, "specificity": 0.4, "timing_mae_s": 1.5},
    {"who": "driver", "balanced_accuracy": 1.0, "recall": 1.0, "specificity": 1.0, "timing_mae_s": 0.0},
]


# --- figures and tables -----------------------------------------------------------------


def test_heldout_bars_beside_in_sample_with_interval_error_bars():
    fig = figures.heldout_vs_insample(crossval_result()["summary"], IN_SAMPLE)
    names = [(t.name, t.xaxis) for t in fig.data]
    assert names == [
        ("in-sample", "x"),
        ("held out (95 % interval)", "x"),
        ("in-sample", "x2"),
        ("held out (95 % interval)", "x2"),
    ]
    ins_ba, held_ba, ins_mae, held_mae = fig.data
    assert list(held_ba.x) == ["agent", "greedy", "imitation"]  # the driver is the reference, not a bar
    assert list(held_ba.y) == pytest.approx([80.0, 60.0, 85.0])
    assert list(held_ba.error_y.array) == pytest.approx([10.0, 2.0, 3.0])  # hi - value, in percent
    assert list(held_ba.error_y.arrayminus) == pytest.approx([5.0, 5.0, 5.0])  # value - lo
    assert list(ins_ba.y[:2]) == pytest.approx([90.0, 70.0]) and ins_ba.y[2] is None  # no imitation in-sample
    assert ins_ba.error_y.array is None  # in-sample figures have no interval
    assert list(held_mae.y[:2]) == pytest.approx([1.5, 4.0]) and held_mae.y[2] is None  # never timed
    assert list(held_mae.error_y.array[:2]) == pytest.approx([0.75, 0.5]) and held_mae.error_y.array[2] is None
    assert fig.layout.yaxis.title.text == "balanced accuracy [%]" and fig.layout.yaxis2.title.text == "timing MAE [s]"
    assert fig.layout.barmode == "group"


def test_heldout_bars_alone_without_an_evaluation():
    fig = figures.heldout_vs_insample(crossval_result()["summary"])
    assert [t.name for t in fig.data] == ["held out (95 % interval)"] * 2


def test_per_fold_figure_in_percent():
    fig = figures.crossval_folds(crossval_result()["per_fold"])
    assert [t.name for t in fig.data] == ["agent", "greedy", "imitation"]
    assert list(fig.data[0].x) == [1, 2] and list(fig.data[0].y) == pytest.approx([78.0, 82.0])
    assert fig.layout.yaxis.title.text == "balanced accuracy [%]"
    assert figures.crossval_folds([]).data == ()


def test_crossval_table_puts_in_sample_next_to_held_out():
    t = views.crossval_table(crossval_result()["summary"], IN_SAMPLE).set_index("policy")
    assert t.index.tolist() == ["agent", "greedy", "imitation"]
    assert list(t.columns[:3]) == [
        "balanced accuracy in-sample [%]",
        "balanced accuracy held out [%]",
        "balanced accuracy held out 95 % interval [%]",
    ]
    assert t.loc["agent", "balanced accuracy in-sample [%]"] == 90.0
    assert t.loc["agent", "balanced accuracy held out [%]"] == 80.0
    assert t.loc["agent", "balanced accuracy held out 95 % interval [%]"] == "75.0 – 90.0"
    assert t.loc["agent", "timing MAE held out 95 % interval [s]"] == "1.00 – 2.25"
    assert pd.isna(t.loc["imitation", "balanced accuracy in-sample [%]"])  # the run has no imitation row
    assert pd.isna(t.loc["imitation", "timing MAE held out [s]"])  # it never changed lane
    assert t.loc["greedy", "decisions held out"] == 40
    alone = views.crossval_table(crossval_result()["summary"])
    assert not [c for c in alone.columns if "in-sample" in c]


def test_unscored_reasons_and_the_scored_count():
    res = crossval_result()
    t = views.unscored_table(res)
    assert t["reason"].tolist() == ["no_press", "following"] and t["decisions"].tolist() == [7, 3]
    assert t["meaning"].str.len().min() > 0  # the RL stage's explanation of each reason
    assert views.scored_line(res).startswith("40 of 50 decisions scored (80%), 2 folds by session")
    assert views.unscored_table({"unscored": {}}).empty


def test_which_crossval_is_shown_beside_a_run():
    normal = {"kind": "style", "name": "Normal"}
    assert views.default_crossval(pd.DataFrame(), "r", normal) is None  # list_crossvals of an empty workspace

    def table(*results):
        return pd.DataFrame(
            [
                {
                    "crossval_id": r["crossval_id"],
                    "target_kind": r["target"]["kind"],
                    "target": r["target"]["name"],
                    "run_id": r["run_id"],
                    "reward": "timing",
                    "folds": 2,
                    "created_at": r["crossval_id"][:15],
                }
                for r in results
            ]
        )

    old_of_run = crossval_result("r", "20260101-000000-a")
    newer_same_target = crossval_result(None, "20260201-000000-b")
    other_target = crossval_result("x", "20260301-000000-c", target=("driver", "D01"))
    t = table(old_of_run, newer_same_target, other_target)
    assert views.default_crossval(t, "r", normal, own_id="20260101-000000-a") == "20260101-000000-a"
    assert views.default_crossval(t, "r", normal) == "20260101-000000-a"  # the run's own before a newer one
    assert views.default_crossval(t, "q", normal) == "20260201-000000-b"  # newest of the same target
    assert views.default_crossval(t, "q", {"kind": "driver", "name": "D09"}) is None
    assert views.crossvals_view(t)["crossval_id"].tolist()[0] == "20260301-000000-c"  # newest first
    diff = views.crossval_differences(
        newer_same_target,
        "q",
        {
            "target": normal,
            "dqn": {"episodes": 3000},
            "env": {"scenes": "recorded", "observation": "positions", "reward": {"name": "timing"}},
        },
    )
    assert diff == [
        "it is of no run, not of q",
        "scenes `random` (the run: `recorded`)",
        "its agents trained 30 episodes per fold (the run: 3000)",
    ]


# --- the `laneprint crossval --run` job ----------------------------------------------------


def test_crossval_command_line(tmp_path):
    cmd = jobs.crossval_command(jobs.CrossvalRequest("Normal-seed0", folds=3, episodes=500, bootstrap=200), tmp_path)
    assert cmd == [
        sys.executable,
        "-m",
        "laneprint.app.cli",
        "crossval",
        "--run",
        "Normal-seed0",
        "--folds",
        "3",
        "--split",
        "session",
        "--seed",
        "0",
        "--bootstrap",
        "200",
        "--episodes",
        "500",
        "--workspace",
        str(tmp_path),
    ]
    same = jobs.crossval_command(jobs.CrossvalRequest("r", split="section"), tmp_path)
    assert "--episodes" not in same and same[same.index("--split") + 1] == "section"  # the run's own episodes
    assert views.command_text(same).startswith("laneprint crossval --run r --folds 4")


BAR = "\x1b[?25l\rfold {k}/4: agent \x1b[38;5;237m━━━━━━━━━━━━\x1b[0m   {d}/{t} 0:00:0{k}"


def test_progress_read_from_the_bar_in_the_log():
    log = "\r ━━━          0/? 0:00:00" + "".join(
        BAR.format(k=k, d=d, t=1000) for k, d in [(1, 500), (1, 1000), (2, 250)]
    )
    p = jobs.crossval_progress(log)
    assert (p["fold"], p["folds"], p["step"], p["done"], p["total"]) == (2, 4, "agent", 250, 1000)
    assert p["fraction"] == pytest.approx((1 + 0.25) / 4)
    assert "crossval_id" not in p and "error" not in p
    assert jobs.crossval_progress(log + "fold 3/4: agent ━━  12/10")["fold"] == 2  # a half-written redraw
    done = jobs.crossval_progress(log + "\n┃ who ┃\nstored as crossval/20261130-x-normal\n")
    assert done["crossval_id"] == "20261130-x-normal"
    assert (
        jobs.crossval_progress("\r ━━ 0/? 0:00:00\nerror: no run 'nope' in /w\n")["error"]
        == "error: no run 'nope' in /w"
    )


def _job(ws, job_id, log, pid=None, **extra):
    d = jobs.crossval_jobs_dir(ws)
    d.mkdir(parents=True, exist_ok=True)
    atomic_write_json(
        d / f"{job_id}.json",
        {"job_id": job_id, "run_id": "r", "pid": pid, "launched_at": f"2026-11-30T12:00:0{job_id[-1]}+00:00", **extra},
    )
    (d / f"{job_id}.log").write_text(log)


def test_status_of_ended_crossval_jobs(tmp_path):
    ws = Workspace(tmp_path).ensure()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    write_fake_crossval(ws, crossval_result("r"), of_run=False)
    _job(ws, "j1", BAR.format(k=4, d=30, t=30) + f"\nstored as crossval/{CROSSVAL_ID}\n", dead.pid)
    _job(ws, "j2", BAR.format(k=1, d=3, t=30) + "\nerror: no run 'r' in /w\n", dead.pid)
    _job(ws, "j3", BAR.format(k=1, d=3, t=30), dead.pid, cancelled_at="2026-11-30T12:01:00+00:00")
    _job(ws, "j4", BAR.format(k=1, d=3, t=30) + "\nstored as crossval/gone\n", dead.pid)
    st = {j: jobs.crossval_status(ws, j) for j in ("j1", "j2", "j3", "j4", "nope")}
    assert st["j1"]["state"] == "done" and st["j1"]["crossval_id"] == CROSSVAL_ID and st["j1"]["fraction"] == 1.0
    assert st["j2"]["state"] == "failed" and st["j2"]["message"] == "error: no run 'r' in /w"
    assert "error: no run" in st["j2"]["log"] and "\x1b" not in st["j2"]["log"]
    assert st["j3"]["state"] == "cancelled"
    assert st["j4"]["state"] == "failed"  # says it stored a result that is not there
    assert st["nope"]["state"] == "unknown"
    assert jobs.crossval_job_ids(ws) == ["j4", "j3", "j2", "j1"]  # newest first
    assert jobs.crossval_job_ids(ws, "other") == [] and jobs.active_crossvals(ws) == []
    assert jobs.run_ids(ws) == []  # cross-validation jobs are not training runs


def test_running_crossval_shows_progress_and_cancels(tmp_path):
    ws = Workspace(tmp_path).ensure()
    code = "import signal, sys, time\nsignal.signal(signal.SIGTERM, lambda *a: sys.exit(42))\ntime.sleep(30)"
    proc = subprocess.Popen([sys.executable, "-c", code, "laneprint-fake-crossval"], start_new_session=True)
    try:
        time.sleep(0.3)  # let it install its handler
        _job(ws, "j1", BAR.format(k=2, d=100, t=400), proc.pid)
        st = jobs.crossval_status(ws, "j1")
        assert st["state"] == "running" and st["message"] == "fold 2/4: training the agent, episode 100/400"
        assert st["fraction"] == pytest.approx((1 + 0.25) / 4)
        _job(ws, "j1", BAR.format(k=4, d=400, t=400), proc.pid)
        st = jobs.crossval_status(ws, "j1")
        assert st["fraction"] == 0.99 and "scoring" in st["message"]  # the last fold's agent trained: not done
        assert jobs.active_crossvals(ws, "r") == ["j1"]
        assert jobs.cancel_crossval(ws, "j1")
        assert proc.wait(timeout=10) == 42
        assert jobs.crossval_status(ws, "j1")["state"] == "cancelled"
        assert not jobs.cancel_crossval(ws, "j1")
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            proc.wait()


def test_launch_runs_the_command_in_the_background_with_a_drawn_bar(tmp_path, monkeypatch):
    """The launcher's wiring (own session, log, job record, terminal env) with a stand-in for the command."""
    ws = Workspace(tmp_path).ensure()
    script = (
        "import os, sys\nassert os.environ['TTY_COMPATIBLE'] == '1'\n"
        "sys.stderr.write('\\rfold 1/2: agent ━━  5/10 0:00:01\\n')\nprint('error: stand-in ends')\n"
        "sys.exit(1)"
    )
    monkeypatch.setattr(jobs, "crossval_command", lambda req, root: [sys.executable, "-c", script, "laneprint"])
    job_id = jobs.launch_crossval(ws, jobs.CrossvalRequest("my run/1"))
    assert job_id.startswith("my_run_1-cv-")
    record = json.loads((jobs.crossval_jobs_dir(ws) / f"{job_id}.json").read_text())
    assert record["run_id"] == "my run/1" and record["request"]["folds"] == 4
    jobs._CHILDREN[record["pid"]].wait(timeout=30)
    st = jobs.crossval_status(ws, job_id)
    assert (st["state"], st["message"], st["fold"], st["done"]) == ("failed", "error: stand-in ends", 1, 5)


# --- pages -------------------------------------------------------------------------------


def run_page(name: str) -> AppTest:
    at = AppTest.from_file(page_path(name), default_timeout=60).run()
    assert not at.exception, [e.value for e in at.exception]
    return at


@pytest.fixture
def copy_ws(sample_ws, tmp_path, monkeypatch) -> Workspace:
    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    return ws


def frame_with(at: AppTest, column: str):
    return next(d.value for d in at.dataframe if column in d.value.columns)


def test_results_page_held_out_beside_in_sample(copy_ws):
    write_fake_crossval(copy_ws, crossval_result("Normal-seed0"))
    at = run_page("results")
    assert at.selectbox(key="result_run").value == "Normal-seed1"
    # no cross-validation of this run: the newest of its target, said to be another run's
    assert at.selectbox(key="cv_pick_Normal-seed1").value == CROSSVAL_ID
    assert any("it is of run Normal-seed0, not of Normal-seed1" in c.value for c in at.caption)
    at.selectbox(key="result_run").set_value("Normal-seed0").run()
    assert not at.exception, [e.value for e in at.exception]
    assert not any("not of Normal-seed0" in c.value for c in at.caption)
    ev = json.loads((copy_ws.runs_dir / "Normal-seed0" / "evaluation.json").read_text())
    in_sample = {r["who"]: r for r in ev.get("summary_members") or ev["summary"]}
    table = frame_with(at, "balanced accuracy held out [%]").set_index("policy")
    assert table.index.tolist() == ["agent", "greedy", "imitation"]
    assert table["balanced accuracy held out [%]"].tolist() == [80.0, 60.0, 85.0]
    assert table.loc["agent", "balanced accuracy in-sample [%]"] == pytest.approx(
        100 * in_sample["agent"]["balanced_accuracy"], abs=0.01
    )
    assert table.loc["greedy", "balanced accuracy held out 95 % interval [%]"] == "55.0 – 62.0"
    unscored = frame_with(at, "reason")
    assert dict(zip(unscored["reason"], unscored["decisions"])) == {"no_press": 7, "following": 3}
    assert any(c.value.startswith("40 of 50 decisions scored") for c in at.caption)
    bars = next(json.loads(c.proto.spec) for c in at.get("plotly_chart") if "held out (95 % interval)" in c.proto.spec)
    held = [t for t in bars["data"] if t["name"] == "held out (95 % interval)"][0]
    assert held["error_y"]["array"] == pytest.approx([10.0, 2.0, 3.0])
    assert "in-sample" in [t["name"] for t in bars["data"]]
    stored = frame_with(at, "crossval_id")
    assert stored["crossval_id"].tolist() == [CROSSVAL_ID]


def test_results_page_without_crossval_says_how_and_offers_the_button(copy_ws):
    at = run_page("results")
    assert "laneprint crossval --run Normal-seed1" in at.info[0].value
    assert at.button(key="cv_start_Normal-seed1").label == "Cross-validate"
    policies = frame_with(at, "policy")["policy"].tolist()  # in-sample: imitation when the evaluation has it
    assert policies[:2] == ["agent", "greedy"] and policies[-1] == "driver"


def test_results_page_shows_stored_crossvals_without_runs(empty_ws):
    write_fake_crossval(empty_ws.ensure(), crossval_result(None))
    at = run_page("results")
    assert at.info and frame_with(at, "crossval_id")["target"].tolist() == ["Normal"]
    assert frame_with(at, "balanced accuracy held out [%]")["policy"].tolist() == ["agent", "greedy", "imitation"]


def test_training_page_launches_crossval_of_a_finished_run(copy_ws, monkeypatch):
    spawned = []

    def fake_spawn(folder, job_id, cmd, cwd, record, env=None):
        spawned.append((cmd, env))
        atomic_write_json(
            folder / f"{job_id}.json",
            {**record, "pid": None, "command": cmd, "launched_at": "2026-11-30T12:00:00+00:00"},
        )
        return 0

    monkeypatch.setattr(jobs, "_spawn", fake_spawn)
    at = run_page("training")
    assert at.selectbox(key="show_run").value == "Normal-seed1"
    at.number_input(key="cv_folds_Normal-seed1").set_value(2)
    at.number_input(key="cv_episodes_Normal-seed1").set_value(40)
    at.button(key="cv_start_Normal-seed1").click().run()
    assert not at.exception, [e.value for e in at.exception]
    ((cmd, env),) = spawned
    assert cmd[2:] == [
        "laneprint.app.cli",
        "crossval",
        "--run",
        "Normal-seed1",
        "--folds",
        "2",
        "--split",
        "session",
        "--seed",
        "0",
        "--bootstrap",
        "1000",
        "--episodes",
        "40",
        "--workspace",
        str(copy_ws.root),
    ]
    assert env["TTY_COMPATIBLE"] == "1"
    assert len(at.session_state["crossval_launched"]) == 1
    # the stand-in process never ran: the job shows as failed, with the button back
    assert any("cross-validation of Normal-seed1: failed" in p.proto.text for p in at.get("progress"))
    assert at.button(key="cv_start_Normal-seed1")


@pytest.mark.slow
def test_crossval_from_the_training_page_lands_on_the_results_page(copy_ws):
    """The real `laneprint crossval --run` (2 folds, 30 episodes): launched by the button, followed to its
    end, then shown on the Results page beside the run's in-sample figures."""
    at = run_page("training")
    at.number_input(key="cv_folds_Normal-seed1").set_value(2)
    at.number_input(key="cv_bootstrap_Normal-seed1").set_value(20)
    at.button(key="cv_start_Normal-seed1").click().run()
    assert not at.exception, [e.value for e in at.exception]
    job_id = at.session_state["crossval_launched"][0]
    deadline = time.monotonic() + 240
    while time.monotonic() < deadline and jobs.crossval_status(copy_ws, job_id)["state"] in jobs.ACTIVE_STATES:
        time.sleep(0.5)
    status = jobs.crossval_status(copy_ws, job_id)
    assert status["state"] == "done", status
    assert (copy_ws.runs_dir / "Normal-seed1" / "crossval.json").exists()
    at = run_page("results")
    assert at.selectbox(key="cv_pick_Normal-seed1").value == status["crossval_id"]
    table = frame_with(at, "balanced accuracy held out [%]")
    assert table["policy"].tolist() == ["agent", "greedy", "imitation"]
    assert table["balanced accuracy held out [%]"].between(0, 100).all()
