"""Crash safety you can show: run real `laneprint` commands on a workspace, SIGKILL them at a
random (seeded) moment of their work, then prove the workspace is whole and the work can go on.

One kill (`kill_once`), on a fresh copy of a prepared workspace:

1. start the command as a subprocess and SIGKILL it once it has used a drawn amount of CPU
   time: start-up plus a uniform fraction of the command's own work, measured in CPU seconds
   (`calibrate`). CPU time, unlike wall time, hardly depends on how loaded the machine is, so
   the kill lands in a live process; when the command still finished first, that attempt is
   not a kill: it is a fresh measurement of the command, and the kill is drawn again from it
   (`plan_kill`, at most `RETRIES` times);
2. `laneprint check --repair --json`: a ``problem`` finding means the kill left the
   workspace inconsistent; leftovers of the interrupted writes are removed and counted;
3. every run that was training must be listed as 'interrupted' (never 'running') by
   `laneprint runs --json` and by the dashboard's run table;
4. recovery, with a timeout (a stale lock would make it wait): each interrupted run is
   resumed with `laneprint train --resume RUN_ID` (from its last checkpoint), and the
   command is run again when nothing was resumed;
5. the check (`laneprint.app.check.check_workspace`, in this process) must be clean, and the command's own postcondition must hold
   (`Command.verify`: e.g. every held-back log stored once, a resumed run's metrics
   numbered 1..N with no gap or repeat).

A new command is one entry of `COMMANDS`: its arguments, and optionally a postcondition and its
own recovery (a fleet resumes as a whole: `train --resume FLEET_ID`).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np


@dataclass(frozen=True)
class Context:
    """What a command's arguments may refer to."""

    logs: Path  # held-back logs (not in the base workspace) for `ingest`
    driver: str  # a driver of the base workspace
    tag: str  # unique per kill (run ids)


@dataclass(frozen=True)
class Command:
    """A laneprint command to kill: its arguments (after `laneprint`, before `-w WS --json`)."""

    args: Callable[[Context], list[str]]
    verify: Callable[[Path, Context], list[str]] = lambda ws, ctx: []  # postcondition failures after recovery
    trains: bool = False  # writes run folders (checked for 'interrupted' and resumed)
    resume: Callable[[Path], list[list[str]]] | None = None  # its own recovery commands, when it has any to give


def _held_back_stored(ws: Path, ctx: Context) -> list[str]:
    """Every held-back log is a recording, stored once (by content hash)."""
    from laneprint.workspace import content_id

    missing = [
        p.name
        for p in sorted(ctx.logs.iterdir())
        if not (ws / "recordings" / content_id(p.read_bytes()) / "meta.parquet").exists()
    ]
    return [f"held-back log {m} not stored" for m in missing]


def _analysis_current(ws: Path, ctx: Context) -> list[str]:
    from laneprint.workspace import Workspace

    meta = Workspace(ws).read_meta("analysis")
    return [] if meta.get("data_fingerprint") == Workspace(ws).fingerprint() else ["analysis missing or stale"]


def _runs_complete(ws: Path, ctx: Context) -> list[str]:
    """Every run done, its metrics numbered 1..N exactly once."""
    from rl.runs import read_metrics

    out = []
    for cfg in sorted((ws / "runs").glob("*/config.json")):
        status = json.loads((cfg.parent / "status.json").read_text())
        n = int(json.loads(cfg.read_text())["dqn"]["episodes"])
        eps = read_metrics(cfg.parent / "metrics.jsonl").get("episode")
        if status["state"] != "done" or eps is None or list(eps) != list(range(1, n + 1)):
            out.append(f"run {cfg.parent.name}: state {status['state']}, metrics not 1..{n}")
    return out


def _crossval_stored(ws: Path, ctx: Context) -> list[str]:
    return [] if list((ws / "crossval").glob("*/result.json")) else ["no cross-validation stored"]


def _resume_fleets(ws: Path) -> list[list[str]]:
    """`train --resume FLEET_ID` for each fleet of the workspace (none when killed before its fleet.json)."""
    return [["train", "--resume", p.parent.name] for p in sorted((ws / "fleets").glob("*/fleet.json"))]


# one line per command
COMMANDS: dict[str, Command] = {
    "ingest": Command(lambda c: ["ingest", str(c.logs)], _held_back_stored),
    "analyze": Command(lambda c: ["analyze"], _analysis_current),
    "train": Command(
        lambda c: [
            "train",
            "--driver",
            c.driver,
            "--episodes",
            "1000",
            "--checkpoint-every",
            "100",
            "--run-id",
            f"crash-{c.tag}",
        ],
        _runs_complete,
        trains=True,
    ),
    "crossval": Command(
        lambda c: ["crossval", "--driver", c.driver, "--episodes", "10", "--folds", "2", "--bootstrap", "10"],
        _crossval_stored,
    ),
    "fleet": Command(
        lambda c: ["train", "--drivers", "all", "--episodes", "1000", "--checkpoint-every", "100"],
        _runs_complete,
        trains=True,
        resume=_resume_fleets,
    ),
}


def laneprint(args: list[str], ws: Path, timeout: float | None = None) -> subprocess.CompletedProcess:
    """Run `laneprint ARGS -w WS --json` to the end (as the user would, in a subprocess)."""
    return subprocess.run(
        [sys.executable, "-m", "laneprint.app.cli", *args, "-w", str(ws), "--json"],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _json(proc: subprocess.CompletedProcess) -> dict[str, Any]:
    try:
        return json.loads(proc.stdout)
    except ValueError:
        return {}


RETRIES = 5  # attempts that finish before their kill point, redrawn (not counted as kills)


@dataclass
class KillResult:
    """What one kill did and what was found after it."""

    command: str
    delay_s: float  # wall seconds from the start to the kill
    finished_before_kill: bool  # every attempt finished first: no live process was killed
    cpu_s: float = 0.0  # CPU seconds the process had used when killed
    work_fraction: float = 0.0  # the drawn moment: fraction of the command's work (after start-up) done
    retries: int = 0  # attempts that finished before their kill point (each a fresh measurement)
    problems: list[str] = field(default_factory=list)  # inconsistencies (check problems, failed recovery)
    repaired: int = 0
    interrupted_runs: list[str] = field(default_factory=list)
    resumed: dict[str, int] = field(default_factory=dict)  # run id -> episode it resumed from
    recovery_s: float = 0.0

    @property
    def live(self) -> bool:
        """The SIGKILL hit a process still at work."""
        return not self.finished_before_kill

    @property
    def consistent(self) -> bool:
        return not self.problems


@dataclass(frozen=True)
class Attempt:
    """One start of a command: killed at its kill point, or finished before it."""

    finished: bool
    cpu_s: float  # CPU seconds used: at the kill, or in all when it finished
    wall_s: float
    returncode: int


_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of a live process, all its threads (Linux /proc); None if unreadable."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / _TICK  # utime, stime (fields 14 and 15 of stat)


def run_until(
    argv: list[str],
    at_cpu_s: float,
    ws: Path | None = None,
    after: Callable[[Path], bool] | None = None,
    poll_s: float = 0.02,
) -> Attempt:
    """Start `argv` and SIGKILL it once it has used `at_cpu_s` CPU seconds and `after(ws)` holds
    (no kill when `at_cpu_s` is infinite); where /proc cannot tell CPU time, wall time stands in."""
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    t0 = time.monotonic()
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:  # finished: its own rusage is the exact CPU time it needed
            proc.returncode = os.waitstatus_to_exitcode(status)
            return Attempt(True, usage.ru_utime + usage.ru_stime, time.monotonic() - t0, proc.returncode)
        used = cpu_seconds(proc.pid)
        used = time.monotonic() - t0 if used is None else used
        if used >= at_cpu_s and (after is None or after(ws)):
            os.kill(proc.pid, signal.SIGKILL)
            _, status, _ = os.wait4(proc.pid, 0)
            proc.returncode = os.waitstatus_to_exitcode(status)
            return Attempt(False, used, time.monotonic() - t0, proc.returncode)
        time.sleep(poll_s)


def _argv(cmd: Command, ctx: Context, ws: Path) -> list[str]:
    return [sys.executable, "-m", "laneprint.app.cli", *cmd.args(ctx), "-w", str(ws), "--json"]


def calibrate(base: Path, ctx: Context, names: list[str], scratch: Path) -> tuple[float, dict[str, float]]:
    """CPU seconds of the CLI's start-up (`laneprint --help`) and of each command, untouched, on a copy
    of the base workspace."""
    startup = run_until([sys.executable, "-m", "laneprint.app.cli", "--help"], float("inf")).cpu_s
    out = {}
    for name in names:
        ws = scratch / f"calibrate-{name}"
        shutil.copytree(base, ws)
        cal = Context(ctx.logs, ctx.driver, f"cal-{name}")
        run = run_until(_argv(COMMANDS[name], cal, ws), float("inf"))
        if run.returncode != 0:
            err = laneprint(COMMANDS[name].args(cal), ws).stderr.strip()[-300:]
            raise RuntimeError(f"`laneprint {name}` fails without a kill (exit {run.returncode}): {err}")
        out[name] = run.cpu_s
        shutil.rmtree(ws)
    return startup, out


def plan_kill(rng: np.random.Generator, startup_s: float, work_s: float) -> tuple[float, float]:
    """A moment drawn uniformly over the middle 90 % of a command's work: (fraction, CPU seconds)."""
    f = float(rng.uniform(0.05, 0.95))
    return f, startup_s + f * max(work_s - startup_s, 0.0)


def kill_live(
    start: Callable[[float], Attempt], rng: np.random.Generator, startup_s: float, work_s: float
) -> tuple[Attempt, float, float, int]:
    """Start a command (`start(at_cpu_s)`, each time afresh) until one attempt is killed while live,
    at most `RETRIES` + 1 times: an attempt that finished first is a fresh measurement of its work,
    the next moment is drawn from it. Returns the last attempt, its drawn fraction, the work
    estimate (CPU s) and the number of attempts that finished first (redrawn, not kills)."""
    for retry in range(RETRIES + 1):  # noqa: B007 - returned after the loop
        fraction, at = plan_kill(rng, startup_s, work_s)
        attempt = start(at)
        if not attempt.finished:
            break
        if attempt.returncode == 0:
            work_s = attempt.cpu_s
    return attempt, fraction, work_s, retry


def _interrupted_states(ws: Path) -> tuple[dict[str, str], dict[str, str]]:
    """Run states as `laneprint runs --json` and as the dashboard's run table show them."""
    from dashboard.jobs import runs_table
    from laneprint.workspace import Workspace

    cli = {r["run_id"]: r["state"] for r in _json(laneprint(["runs"], ws, timeout=120)).get("runs", [])}
    table = runs_table(Workspace(ws))
    return cli, dict(zip(table["run_id"], table["state"]))


def _checkpoint_episode(path: Path) -> int:
    """Episodes done at a run's last checkpoint (0 without one)."""
    import torch

    return int(torch.load(path, weights_only=True)["counters"]["episodes_done"]) if path.exists() else 0


def kill_once(
    name: str,
    base: Path,
    ctx: Context,
    at_cpu_s: float,
    ws: Path,
    timeout_s: float,
    cmd: Command | None = None,
    after: Callable[[Path], bool] | None = None,
    attempt: Attempt | None = None,
) -> KillResult:
    """Copy `base` to `ws`, kill command `name` (or `cmd`) once it has used `at_cpu_s` CPU seconds (and
    `after(ws)` holds), then check, repair, recover, check again. With `attempt`, the command has
    already been started and killed on `ws` (see `run_kills`)."""
    cmd = cmd or COMMANDS[name]
    if attempt is None:
        shutil.copytree(base, ws)
        attempt = run_until(_argv(cmd, ctx, ws), at_cpu_s, ws, after)
    res = KillResult(name, round(attempt.wall_s, 2), attempt.finished, round(attempt.cpu_s, 2))

    first = laneprint(["check", "--repair"], ws, timeout=timeout_s)
    report = _json(first)
    res.repaired = len(report.get("repaired", []))
    res.problems += [
        f"after the kill: {f['path']}: {f['message']}" for f in report.get("findings", []) if f["kind"] == "problem"
    ]
    if first.returncode != 0 and not res.problems:
        res.problems.append(f"check --repair exit {first.returncode}: {first.stderr.strip()[-200:]}")

    if cmd.trains:
        cli, dash = _interrupted_states(ws)
        res.interrupted_runs = sorted(r for r, s in cli.items() if s == "interrupted")
        for rid, state in cli.items():
            if state == "running":
                res.problems.append(f"run {rid} listed as running after its process was killed")
            if dash.get(rid) != state:
                res.problems.append(f"run {rid}: `laneprint runs` says {state}, the dashboard {dash.get(rid)}")

    t0 = time.monotonic()
    own = cmd.resume(ws) if cmd.resume else []
    try:
        for args in own:  # the command's own resume (a fleet's runs continue from their checkpoints)
            before = {rid: _checkpoint_episode(ws / "runs" / rid / "checkpoint.pt") for rid in res.interrupted_runs}
            out = laneprint(args, ws, timeout=timeout_s)
            if out.returncode != 0:
                res.problems.append(f"`laneprint {' '.join(args)}` failed: {out.stderr.strip()[-200:]}")
            else:
                res.resumed.update(before)
        for rid in [] if own else res.interrupted_runs:
            expected = _checkpoint_episode(ws / "runs" / rid / "checkpoint.pt")
            out = laneprint(["train", "--resume", rid], ws, timeout=timeout_s)
            if out.returncode != 0:
                res.problems.append(f"resume of {rid} failed: {out.stderr.strip()[-200:]}")
                continue
            res.resumed[rid] = int(_json(out).get("resumed_from_episode", -1))
            if res.resumed[rid] != expected:
                res.problems.append(
                    f"run {rid} resumed from episode {res.resumed[rid]}, its checkpoint is at {expected}"
                )
        if not res.resumed and not own:  # a new tag: a command that had finished keeps its run
            out = laneprint(cmd.args(Context(ctx.logs, ctx.driver, ctx.tag + "-again")), ws, timeout=timeout_s)
            if out.returncode != 0:
                res.problems.append(f"re-run failed (exit {out.returncode}): {out.stderr.strip()[-200:]}")
    except subprocess.TimeoutExpired:
        res.problems.append(f"recovery did not finish within {timeout_s:.0f} s (waiting on a lock?)")
    res.recovery_s = round(time.monotonic() - t0, 1)

    from laneprint.app.check import check_workspace
    from laneprint.workspace import Workspace

    final = check_workspace(Workspace(ws))  # what `laneprint check` runs, in this process (saves a start-up)
    res.problems += [
        f"after recovery: {f['kind']} {f['path']}: {f['message']}" for f in final["findings"] if f["kind"] != "note"
    ]
    res.problems += cmd.verify(ws, ctx)
    return res


def prepare(scratch: Path, seed: int, drivers: int = 3, held_back: int = 2) -> tuple[Path, Context]:
    """A base workspace (a simulated study, all but `held_back` logs ingested, analysed) and the
    held-back logs, under `scratch`."""
    study, logs, base = scratch / "study", scratch / "held_back", scratch / "base"
    for args in (["simulate", "--out", str(study), "--drivers", str(drivers), "--seed", str(seed)],):
        out = subprocess.run(
            [sys.executable, "-m", "laneprint.app.cli", *args, "--json"], capture_output=True, text=True
        )
        if out.returncode != 0:
            raise RuntimeError(out.stderr[-300:])
    files = sorted(p for p in study.iterdir() if p.name.endswith((".mcap", ".csv.gz", ".csv")))
    logs.mkdir()
    for p in files[-held_back:]:
        shutil.move(str(p), logs / p.name)
    for args in (["ingest", str(study)], ["analyze"]):
        out = laneprint(args, base)
        if out.returncode != 0:
            raise RuntimeError(out.stderr[-300:])
    return base, Context(logs, "D01", "")


def run_kills(
    names: list[str], kills: int, seed: int, scratch: Path, jobs: int = 1, log: Callable[[str], None] = print
) -> list[KillResult]:
    """`kills` kills spread evenly over `names` (order and moments drawn from `seed`), `jobs` at a time
    (each on its own copy of the workspace)."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(seed)
    base, ctx = prepare(scratch, seed)
    startup, work = calibrate(base, ctx, names, scratch)
    log(f"CPU seconds: start-up {startup:.1f}, " + ", ".join(f"{k} {v:.1f}" for k, v in work.items()))
    plan = [names[i % len(names)] for i in range(kills)]
    rng.shuffle(plan)
    timeout = max(300.0, 20 * max(work.values()))  # wall time, on a machine that may be busy

    def one(i: int) -> KillResult:
        name, ws, kctx = plan[i], scratch / f"kill-{i:03d}", Context(ctx.logs, ctx.driver, f"{i:03d}")
        draws = np.random.default_rng([seed, i])  # this kill's moments, whatever the order kills run in

        def start(at_cpu_s: float) -> Attempt:
            shutil.rmtree(ws, ignore_errors=True)
            shutil.copytree(base, ws)
            return run_until(_argv(COMMANDS[name], kctx, ws), at_cpu_s)

        attempt, fraction, work[name], retry = kill_live(start, draws, startup, work[name])
        res = kill_once(name, base, kctx, attempt.cpu_s, ws, timeout, attempt=attempt)
        res.work_fraction, res.retries = round(fraction, 3), retry
        shutil.rmtree(ws, ignore_errors=True)
        log(
            f"[{i + 1}/{kills}] {res.command} killed at {res.work_fraction:.0%} of its work "
            f"({res.cpu_s} CPU s, {res.delay_s} s)"
            f"{' (had finished: NOT a live kill)' if res.finished_before_kill else ''}"
            f"{f' after {retry} early finish(es)' if retry else ''}: repaired {res.repaired}, "
            f"resumed {res.resumed or '-'}, recovery {res.recovery_s} s, "
            f"{'consistent' if res.consistent else 'INCONSISTENT: ' + '; '.join(res.problems)}"
        )
        return res

    with ThreadPoolExecutor(max(1, jobs)) as pool:
        return list(pool.map(one, range(kills)))
