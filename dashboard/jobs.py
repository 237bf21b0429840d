"""Training runs launched from the dashboard: a `laneprint train` subprocess per run.

The process gets its own session (`start_new_session=True`), so it outlives page
reloads, closed browsers and even the dashboard server; everything the pages show
about it is read back from the run folder (`runs/<run_id>/status.json`,
`metrics.jsonl`, ...) that the trainer writes. The dashboard itself only keeps,
under `dashboard/jobs/`, the command it ran, the pid and the process's output, so a
run that dies before writing its status still shows why.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pandas as pd

from laneprint.workspace import Workspace, atomic_write_json

#: Popen handles of the runs this server started, so finished children are reaped.
_CHILDREN: dict[int, subprocess.Popen] = {}

ACTIVE_STATES = ("starting", "running")


@dataclass(frozen=True)
class TrainRequest:
    """What the Training form asks for; turned into a `laneprint train` command line."""

    target: str
    """'style' or 'driver'."""
    name: str
    """Style name or driver id."""
    episodes: int
    """Training episodes."""
    seed: int = 0
    """Seed of the run."""
    reward: str | None = None
    """Reward formulation (None: the trainer's default)."""
    lines: str | None = None
    """Reference lines: 'analysis' or 'paper' (None: the trainer's default)."""
    options: dict[str, str] = field(default_factory=dict)
    """Further `--option value` pairs for settings the form changed from their defaults."""


def new_run_id(req: TrainRequest) -> str:
    """A unique, readable run id: `<name>-<UTC time>-<4 hex>`."""
    stem = "".join(c if c.isalnum() else "_" for c in req.name)[:24] or "run"
    return f"{stem}-{datetime.now(timezone.utc):%Y%m%d-%H%M%S}-{uuid.uuid4().hex[:4]}"


def train_command(req: TrainRequest, workspace: Path, run_id: str) -> list[str]:
    """The `laneprint train` command line for `req` (run with this interpreter)."""
    if req.target not in ("style", "driver"):
        raise ValueError(f"target must be 'style' or 'driver', not {req.target!r}")
    cmd = [sys.executable, "-m", "laneprint.cli", "train", f"--{req.target}", req.name,
           "--episodes", str(int(req.episodes)), "--seed", str(int(req.seed)),
           "--run-id", run_id, "--workspace", str(workspace)]
    if req.reward:
        cmd += ["--reward", req.reward]
    if req.lines:
        cmd += ["--lines", req.lines]
    for opt, value in req.options.items():
        cmd += [opt, str(value)]
    return cmd


def jobs_dir(ws: Workspace) -> Path:
    return ws.root / "dashboard" / "jobs"


def launch(ws: Workspace, req: TrainRequest, run_id: str | None = None) -> str:
    """Start a training process for `req`; returns its run id at once."""
    run_id = run_id or new_run_id(req)
    cmd = train_command(req, ws.root, run_id)
    jd = jobs_dir(ws)
    jd.mkdir(parents=True, exist_ok=True)
    with open(jd / f"{run_id}.log", "wb") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True, cwd=ws.root)
    _CHILDREN[proc.pid] = proc
    atomic_write_json(jd / f"{run_id}.json", {
        "run_id": run_id, "pid": proc.pid, "command": cmd, "request": asdict(req),
        "launched_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    })
    return run_id


def reap() -> None:
    """Collect exit codes of finished children so they do not linger as zombies."""
    for pid, proc in list(_CHILDREN.items()):
        if proc.poll() is not None:
            del _CHILDREN[pid]


def pid_alive(pid: int | None) -> bool:
    """True if this pid is a live laneprint process (not a zombie, not a reused pid)."""
    if not pid:
        return False
    reap()
    proc = _CHILDREN.get(int(pid))
    if proc is not None:
        return proc.poll() is None
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return False  # another user's process: not a run of ours
    proc_dir = Path(f"/proc/{int(pid)}")
    if not proc_dir.is_dir():  # no /proc (not Linux): trust kill(0)
        return True
    try:
        state = (proc_dir / "stat").read_text().split(") ", 1)[1][0]
        cmdline = (proc_dir / "cmdline").read_bytes()
    except (OSError, IndexError):
        return False
    # a zombie still answers kill(0); a pid reused by another program must not be signalled
    return state != "Z" and b"laneprint" in cmdline


def read_json(path: Path) -> dict[str, Any] | None:
    """A JSON file, or None when missing or half-written."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def log_tail(ws: Workspace, run_id: str, n_chars: int = 2000) -> str:
    """The end of a launched run's process output ('' when none)."""
    try:
        data = (jobs_dir(ws) / f"{run_id}.log").read_bytes()
    except OSError:
        return ""
    return data[-n_chars:].decode(errors="replace")


def run_status(ws: Workspace, run_id: str) -> dict[str, Any]:
    """The run's status.json, completed with what the launcher knows.

    States: 'starting' (launched, no status yet), 'running', 'done', 'failed',
    'cancelled', plus 'lost' for a run marked running whose process is gone.
    """
    job = read_json(jobs_dir(ws) / f"{run_id}.json") or {}
    status = read_json(ws.runs_dir / run_id / "status.json")
    if status is None:
        if job and pid_alive(job.get("pid")):
            return {"state": "starting", "pid": job.get("pid"), "episode": 0,
                    "episodes": job.get("request", {}).get("episodes"), "message": "starting"}
        if job:
            return {"state": "failed", "pid": job.get("pid"), "episode": 0,
                    "episodes": job.get("request", {}).get("episodes"),
                    "message": "the training process ended before writing its status",
                    "log": log_tail(ws, run_id)}
        return {"state": "unknown", "message": "no status.json"}
    status = dict(status)
    if status.get("state") == "running" and not pid_alive(status.get("pid")):
        # the trainer may have just finished: re-read once before calling it lost
        time.sleep(0.05)
        status = dict(read_json(ws.runs_dir / run_id / "status.json") or status)
        if status.get("state") == "running":
            status["state"] = "lost"
            status["message"] = "process ended without a final status (killed?)"
            status["log"] = log_tail(ws, run_id)
    return status


def cancel(ws: Workspace, run_id: str) -> bool:
    """Ask a running run to stop (SIGTERM: the trainer checkpoints and marks it cancelled)."""
    st = run_status(ws, run_id)
    pid = st.get("pid")
    if st.get("state") not in ACTIVE_STATES or not pid_alive(pid):
        return False
    try:
        os.kill(int(pid), signal.SIGTERM)
    except ProcessLookupError:
        return False
    return True


def run_ids(ws: Workspace) -> list[str]:
    """Run folders and launched jobs, newest first."""
    ids = {p.name for p in ws.runs_dir.glob("*") if p.is_dir() and not p.name.startswith(".")}
    ids |= {p.stem for p in jobs_dir(ws).glob("*.json")}

    def started(rid: str) -> float:
        for p in (ws.runs_dir / rid / "status.json", jobs_dir(ws) / f"{rid}.json", ws.runs_dir / rid):
            try:
                return p.stat().st_ctime
            except OSError:
                continue
        return 0.0

    return sorted(ids, key=started, reverse=True)


def runs_table(ws: Workspace) -> pd.DataFrame:
    """`rl.runs.list_runs` with the launcher's view of each state ('starting', 'lost'), newest first,
    plus launched runs that have no run folder yet."""
    from rl.runs import list_runs

    table = list_runs(ws)
    known = set(table["run_id"])
    extra = []
    for rid in run_ids(ws):
        if rid in known:
            continue
        req = (read_json(jobs_dir(ws) / f"{rid}.json") or {}).get("request", {})
        extra.append({"run_id": rid, "target_kind": req.get("target"), "target": req.get("name"),
                      "reward": req.get("reward"), "lines_source": req.get("lines"), "seed": req.get("seed"),
                      **{k: v for k, v in run_status(ws, rid).items() if k in table.columns}})
    if extra:
        table = pd.concat([table, pd.DataFrame(extra, columns=table.columns)], ignore_index=True)
    if len(table):
        status = {rid: run_status(ws, rid) for rid in table["run_id"]}
        table["state"] = [status[r].get("state") for r in table["run_id"]]
        table["message"] = [status[r].get("message") for r in table["run_id"]]
    order = {rid: i for i, rid in enumerate(run_ids(ws))}
    return table.sort_values("run_id", key=lambda s: s.map(order)).reset_index(drop=True)
