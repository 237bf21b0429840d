"""Background jobs launched from the dashboard: a `laneprint train` subprocess per run,
a `laneprint crossval --run RUN_ID` subprocess per cross-validation.

The process gets its own session (`start_new_session=True`), so it outlives page
reloads, closed browsers and even the dashboard server; everything the pages show
about a training run is read back from the run folder (`runs/<run_id>/status.json`,
`metrics.jsonl`, ...) that the trainer writes. The dashboard itself only keeps,
under `dashboard/jobs/`, the command it ran, the pid and the process's output, so a
run that dies before writing its status still shows why.

Cross-validations keep the same three things under `dashboard/crossval_jobs/`
(`<job_id>.json`, `<job_id>.log`). `laneprint crossval` writes no status file while
it works, so its progress is read from its own progress bar in the log (the process
is told its output is a terminal, so the bar is redrawn there), and its end from the
`stored as crossval/<id>` line and that folder's `result.json`.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import uuid
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pandas as pd

from laneprint.processes import laneprint_process_alive
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
    cmd = [
        sys.executable,
        "-m",
        "laneprint.app.cli",
        "train",
        f"--{req.target}",
        req.name,
        "--episodes",
        str(int(req.episodes)),
        "--seed",
        str(int(req.seed)),
        "--run-id",
        run_id,
        "--workspace",
        str(workspace),
    ]
    if req.reward:
        cmd += ["--reward", req.reward]
    if req.lines:
        cmd += ["--lines", req.lines]
    for opt, value in req.options.items():
        cmd += [opt, str(value)]
    return cmd


def identical_active_run(ws: Workspace, req: TrainRequest) -> str:
    """Why `req` should not start: a run launched with exactly this request is still starting or
    running ('' when none is)."""
    want = asdict(req)
    for path in jobs_dir(ws).glob("*.json"):
        job = read_json(path) or {}
        if job.get("request") == json.loads(json.dumps(want)):
            rid = job.get("run_id") or path.stem
            if run_status(ws, rid).get("state") in ACTIVE_STATES:
                return (
                    f"run {rid} with the same target, episodes, seed and settings is already under way "
                    "(change the seed to train a second agent)"
                )
    return ""


def jobs_dir(ws: Workspace) -> Path:
    return ws.root / "dashboard" / "jobs"


def launch(ws: Workspace, req: TrainRequest, run_id: str | None = None) -> str:
    """Start a training process for `req`; returns its run id at once."""
    run_id = run_id or new_run_id(req)
    cmd = train_command(req, ws.root, run_id)
    _spawn(jobs_dir(ws), run_id, cmd, ws.root, {"run_id": run_id, "request": asdict(req)})
    return run_id


def _spawn(
    folder: Path, job_id: str, cmd: list[str], cwd: Path, record: dict[str, Any], env: dict[str, str] | None = None
) -> int:
    """Start `cmd` in its own session, output to `folder/<job_id>.log`; record it in `<job_id>.json`."""
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / f"{job_id}.log", "wb") as log:
        proc = subprocess.Popen(
            cmd,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
            cwd=cwd,
            env=env,
        )
    _CHILDREN[proc.pid] = proc
    atomic_write_json(
        folder / f"{job_id}.json",
        {
            **record,
            "pid": proc.pid,
            "command": cmd,
            "launched_at": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        },
    )
    return proc.pid


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
    return laneprint_process_alive(pid)


def read_json(path: Path) -> dict[str, Any] | None:
    """A JSON file, or None when missing or half-written."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def terminal_log_tail(path: Path, n_chars: int = 2000) -> str:
    """The readable end of a process's output drawn for a terminal: codes removed, the last redraw of each line."""
    text = _ANSI.sub("", _file_tail(path, 20 * n_chars))
    lines = [ln.rstrip() for ln in re.split(r"\r?\n", text)]
    lines = [ln.split("\r")[-1] for ln in lines if ln.strip()]
    return "\n".join(lines)[-n_chars:]


def _file_tail(path: Path, n_chars: int) -> str:
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - n_chars))
            data = fh.read()
    except OSError:
        return ""
    return data.decode(errors="replace")


def log_tail(ws: Workspace, run_id: str, n_chars: int = 2000) -> str:
    """The end of a launched run's process output ('' when none)."""
    return _file_tail(jobs_dir(ws) / f"{run_id}.log", n_chars)


def run_status(ws: Workspace, run_id: str) -> dict[str, Any]:
    """The run's status.json, completed with what the launcher knows.

    States: 'starting' (launched, no status yet), 'running', 'done', 'failed',
    'cancelled', plus 'interrupted' for a run marked running whose process no longer
    holds the run's lock (killed: `rl.runs.run_state`).
    """
    from rl.runs import mark_interrupted, run_state

    job = read_json(jobs_dir(ws) / f"{run_id}.json") or {}
    status = mark_interrupted(ws.runs_dir / run_id, read_json(ws.runs_dir / run_id / "status.json"))
    if status is None:
        if job and pid_alive(job.get("pid")):
            return {
                "state": "starting",
                "pid": job.get("pid"),
                "episode": 0,
                "episodes": job.get("request", {}).get("episodes"),
                "message": "starting",
            }
        state = run_state(ws.runs_dir / run_id, None)  # a run folder: 'starting', or 'interrupted' (killed)
        if state == "interrupted":
            return {
                "state": state,
                "episode": 0,
                "episodes": job.get("request", {}).get("episodes"),
                "message": f"interrupted before its first status; resume with `laneprint train --resume {run_id}`",
                "log": log_tail(ws, run_id),
            }
        if job:
            return {
                "state": "failed",
                "pid": job.get("pid"),
                "episode": 0,
                "episodes": job.get("request", {}).get("episodes"),
                "message": "the training process ended before writing its status",
                "log": log_tail(ws, run_id),
            }
        return {"state": state or "unknown", "message": "no status.json"}
    status = dict(status)
    state = run_state(ws.runs_dir / run_id, status)
    if state == "interrupted" and status.get("state") == "running":
        # the trainer may have just finished (it drops its lock after its last status): re-read once
        status = dict(read_json(ws.runs_dir / run_id / "status.json") or status)
        state = run_state(ws.runs_dir / run_id, status)
    if state == "interrupted":
        status["message"] = (
            f"interrupted at episode {status.get('episode', 0)} (the process died); "
            f"resume with `laneprint train --resume {run_id}`"
        )
        status["log"] = log_tail(ws, run_id)
    status["state"] = state
    return status


def cancel(ws: Workspace, run_id: str) -> bool:
    """Ask a running run to stop (SIGTERM: the trainer checkpoints and marks it cancelled)."""
    st = run_status(ws, run_id)
    pid = st.get("pid")
    if st.get("state") not in ACTIVE_STATES or pid is None or not pid_alive(pid):
        return False
    try:
        os.kill(int(pid), signal.SIGTERM)
    except ProcessLookupError:
        return False
    return True


def in_fleet(ws: Workspace, run_id: str) -> bool:
    """True if the run was trained as part of a fleet (its config.json names a `fleet_id`)."""
    return bool((read_json(ws.runs_dir / run_id / "config.json") or {}).get("fleet_id"))


def run_ids(ws: Workspace) -> list[str]:
    """Run folders and launched jobs, newest first."""
    ids = {p.name for p in ws.runs_dir.glob("*") if p.is_dir() and not p.name.startswith(".")}
    ids |= {p.stem for p in jobs_dir(ws).glob("*.json")}

    def started(rid: str) -> float:
        # config.json is written when a run starts (or resumes); a folder's or status's ctime also moves
        # when a lock file or a cross-validation appears in it, which made an old run "newest"
        for p in (ws.runs_dir / rid / "config.json", jobs_dir(ws) / f"{rid}.json", ws.runs_dir / rid):
            try:
                return p.stat().st_mtime
            except OSError:
                continue
        return 0.0

    return sorted(ids, key=started, reverse=True)


def runs_table(ws: Workspace) -> pd.DataFrame:
    """`rl.runs.list_runs` with the launcher's view of each state ('starting', 'interrupted'), newest first,
    plus launched runs that have no run folder yet."""
    from rl.runs import list_runs

    table = list_runs(ws)
    known = set(table["run_id"])
    extra = []
    for rid in run_ids(ws):
        if rid in known:
            continue
        req = (read_json(jobs_dir(ws) / f"{rid}.json") or {}).get("request", {})
        extra.append(
            {
                "run_id": rid,
                "target_kind": req.get("target"),
                "target": req.get("name"),
                "reward": req.get("reward"),
                "lines_source": req.get("lines"),
                "seed": req.get("seed"),
                **{k: v for k, v in run_status(ws, rid).items() if k in table.columns},
            }
        )
    if extra:
        table = pd.concat([table, pd.DataFrame(extra, columns=table.columns)], ignore_index=True)
    if len(table):
        status = {rid: run_status(ws, rid) for rid in table["run_id"]}
        table["state"] = [status[r].get("state") for r in table["run_id"]]
        table["message"] = [status[r].get("message") for r in table["run_id"]]
    order = {rid: i for i, rid in enumerate(run_ids(ws))}
    return table.sort_values("run_id", key=lambda s: s.map(order)).reset_index(drop=True)


# --- cross-validations: `laneprint crossval --run RUN_ID` ---------------------------------


@dataclass(frozen=True)
class CrossvalRequest:
    """What the Cross-validate button asks for; turned into a `laneprint crossval --run` command line."""

    run_id: str
    """The trained run whose target, reward, scenes and trainer settings are cross-validated."""
    folds: int = 4
    """K: the target's sessions are split into K folds."""
    split: str = "session"
    """'session' (each driver's sessions dealt to the folds) or 'section' (speed sections held out)."""
    seed: int = 0
    """Seed of the folds, the bootstrap and the imitation classifier."""
    episodes: int | None = None
    """Training episodes of each fold's agent (None: the run's own)."""
    bootstrap: int = 1000
    """Bootstrap resamples for the 95 % intervals."""


def crossval_command(req: CrossvalRequest, workspace: Path) -> list[str]:
    """The `laneprint crossval --run` command line for `req` (run with this interpreter)."""
    cmd = [
        sys.executable,
        "-m",
        "laneprint.app.cli",
        "crossval",
        "--run",
        req.run_id,
        "--folds",
        str(int(req.folds)),
        "--split",
        req.split,
        "--seed",
        str(int(req.seed)),
        "--bootstrap",
        str(int(req.bootstrap)),
    ]
    if req.episodes is not None:
        cmd += ["--episodes", str(int(req.episodes))]
    return cmd + ["--workspace", str(workspace)]


#: Rich draws its progress bar into a file only when told it is a terminal; no colours, a fixed width.
CROSSVAL_ENV = {"TTY_COMPATIBLE": "1", "TTY_INTERACTIVE": "1", "NO_COLOR": "1", "COLUMNS": "120", "TERM": "xterm"}


def crossval_jobs_dir(ws: Workspace) -> Path:
    return ws.root / "dashboard" / "crossval_jobs"


def new_crossval_job_id(run_id: str) -> str:
    """`<run_id>-cv-<UTC time>-<4 hex>` (file-name safe)."""
    stem = "".join(c if c.isalnum() or c in "-_" else "_" for c in run_id)[:48] or "run"
    return f"{stem}-cv-{datetime.now(timezone.utc):%Y%m%d-%H%M%S}-{uuid.uuid4().hex[:4]}"


def launch_crossval(ws: Workspace, req: CrossvalRequest) -> str:
    """Start `laneprint crossval --run` for `req` in the background; returns its job id at once."""
    job_id = new_crossval_job_id(req.run_id)
    _spawn(
        crossval_jobs_dir(ws),
        job_id,
        crossval_command(req, ws.root),
        ws.root,
        {"job_id": job_id, "run_id": req.run_id, "request": asdict(req)},
        env={**os.environ, **CROSSVAL_ENV},
    )
    return job_id


_ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]|\x1b\][^\x07]*\x07")
#: 'fold 2/4: agent ━━━━━━━╸      383/1000 0:00:07' (the elapsed time: a whole redraw, not a half-written one)
_FOLD = re.compile(r"fold (\d+)/(\d+): ([a-z_ ]+?)\s*[━╸╺╾╼\s]*(\d+)/(\d+|\?)(?=\s+\d+:\d\d)")
_STORED = re.compile(r"stored as crossval/(\S+)")


def crossval_progress(log: str) -> dict[str, Any]:
    """What the end of a `laneprint crossval` output says: the fold and step reached, the stored id, an error.

    Keys (each only when found): `fold` (1-based), `folds`, `step` (what the fold is
    doing: 'agent'), `done`, `total` (its episodes), `fraction` (of the whole job,
    counting each fold's agent training), `crossval_id`, `error`.
    """
    text = _ANSI.sub("", log)
    out: dict[str, Any] = {}
    found = list(_FOLD.finditer(text))
    if found:
        m = found[-1]
        fold, folds, done = int(m.group(1)), int(m.group(2)), int(m.group(4))
        total = int(m.group(5)) if m.group(5) != "?" else 0
        within = min(1.0, done / total) if total else 0.0
        out.update(
            fold=fold,
            folds=folds,
            step=m.group(3).strip(),
            done=done,
            total=total,
            fraction=min(1.0, (fold - 1 + within) / folds) if folds else 0.0,
        )
    stored = _STORED.findall(text)
    if stored:
        out["crossval_id"] = stored[-1]
    errors = [ln.strip() for ln in re.split(r"[\r\n]", text) if ln.strip().startswith("error:")]
    if errors:
        out["error"] = errors[-1]
    return out


def crossval_log_tail(ws: Workspace, job_id: str, n_chars: int = 2000) -> str:
    """The readable end of a cross-validation's output: terminal codes removed, the last redraw of each line."""
    return terminal_log_tail(crossval_jobs_dir(ws) / f"{job_id}.log", n_chars)


def crossval_status(ws: Workspace, job_id: str) -> dict[str, Any]:
    """State and progress of a launched cross-validation.

    States: 'starting' (no progress drawn yet), 'running', 'done' (its result is
    stored: `crossval_id`), 'failed' (ended without storing one: `message`, `log`),
    'cancelled', 'unknown' (no such job).
    """
    folder = crossval_jobs_dir(ws)
    job = read_json(folder / f"{job_id}.json")
    if job is None:
        return {"job_id": job_id, "state": "unknown", "message": "no such cross-validation job"}
    prog = crossval_progress(_file_tail(folder / f"{job_id}.log", 16_000))
    out = {
        "job_id": job_id,
        "run_id": job.get("run_id"),
        "pid": job.get("pid"),
        "launched_at": job.get("launched_at"),
        "request": job.get("request", {}),
        **prog,
    }
    out.setdefault("fraction", 0.0)
    if pid_alive(job.get("pid")):
        if "fold" not in prog:
            out.update(state="starting", message="reading the run and the analysis")
        elif prog["total"] and prog["done"] >= prog["total"]:
            out.update(
                state="running",
                fraction=min(out["fraction"], 0.99),
                message=f"fold {prog['fold']}/{prog['folds']}: agent trained; fitting the imitation "
                "classifier and scoring the held-out sessions",
            )
        else:
            out.update(
                state="running",
                message=f"fold {prog['fold']}/{prog['folds']}: training the "
                f"{prog['step']}, episode {prog['done']}/{prog['total'] or '?'}",
            )
        return out
    cv_id = prog.get("crossval_id")
    if cv_id and (ws.root / "crossval" / cv_id / "result.json").exists():
        out.update(state="done", fraction=1.0, message=f"stored as crossval/{cv_id}")
    elif job.get("cancelled_at"):
        out.update(state="cancelled", message=f"cancelled at {job['cancelled_at']}")
    else:
        out.update(
            state="failed",
            message=prog.get("error") or "the process ended without storing a result",
            log=crossval_log_tail(ws, job_id),
        )
    return out


def crossval_job_ids(ws: Workspace, run_id: str | None = None) -> list[str]:
    """Launched cross-validations (of one run, when given), newest first."""
    jobs = []
    for path in crossval_jobs_dir(ws).glob("*.json"):
        job = read_json(path) or {}
        if run_id is None or job.get("run_id") == run_id:
            jobs.append((str(job.get("launched_at") or ""), path.stem))
    return [jid for _, jid in sorted(jobs, reverse=True)]


def active_crossvals(ws: Workspace, run_id: str | None = None) -> list[str]:
    """Cross-validations still working (of one run, when given), newest first."""
    return [j for j in crossval_job_ids(ws, run_id) if crossval_status(ws, j)["state"] in ACTIVE_STATES]


def cancel_crossval(ws: Workspace, job_id: str) -> bool:
    """Stop a working cross-validation (SIGTERM; nothing is stored, the job is marked cancelled)."""
    path = crossval_jobs_dir(ws) / f"{job_id}.json"
    job = read_json(path)
    if not job or crossval_status(ws, job_id)["state"] not in ACTIVE_STATES or not pid_alive(job.get("pid")):
        return False
    atomic_write_json(path, {**job, "cancelled_at": datetime.now(timezone.utc).isoformat(timespec="seconds")})
    try:
        os.kill(int(job["pid"]), signal.SIGTERM)
    except ProcessLookupError:
        return False
    return True


# --- fleets: `laneprint train --drivers all | --styles all --seeds N` ----------------------


@dataclass(frozen=True)
class FleetRequest:
    """What the fleet form asks for; turned into a `laneprint train --drivers/--styles` command line."""

    kind: str
    """'drivers' or 'styles'."""
    episodes: int
    """Training episodes of each agent."""
    seeds: int = 1
    """Agents per target (seeds 0..N-1)."""
    names: tuple[str, ...] = ()
    """Targets by name; empty: all of them."""
    backend: str = "local"
    """'local' (batched in one process) or 'ray'."""


def fleet_command(req: FleetRequest, workspace: Path) -> list[str]:
    """The `laneprint train --drivers all|IDS | --styles all` command line for `req` (run with this interpreter)."""
    if req.kind not in ("drivers", "styles"):
        raise ValueError(f"kind must be 'drivers' or 'styles', not {req.kind!r}")
    if req.backend not in ("local", "ray"):
        raise ValueError(f"backend must be 'local' or 'ray', not {req.backend!r}")
    cmd = [
        sys.executable,
        "-m",
        "laneprint.app.cli",
        "train",
        f"--{req.kind}",
        ",".join(req.names) or "all",
        "--seeds",
        str(int(req.seeds)),
        "--episodes",
        str(int(req.episodes)),
    ]
    if req.backend != "local":  # the trainer's default; older trainers know no --backend
        cmd += ["--backend", req.backend]
    return cmd + ["--workspace", str(workspace)]


def fleet_jobs_dir(ws: Workspace) -> Path:
    return ws.root / "dashboard" / "fleet_jobs"


def launch_fleet(ws: Workspace, req: FleetRequest) -> str:
    """Start a fleet's training in the background; returns its job id at once (the fleet's own id
    is known once the trainer writes `fleets/<id>/fleet.json` with this process's pid)."""
    job_id = f"fleet-{req.kind}-{datetime.now(timezone.utc):%Y%m%d-%H%M%S}-{uuid.uuid4().hex[:4]}"
    _spawn(
        fleet_jobs_dir(ws),
        job_id,
        fleet_command(req, ws.root),
        ws.root,
        {"job_id": job_id, "request": asdict(req)},
        env={**os.environ, **CROSSVAL_ENV},
    )
    return job_id


def fleet_job_ids(ws: Workspace) -> list[str]:
    """Launched fleets, newest first."""
    jobs = [(str((read_json(p) or {}).get("launched_at") or ""), p.stem) for p in fleet_jobs_dir(ws).glob("*.json")]
    return [jid for _, jid in sorted(jobs, reverse=True)]


def fleet_job_status(ws: Workspace, job_id: str) -> dict[str, Any]:
    """State of a launched fleet: the fleet's own (`rl.fleet.store`), or 'starting' / 'failed' before it has one.

    Keys: job_id, pid, request, state, message, fleet_id (once known), log (when failed).
    """
    from rl.fleet.store import fleet_of_pid, load_fleet

    path = fleet_jobs_dir(ws) / f"{job_id}.json"
    job = read_json(path)
    if job is None:
        return {"job_id": job_id, "state": "unknown", "message": "no such fleet job"}
    out = {
        "job_id": job_id,
        "pid": job.get("pid"),
        "request": job.get("request", {}),
        "launched_at": job.get("launched_at"),
        "fleet_id": job.get("fleet_id"),
    }
    if out["fleet_id"] is None:
        out["fleet_id"] = fleet_of_pid(ws, job.get("pid"))
        if out["fleet_id"]:
            atomic_write_json(path, {**job, "fleet_id": out["fleet_id"]})  # found once, kept
    alive = pid_alive(job.get("pid"))  # also reaps the finished child, so it reads as gone
    if out["fleet_id"]:
        fleet = load_fleet(ws, out["fleet_id"])
        state = fleet["state_read"]
        out.update(state="starting" if state == "created" else state, message=fleet.get("message") or "")
        if out["state"] == "interrupted":
            out["log"] = terminal_log_tail(fleet_jobs_dir(ws) / f"{job_id}.log")
        return out
    if alive:
        return {**out, "state": "starting", "message": "reading the analysis and setting up the agents"}
    return {
        **out,
        "state": "failed",
        "message": "the trainer ended before writing its fleet.json",
        "log": terminal_log_tail(fleet_jobs_dir(ws) / f"{job_id}.log"),
    }


def active_fleet_jobs(ws: Workspace) -> list[str]:
    """Fleets still starting or training, newest first."""
    return [j for j in fleet_job_ids(ws) if fleet_job_status(ws, j)["state"] in ACTIVE_STATES]


def cancel_fleet(ws: Workspace, job_id: str) -> bool:
    """Stop a training fleet (SIGTERM: the trainer checkpoints its agents and marks the fleet cancelled)."""
    st = fleet_job_status(ws, job_id)
    if st["state"] not in ACTIVE_STATES or not pid_alive(st.get("pid")):
        return False
    try:
        os.kill(int(st["pid"]), signal.SIGTERM)
    except ProcessLookupError:
        return False
    return True


# --- downloads: a run's policy and the study's report -------------------------------------


def onnx_missing() -> str | None:
    """What to install for the ONNX export when onnx or onnxruntime is missing, else None (found without
    importing them or torch: the page calls it on every run)."""
    from importlib.util import find_spec

    if find_spec("onnx") and find_spec("onnxruntime"):
        return None
    from rl.deploy.export import ONNX_HINT

    return ONNX_HINT


def policy_is_current(ws: Workspace, run_id: str) -> bool:
    """True when `exports/<run_id>/policy.onnx` exists and is not older than the run's weights."""
    onnx = ws.root / "exports" / run_id / "policy.onnx"
    weights = ws.runs_dir / run_id / "weights.pt"
    return onnx.exists() and not (weights.exists() and onnx.stat().st_mtime < weights.stat().st_mtime)


def export_policy(ws: Workspace, run_id: str) -> str | None:
    """Export the run's policy (`laneprint export RUN_ID`); None when it worked, else why not, in one line
    (the page shows it: a download that fails must say why on the page, not only in the server's log)."""
    from laneprint.errors import UserError
    from rl.deploy.export import export_run

    if (hint := onnx_missing()) is not None:
        return hint
    try:
        export_run(ws, run_id)
    except UserError as exc:
        return str(exc)
    except Exception as exc:  # noqa: BLE001 - shown on the page with its type
        return f"the export failed: {type(exc).__name__}: {exc}"
    return None


def policy_zip(ws: Workspace, run_id: str) -> bytes:
    """The run's ONNX policy with policy.json and README.md as a zip: `laneprint export`'s folder
    (`exports/<run_id>/`), exported first when it is missing or older than the run's weights."""
    import io
    import zipfile

    from rl.deploy.export import export_run

    folder = ws.root / "exports" / run_id
    weights = ws.runs_dir / run_id / "weights.pt"
    onnx = folder / "policy.onnx"
    if not onnx.exists() or (weights.exists() and onnx.stat().st_mtime < weights.stat().st_mtime):
        export_run(ws, run_id)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in ("policy.onnx", "policy.json", "README.md"):
            if (folder / name).exists():
                zf.write(folder / name, f"{run_id}/{name}")
    return buf.getvalue()


def report_bytes(ws: Workspace) -> bytes:
    """`laneprint report` of the workspace as one HTML file's bytes."""
    from dashboard.report import report_html

    return report_html(ws).encode()
