"""Reading fleets: hand-written `fleets/<id>/fleet.json` and run folders as the fleet trainer writes them."""

import subprocess
import sys

import numpy as np
import pytest

from laneprint.errors import UserError
from laneprint.workspace import Workspace, atomic_write_json
from rl.fleet import store as fleet_store


def summary(agent, greedy, imitation=None):
    """Evaluation rows: (recall, balanced accuracy) per policy."""
    rows = [
        {"who": "agent", "recall": agent[0], "balanced_accuracy": agent[1], "timing_mae_s": 0.4},
        {"who": "greedy", "recall": greedy[0], "balanced_accuracy": greedy[1], "timing_mae_s": 2.0},
    ]
    if imitation:
        rows.append({"who": "imitation", "recall": imitation[0], "balanced_accuracy": imitation[1]})
    return rows + [{"who": "driver", "recall": 1.0, "balanced_accuracy": 1.0, "timing_mae_s": 0.0}]


def write_run(ws, run_id, fleet_id, driver, seed, state="done", episode=50, episodes=50, pid=None, rows=None):
    d = ws.runs_dir / run_id
    d.mkdir(parents=True)
    atomic_write_json(
        d / "config.json",
        {
            "run_id": run_id,
            "target": {"kind": "driver", "name": driver},
            "seed": seed,
            "fleet_id": fleet_id,
            "dqn": {"episodes": episodes},
        },
    )
    atomic_write_json(d / "status.json", {"state": state, "pid": pid, "episode": episode, "episodes": episodes})
    if rows is not None:
        atomic_write_json(d / "evaluation.json", {"summary": rows})


def write_fleet(
    ws, fleet_id, runs, state="done", pid=None, created="2026-11-30T10:00:00+00:00", targets=None, seeds=(0,)
):
    folder = fleet_store.fleet_dir(ws) / fleet_id
    folder.mkdir(parents=True)
    atomic_write_json(
        folder / "fleet.json",
        {
            "fleet_id": fleet_id,
            "created_at": created,
            "targets": targets or [{"kind": "driver", "name": n} for n in ("D01", "D02", "D03")],
            "seeds": list(seeds),
            "runs": runs,
            "backend": "local",
            "state": state,
            "pid": pid,
            "updated_at": created,
            "message": "",
        },
    )


@pytest.fixture
def dead_pid():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


@pytest.fixture
def live_pid():
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)", "laneprint-fake-fleet"])
    yield proc.pid
    proc.kill()
    proc.wait()


def test_fleet_table_scores_each_agent_against_its_target(tmp_path):
    ws = Workspace(tmp_path).ensure()
    write_run(ws, "f-D01-s0", "f", "D01", 0, rows=summary((0.96, 0.90), (1.0, 0.80), (0.7, 0.88)))
    write_run(ws, "f-D02-s0", "f", "D02", 0, rows=summary((0.94, 0.95), (1.0, 0.60)))  # recall short
    write_run(ws, "f-D03-s0", "f", "D03", 0, rows=summary((1.0, 0.64), (1.0, 0.60)))  # 4 points over greedy
    write_fleet(ws, "f", ["f-D01-s0", "f-D02-s0", "f-D03-s0"])
    t = fleet_store.fleet_table(ws, "f").set_index("run_id")
    assert t["target"].tolist() == ["D01", "D02", "D03"] and t["target_kind"].unique().tolist() == ["driver"]
    assert t.loc["f-D01-s0", "agent_minus_greedy"] == pytest.approx(0.10)
    assert t.loc["f-D01-s0", "imitation_balanced_accuracy"] == 0.88
    assert np.isnan(t.loc["f-D02-s0", "imitation_balanced_accuracy"])  # no imitation row
    assert t["meets_target"].tolist() == [True, False, False]
    assert t["timing_mae_s"].tolist() == [0.4] * 3
    progress = fleet_store.fleet_progress(t.reset_index())
    assert progress == {
        "n_runs": 3,
        "n_done": 3,
        "n_evaluated": 3,
        "n_meeting_target": 1,
        "episode": 150,
        "episodes": 150,
    }


def test_meets_target_on_the_edges():
    assert fleet_store.meets_target(0.95, 0.75, 0.70)
    assert not fleet_store.meets_target(0.9499, 0.9, 0.5)
    assert not fleet_store.meets_target(1.0, 0.7499, 0.70)
    assert not fleet_store.meets_target(np.nan, 0.9, 0.5)


def test_a_running_fleet_with_a_dead_process_reads_interrupted(tmp_path, dead_pid, live_pid):
    ws = Workspace(tmp_path).ensure()
    write_run(ws, "a-0", "a", "D01", 0, state="done", rows=summary((1.0, 0.9), (1.0, 0.7)))
    write_run(ws, "a-1", "a", "D02", 0, state="running", episode=20, pid=dead_pid)
    write_fleet(ws, "a", ["a-0", "a-1", "a-2"], state="running", pid=dead_pid)
    assert fleet_store.load_fleet(ws, "a")["state_read"] == "interrupted"
    t = fleet_store.fleet_table(ws, "a")
    assert t["state"].tolist() == ["done", "interrupted", "not started"]
    assert t["meets_target"].tolist() == [True, None, None]
    assert t["episode"].tolist() == [50, 20, 0] and t["episodes"].tolist() == [50, 50, 0]
    # the same fleet with its trainer alive: running, the run without a folder is pending
    write_run(ws, "b-1", "b", "D02", 0, state="running", episode=20, pid=live_pid)
    write_fleet(ws, "b", ["b-1", "b-2"], state="running", pid=live_pid)
    assert fleet_store.fleet_table(ws, "b")["state"].tolist() == ["running", "pending"]


def test_list_fleets_newest_first_with_counts(tmp_path, dead_pid):
    ws = Workspace(tmp_path).ensure()
    assert fleet_store.list_fleets(ws).empty and list(fleet_store.list_fleets(ws).columns) == fleet_store.FLEETS_COLUMNS
    write_run(ws, "old-0", "old", "D01", 0, rows=summary((1.0, 0.9), (1.0, 0.7)))
    write_run(ws, "old-1", "old", "D01", 1, state="running", episode=3, pid=dead_pid)
    write_fleet(
        ws,
        "old",
        ["old-0", "old-1"],
        state="running",
        pid=dead_pid,
        seeds=(0, 1),
        targets=[{"kind": "driver", "name": "D01"}],
    )
    write_fleet(
        ws,
        "new",
        ["new-0"],
        state="done",
        created="2026-11-30T11:00:00+00:00",
        targets=[{"kind": "style", "name": s} for s in ("Defensive", "Normal", "Aggressive", "X")],
    )
    (fleet_store.fleet_dir(ws) / "junk").mkdir()  # no fleet.json: not a fleet
    t = fleet_store.list_fleets(ws)
    assert t["fleet_id"].tolist() == ["new", "old"]
    old = t.set_index("fleet_id").loc["old"]
    assert (old["n_runs"], old["n_done"], old["n_evaluated"], old["n_seeds"]) == (2, 1, 1, 2)
    assert old["state"] == "interrupted" and old["targets"] == "driver D01"
    assert t.set_index("fleet_id").loc["new", "targets"] == "4 styles"


def test_targets_summary():
    drivers = [{"kind": "driver", "name": f"D{i:02d}"} for i in range(100)]
    assert fleet_store.targets_summary(drivers) == "100 drivers"
    assert fleet_store.targets_summary(drivers[:2]) == "drivers D00, D01"
    assert fleet_store.targets_summary(drivers[:2] + [{"kind": "style", "name": "Normal"}]) == "2 drivers, 1 style"
    assert fleet_store.targets_summary([]) == "no targets"


def test_missing_fleet_and_fleet_of_pid(tmp_path):
    ws = Workspace(tmp_path).ensure()
    with pytest.raises(UserError, match="no fleet 'nope'"):
        fleet_store.load_fleet(ws, "nope")
    write_fleet(ws, "f", [], pid=4242)
    assert fleet_store.fleet_of_pid(ws, 4242) == "f" and fleet_store.fleet_of_pid(ws, 1) is None
    (fleet_store.fleet_dir(ws) / "f" / "fleet.json").write_text("{half")  # half-written: skipped
    assert fleet_store.list_fleets(ws).empty
    write_fleet(ws, "g", [], pid=None)  # a fleet.json without a pid is not the fleet of a job without one
    assert fleet_store.fleet_of_pid(ws, None) is None


def test_a_created_fleet_reads_as_its_process(tmp_path, dead_pid, live_pid):
    ws = Workspace(tmp_path).ensure()
    write_fleet(ws, "c", [], state="created", pid=live_pid)
    assert fleet_store.load_fleet(ws, "c")["state_read"] == "created"
    write_fleet(ws, "d", [], state="created", pid=dead_pid)
    assert fleet_store.load_fleet(ws, "d")["state_read"] == "interrupted"
