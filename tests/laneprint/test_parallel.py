"""`laneprint.parallel`: the local and Ray backends give the same results, and `ingest` and `crossval`
on Ray (a local instance with 2 CPUs, shared by this module's tests) equal their local runs."""

from __future__ import annotations

import importlib.util
import json
import shutil
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.parallel import backend_session, iter_tasks, run_tasks
from laneprint.workspace import Workspace
from rl.problem.rewards import ReferenceLines
from tests.support.rl_workspaces import session_decisions, write_style_analysis

SAMPLE = Path(__file__).resolve().parents[2] / "sample_logs"


def _square(x: int) -> int:
    if x < 0:
        raise UserError(f"item {x} is negative")
    return x * x


def test_local_backend_runs_in_order_and_reports_each_task():
    seen = []
    out = run_tasks(_square, range(5), progress=lambda d, t, m: seen.append((d, t, m)), label="squares")
    assert out == [0, 1, 4, 9, 16]
    assert seen == [(i, 5, "squares") for i in range(6)]
    assert run_tasks(_square, [], backend="ray") == []
    ray = sys.modules.get("ray")
    assert ray is None or not ray.is_initialized()  # no Ray instance started for nothing


def test_bad_backend_options_are_one_line_errors(monkeypatch, tmp_path):
    with pytest.raises(UserError, match="unknown backend 'dask'"):
        run_tasks(_square, [1], backend="dask")
    with pytest.raises(UserError, match="add (--)?backend ray"):
        run_tasks(_square, [1], ray_address="127.0.0.1:6379")
    if importlib.util.find_spec("ray"):
        with pytest.raises(UserError, match="cannot join the Ray cluster at 127.0.0.1:1: Connection refused"):
            run_tasks(_square, [1], backend="ray", ray_address="127.0.0.1:1")
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    with pytest.raises(UserError, match=r"pip install -e '\.\[ray\]'"):
        run_tasks(_square, [1], backend="ray")
    res = CliRunner().invoke(
        app, ["ingest", str(SAMPLE / "D01_S60.mcap"), "--backend", "ray", "-w", str(tmp_path / "ws")]
    )
    assert res.exit_code == 1 and "pip install -e '.[ray]'" in res.output and "Traceback" not in res.output


@pytest.fixture(scope="module")
def ray_cluster():
    """One local Ray instance with 2 CPUs for the module (its start-up takes 5-15 s)."""
    ray = pytest.importorskip("ray")
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import a test module
    with backend_session("ray", num_cpus=2):
        yield ray


@pytest.mark.slow
def test_ray_backend_keeps_item_order_and_turns_a_worker_user_error_into_one_line(ray_cluster):
    seen = []
    assert run_tasks(_square, range(7), backend="ray", progress=lambda d, t, m: seen.append(d)) == [
        x * x for x in range(7)
    ]
    assert seen == list(range(8))
    assert list(iter_tasks(_square, iter(range(5)), backend="ray", in_flight=2)) == [0, 1, 4, 9, 16]
    with pytest.raises(UserError) as err:
        run_tasks(_square, [1, -3, 2], backend="ray")
    assert str(err.value) == "item -3 is negative"
    assert ray_cluster.is_initialized()  # a running instance is used and left running


def _ingest(files: Path, ws: Path, *extra: str) -> dict:
    res = CliRunner().invoke(app, ["ingest", str(files), "-w", str(ws), "--json", *extra])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


@pytest.mark.slow
def test_ingest_on_ray_gives_the_local_catalogue(ray_cluster, tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("D01_S60.mcap", "D01_S70.mcap", "D02_S60.csv.gz", "D02_S70.csv.gz", "D03_S60.mcap"):
        shutil.copy(SAMPLE / name, logs / name)
    shutil.copy(SAMPLE / "D01_S60.mcap", logs / "copy_of_D01_S60.mcap")  # same bytes: a duplicate
    (logs / "broken.csv").write_text("t,x\n1,2\n")  # refused with a reason
    (logs / "notes.txt").write_text("not a log")  # skipped
    local = _ingest(logs, tmp_path / "local")
    ray = _ingest(logs, tmp_path / "ray", "--backend", "ray")
    assert (
        local["counts"] == ray["counts"] == {"ingested": 5, "warning": 0, "duplicate": 1, "rejected": 1, "skipped": 1}
    )
    assert local["files"] == ray["files"]
    cats = [Workspace(tmp_path / w).recordings().drop(columns=["ingested_at"]) for w in ("local", "ray")]
    assert cats[0].equals(cats[1]) and len(cats[0]) == 5
    assert len(Workspace(tmp_path / "ray").rejected()) == 1


@pytest.mark.slow
def test_crossval_on_ray_gives_the_local_figures(ray_cluster, tmp_path):
    write_style_analysis(
        Workspace(tmp_path), session_decisions(ReferenceLines.paper("Normal"), 4, 5), ReferenceLines.paper("Normal")
    )
    args = [
        "crossval",
        "--style",
        "Normal",
        "--folds",
        "2",
        "--episodes",
        "100",
        "--bootstrap",
        "50",
        "--seed",
        "3",
        "-w",
        str(tmp_path),
        "--json",
    ]
    out = []
    for extra in ([], ["--backend", "ray"]):
        res = CliRunner().invoke(app, args + extra)
        assert res.exit_code == 0, res.output
        out.append(json.loads(res.stdout))
    local, ray = out

    def figures(
        folds: list[dict],
    ) -> list[dict]:  # the local fleet stops what cannot win and says so; Ray's folds do not
        return [{k: v for k, v in f.items() if k != "learner_stopped"} for f in folds]

    assert local["summary"] == ray["summary"] and figures(local["per_fold"]) == figures(ray["per_fold"])
    assert [f["fold"] for f in ray["per_fold"]] == [0, 1]
    stored = [Workspace(tmp_path).root / "crossval" / r["crossval_id"] for r in out]
    assert all((s / "result.json").exists() and (s / "states.parquet").exists() for s in stored)
