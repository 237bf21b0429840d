"""Fleets in the workspace: one run folder per (target, seed), trained together.

A fleet is ``fleets/<fleet_id>/fleet.json`` (targets, seeds, its run ids, backend,
state, pid) plus ordinary run folders ``runs/<run_id>/`` whose config.json names
the fleet. `create_fleet` writes them all before any training, so a killed fleet
has every run folder to resume from; `train_fleet` trains the runs that are not
done, in one `FleetTrainer` per shard (one shard locally, one per Ray worker with
``backend='ray'``), streaming each run's metrics, status and checkpoints like a
single run and evaluating each agent as it finishes.

Workers write their runs' folders themselves (every write atomic), so with Ray on
several machines the workspace must be a path every worker sees (a shared file
system); the driver writes fleet.json only.
"""

from __future__ import annotations

import json
import os
import re
import signal
import threading
import time
from contextlib import ExitStack, nullcontext
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pandas as pd
import torch

from laneprint.errors import UserError
from laneprint.locks import FileLock
from laneprint.progress import ProgressFn, report
from laneprint.workspace import Workspace, atomic_write_json
from rl.problem.env import EnvConfig, approaches_from_decisions, formulation_config, replayed_approaches
from rl.fleet.batch import FleetMember, FleetTrainer
from rl.fleet.store import fleet_dir, fleet_table
from rl.runs import (
    Target,
    target_drivers,
    _save_torch,
    _StopFlag,
    _truncate_metrics,
    code_version,
    create_run,
    evaluate_run,
    lock_run,
    now_iso,
    resolve_lines,
    run_dir,
)
from rl.settings import DQNSettings

FLEET_STATES = ("running", "done", "failed", "cancelled")
STATUS_EVERY_S = 2.0  # [s] between status.json writes of a run (more often for small fleets is pointless)


def is_fleet(workspace: Workspace, fleet_id: str) -> bool:
    return (fleet_dir(workspace) / fleet_id / "fleet.json").exists()


def read_fleet(workspace: Workspace, fleet_id: str) -> dict[str, Any]:
    path = fleet_dir(workspace) / fleet_id / "fleet.json"
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        raise UserError(f"no fleet {fleet_id!r} in {workspace.root}") from None


def _write_fleet(workspace: Workspace, fleet: dict[str, Any]) -> None:
    fleet["updated_at"] = now_iso()
    atomic_write_json(fleet_dir(workspace) / fleet["fleet_id"] / "fleet.json", fleet)


def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-") or "x"


def fleet_targets(workspace: Workspace, drivers: str | None = None, styles: str | None = None) -> list[Target]:
    """The targets named by ``--drivers all|ID,ID`` or ``--styles all|NAME,NAME``."""
    if (drivers is None) == (styles is None):
        raise UserError("give exactly one of --drivers all|ID,ID... or --styles all|NAME,NAME...")
    if not workspace.has_table("analysis", "styles"):
        raise UserError(f"no analysis in {workspace.root}: run `laneprint analyze` first")
    table = workspace.read_table("analysis", "styles")
    if drivers is not None:
        known = sorted(table["driver_id"].astype(str).unique())
        kind, wanted = "driver", drivers
    else:
        assert styles is not None  # exactly one of drivers and styles is given (checked above)
        known = list(dict.fromkeys(table["style"].astype(str)))
        kind, wanted = "style", styles
    names = known if wanted.strip().lower() == "all" else [n.strip() for n in wanted.split(",") if n.strip()]
    unknown = [n for n in names if n.lower() not in {k.lower() for k in known}]
    if unknown or not names:
        raise UserError(
            f"unknown {kind}(s) {', '.join(unknown) or '(none given)'}: the analysis has {', '.join(known)}"
        )
    canonical = {k.lower(): k for k in known}
    return [Target(kind, canonical[n.lower()]) for n in dict.fromkeys(names)]


def _approach_counts(workspace: Workspace, targets: list[Target], env: EnvConfig) -> dict[Target, int]:
    """Replayed approaches per target (what `resolved_episodes` scales with: `replayed_approaches`)."""
    decisions = workspace.read_table("analysis", "decisions")
    approaches, _ = approaches_from_decisions(decisions)
    per_driver = (
        pd.Series([a.driver_id for a in approaches for _ in range(replayed_approaches([a], env))])
        .value_counts()
        .to_dict()
    )
    out = {}
    for t in targets:
        drivers, _ = target_drivers(workspace, t)
        out[t] = int(sum(per_driver.get(d, 0) for d in drivers))
    return out


def create_fleet(
    workspace: Workspace,
    targets: list[Target],
    seeds: list[int],
    base: DQNSettings,
    *,
    reward: str | None = None,
    scenes: str | None = None,
    observation: str | None = None,
    other_side: bool | None = None,
    lines_source: str = "analysis",
    dt_s: float | None = None,
    backend: str = "local",
    fleet_id: str | None = None,
) -> dict[str, Any]:
    """Write fleet.json and one run folder per (target, seed); returns the fleet record."""
    workspace.ensure()
    kinds = sorted({t.kind for t in targets})
    fleet_id = fleet_id or f"{datetime.now(timezone.utc):%Y%m%d-%H%M%S}-fleet-{kinds[0]}s-{len(targets) * len(seeds)}"
    if is_fleet(workspace, fleet_id):
        raise UserError(f"fleet {fleet_id!r} exists already (pass --resume {fleet_id} to continue it)")
    common = {
        "fleet_id": fleet_id,
        "code_version": code_version(),
        "data_fingerprint": workspace.fingerprint(),
        "analysis_fingerprint": workspace.analysis_fingerprint(),
    }
    counts = None
    runs = []
    for target in targets:
        env = formulation_config(
            resolve_lines(workspace, target, lines_source), reward, scenes, observation, lines_source, other_side
        )
        if dt_s is not None:
            env = replace(env, dt_s=dt_s)
        if env.scenes == "recorded" and counts is None:
            counts = _approach_counts(workspace, targets, env)
        for seed in seeds:
            settings = replace(base, seed=seed)
            if env.scenes == "recorded":
                assert counts is not None  # counted above for recorded scenes
                if not counts.get(target):
                    raise UserError(
                        f"no recorded approaches for {target.label}: nothing to replay (try --scenes synthetic)"
                    )
                settings = settings.resolved_episodes(counts[target])
            run_id = f"{fleet_id}-{_slug(target.name)}-s{seed}"
            create_run(workspace, target, env, settings, run_id=run_id, lines_source=lines_source, extra=common)
            runs.append(run_id)
    fleet = {
        "fleet_id": fleet_id,
        "created_at": now_iso(),
        "targets": [{"kind": t.kind, "name": t.name} for t in targets],
        "seeds": list(seeds),
        "runs": runs,
        "backend": backend,
        "state": "running",
        "pid": os.getpid(),
        "message": "",
    }
    _write_fleet(workspace, fleet)
    return fleet


# --- one shard: a FleetTrainer over some of the fleet's runs -----------------------------


class _ShardWriter:
    """Metrics, status and checkpoints of a shard's runs, batched so a 1000-agent shard
    does not write 1000 files every step."""

    def __init__(self, workspace: Workspace, run_ids: list[str], episodes: list[int]) -> None:
        self.folders = [run_dir(workspace, r) for r in run_ids]
        self.episodes = episodes
        self.pending: list[list[str]] = [[] for _ in run_ids]
        self.done_episodes = [0] * len(run_ids)
        self.started_at = now_iso()
        self._last = 0.0

    def metric(self, i: int, row: dict[str, Any]) -> None:
        self.pending[i].append(json.dumps(row))
        self.done_episodes[i] = row["episode"]

    def flush(self, i: int) -> None:
        if self.pending[i]:
            with open(self.folders[i] / "metrics.jsonl", "a", encoding="utf-8") as fh:
                fh.write("\n".join(self.pending[i]) + "\n")
            self.pending[i] = []

    def status(self, i: int, state: str, message: str) -> None:
        atomic_write_json(
            self.folders[i] / "status.json",
            {
                "state": state,
                "pid": os.getpid(),
                "episode": int(self.done_episodes[i]),
                "episodes": int(self.episodes[i]),
                "started_at": self.started_at,
                "updated_at": now_iso(),
                "message": message,
            },
        )

    def periodic(self, active: list[int], force: bool = False) -> None:
        """Flush metrics and write 'running' statuses of the active runs, every few seconds."""
        if not force and time.monotonic() - self._last < STATUS_EVERY_S:
            return
        self._last = time.monotonic()
        for i in active:
            self.flush(i)
            self.status(i, "running", "training in a fleet")


def _load_members(workspace: Workspace, run_ids: list[str]) -> tuple[list[FleetMember], list[dict | None]]:
    """Members for the runs (approaches read once) and their checkpoints, if any."""
    decisions = workspace.read_table("analysis", "decisions") if workspace.has_table("analysis", "decisions") else None
    by_driver: dict[str, list] | None = None
    members, states = [], []
    for rid in run_ids:
        folder = run_dir(workspace, rid)
        config = json.loads((folder / "config.json").read_text())
        env = EnvConfig.from_dict(config["env"])
        settings = DQNSettings.from_dict(config["dqn"])
        approaches = None
        if env.scenes == "recorded":
            if decisions is None:
                raise UserError(f"no analysis in {workspace.root}: recorded scenes need `laneprint analyze` first")
            if by_driver is None:
                all_approaches, _ = approaches_from_decisions(decisions)
                by_driver = {}
                for a in all_approaches:
                    by_driver.setdefault(a.driver_id, []).append(a)
            drivers, _ = target_drivers(workspace, Target(**config["target"]))
            approaches = [a for d in drivers for a in by_driver.get(d, [])]
        members.append(FleetMember(env, settings, approaches))
        ckpt = folder / "checkpoint.pt"
        states.append(torch.load(ckpt, weights_only=True) if ckpt.exists() else None)
    return members, states


def _is_done(workspace: Workspace, run_id: str) -> bool:
    folder = run_dir(workspace, run_id)
    try:
        status = json.loads((folder / "status.json").read_text())
    except (OSError, ValueError):
        return False
    return status.get("state") == "done" and (folder / "weights.pt").exists()


def train_shard(
    workspace_root: str,
    run_ids: list[str],
    threads: int = 1,
    evaluate: bool = True,
    progress: ProgressFn | None = None,
    stop: _StopFlag | None = None,
) -> list[dict[str, Any]]:
    """Train the fleet runs `run_ids` (those not done) together; returns one summary per run.

    Runs that have a checkpoint continue from it. On SIGTERM/SIGINT (caught here,
    or by the caller's `stop` when the shard runs in a thread) every active agent
    is checkpointed and its run marked 'cancelled'.
    """
    workspace = Workspace(Path(workspace_root))
    todo = [r for r in run_ids if not _is_done(workspace, r)]
    summaries = [{"run_id": r, "state": "done", "skipped": "done already"} for r in run_ids if r not in todo]
    if not todo:
        return summaries
    with ExitStack() as held:  # each run's lock, for as long as this process trains it (rl.runs.run_state)
        for rid in todo:
            held.callback(lock_run(run_dir(workspace, rid), rid).release)
        return summaries + _train_locked(workspace, todo, threads, evaluate, progress, stop)


def _train_locked(
    workspace: Workspace,
    todo: list[str],
    threads: int,
    evaluate: bool,
    progress: ProgressFn | None,
    stop: _StopFlag | None,
) -> list[dict[str, Any]]:
    """`train_shard`'s work on the runs `todo`, whose locks are held."""
    members, states = _load_members(workspace, todo)
    decisions = (
        workspace.read_table("analysis", "decisions")
        if evaluate and workspace.has_table("analysis", "decisions")
        else None
    )
    classifiers: dict = {}  # one imitation classifier per driver set, shared by its seeds
    for rid, state in zip(todo, states):  # drop metrics written after the checkpoint (all, without one)
        _truncate_metrics(
            run_dir(workspace, rid) / "metrics.jsonl",
            int(state["counters"]["episodes_done"]) if state is not None else 0,
        )
    fleet = FleetTrainer(members, threads=threads, states=states)
    episodes = [s.episodes for s in fleet.settings]
    writer = _ShardWriter(workspace, todo, episodes)
    for i, state in enumerate(states):
        writer.done_episodes[i] = int(state["counters"]["episodes_done"]) if state else 0
        writer.status(i, "running", "resumed in a fleet" if state else "training in a fleet")
    results: dict[int, dict[str, Any]] = {}

    def checkpoint(i: int, state: dict) -> None:
        writer.flush(i)
        _save_torch(writer.folders[i] / "checkpoint.pt", state)

    def finish(i: int, policy: dict, state: dict) -> None:
        checkpoint(i, state)
        _save_torch(writer.folders[i] / "weights.pt", policy)
        config = json.loads((writer.folders[i] / "config.json").read_text())
        summary: dict[str, Any] = {
            "run_id": todo[i],
            "state": "done",
            "target": Target(**config["target"]).label,
            "reward": config["reward"],
            "episodes": int(state["counters"]["episodes_done"]),
            "env_steps": int(state["counters"]["env_steps"]),
            "wall_s": round(fleet.wall_s, 2),
        }
        if evaluate:
            writer.status(i, "running", "evaluating")
            try:
                ev = evaluate_run(workspace, todo[i], decisions=decisions, classifiers=classifiers)
                summary["evaluation"] = ev.get("summary_typical") or ev.get("summary")
            except UserError as exc:
                summary["evaluation_note"] = str(exc)
        writer.status(i, "done", "done")
        results[i] = summary

    def tick(f: FleetTrainer) -> bool:
        writer.periodic([a.member for a in f.agents])
        report(progress, sum(writer.done_episodes), sum(episodes), f"fleet: {len(results)}/{len(todo)} agents done")
        return False

    try:
        with nullcontext(stop) if stop is not None else _StopFlag() as stop:
            fleet.train(
                on_episode=writer.metric,
                on_checkpoint=checkpoint,
                on_finish=finish,
                should_stop=stop,
                on_vector_step=tick,
            )
    except Exception as exc:
        for a in fleet.agents:
            writer.flush(a.member)
            writer.status(a.member, "failed", f"{type(exc).__name__}: {exc}")
        raise
    if fleet.agents:  # stopped by a signal: checkpoint and mark the unfinished runs
        message = f"stopped by signal {signal.Signals(stop.signal).name}" if stop.signal else "stopped"
        for j, a in enumerate(fleet.agents):
            checkpoint(a.member, fleet.agent_state_dict(j))
            writer.status(a.member, "cancelled", message)
            results[a.member] = {
                "run_id": todo[a.member],
                "state": "cancelled",
                "episodes": a.episodes_done,
                "message": message,
            }
    report(progress, sum(writer.done_episodes), sum(episodes), f"fleet: {len(todo)} agents")
    return [results[i] for i in sorted(results)]


# --- the whole fleet ---------------------------------------------------------------------


def shard_runs(run_ids: list[str], n_shards: int) -> list[list[str]]:
    """`run_ids` dealt into `n_shards` shards of near-equal size (round robin)."""
    n = max(1, min(n_shards, len(run_ids)))
    return [run_ids[i::n] for i in range(n)]


def _fleet_progress(
    workspace: Workspace, run_ids: list[str], progress: ProgressFn | None, stop: threading.Event
) -> None:
    """Report summed episodes from the runs' status files until `stop` (for remote workers)."""
    while not stop.wait(1.0):
        done = total = finished = 0
        for rid in run_ids:
            try:
                s = json.loads((run_dir(workspace, rid) / "status.json").read_text())
            except (OSError, ValueError):
                continue
            done += int(s.get("episode") or 0)
            total += int(s.get("episodes") or 0)
            finished += s.get("state") == "done"
        if total:
            report(progress, done, total, f"fleet: {finished}/{len(run_ids)} agents done")


def train_fleet(
    workspace: Workspace,
    fleet_id: str,
    *,
    backend: str = "local",
    ray_address: str | None = None,
    threads: int | None = None,
    evaluate: bool = True,
    progress: ProgressFn | None = None,
) -> dict[str, Any]:
    """Train (or resume) every run of a fleet; returns the fleet record with per-run summaries."""
    from laneprint.parallel import check_backend

    check_backend(backend, ray_address)
    fleet = read_fleet(workspace, fleet_id)
    lock = FileLock(fleet_dir(workspace) / fleet_id / "fleet.lock")  # dies with this process
    if not lock.acquire(blocking=False):
        raise UserError(f"fleet {fleet_id!r} is being trained by another process right now")
    try:
        return _train_fleet(workspace, fleet, backend, ray_address, threads, evaluate, progress)
    finally:
        lock.release()


def _train_fleet(
    workspace: Workspace,
    fleet: dict[str, Any],
    backend: str,
    ray_address: str | None,
    threads: int | None,
    evaluate: bool,
    progress: ProgressFn | None,
) -> dict[str, Any]:
    fleet.update(state="running", pid=os.getpid(), backend=backend, message="training")
    fleet.setdefault("started_at", now_iso())
    _write_fleet(workspace, fleet)
    runs = fleet["runs"]
    cores = os.cpu_count() or 1
    try:
        if backend == "local":
            summaries = _train_local(workspace, runs, threads or cores, evaluate, progress)
        elif backend == "ray":
            from laneprint.parallel import backend_session, run_tasks

            with backend_session("ray", ray_address):
                shards = shard_runs(runs, _ray_cpus())
                stop = threading.Event()
                watcher = threading.Thread(target=_fleet_progress, args=(workspace, runs, progress, stop), daemon=True)
                watcher.start()
                try:
                    parts = run_tasks(
                        _train_shard_task,
                        [(str(workspace.root), s, 1, evaluate) for s in shards],
                        backend="ray",
                        ray_address=ray_address,
                    )
                finally:
                    stop.set()
            summaries = [x for part in parts for x in part]
        else:
            raise UserError(f"unknown --backend {backend!r}: choose 'local' or 'ray'")
    except BaseException as exc:
        fleet.update(
            state="failed" if isinstance(exc, Exception) else "cancelled", message=f"{type(exc).__name__}: {exc}"
        )
        _write_fleet(workspace, fleet)
        raise
    states = {s["state"] for s in summaries}
    fleet.update(
        state="cancelled" if "cancelled" in states else "done",
        message=f"{sum(s['state'] == 'done' for s in summaries)} of {len(runs)} agents done",
    )
    _write_fleet(workspace, fleet)
    by_id = {s["run_id"]: s for s in summaries}
    return {
        **fleet,
        "summaries": [by_id.get(r, {"run_id": r, "state": "missing"}) for r in runs],
        "agents": fleet_table(workspace, fleet["fleet_id"]).to_dict("records"),
    }


def _train_local(
    workspace: Workspace, runs: list[str], threads: int, evaluate: bool, progress: ProgressFn | None
) -> list[dict[str, Any]]:
    """The fleet in this process: one shard per thread, each a `FleetTrainer` with one torch thread.

    Shards in Python threads rather than one stack on several torch threads: torch
    releases the GIL in its kernels, so the shards run in parallel, and on a busy
    machine torch's OpenMP team of 2 spun at its barriers (a 6-agent fleet took
    13x longer on 2 torch threads than on 1, `benchmarks/fleet.py`).
    """
    root = str(workspace.root)
    shards = shard_runs(runs, threads)
    if len(shards) == 1:
        return train_shard(root, runs, 1, evaluate, progress)
    done, totals = [0] * len(shards), [0] * len(shards)
    results: list[list[dict[str, Any]] | None] = [None] * len(shards)
    errors: list[BaseException] = []
    lock = threading.Lock()

    def shard_progress(i: int) -> ProgressFn:
        def update(d: int, t: int, message: str = "") -> None:
            with lock:
                done[i], totals[i] = d, t
                report(progress, sum(done), sum(totals), f"fleet: {len(runs)} agents in {len(shards)} shards")

        return update

    def work(i: int, stop: _StopFlag) -> None:
        try:
            results[i] = train_shard(root, shards[i], 1, evaluate, shard_progress(i), stop=stop)
        except BaseException as exc:  # re-raised in the main thread
            errors.append(exc)

    with _StopFlag() as stop:
        workers = [threading.Thread(target=work, args=(i, stop), name=f"fleet-shard-{i}") for i in range(len(shards))]
        for w in workers:
            w.start()
        for w in workers:
            while w.is_alive():  # join with a timeout so SIGINT/SIGTERM reach the main thread's handler
                w.join(0.5)
    if errors:
        raise errors[0]
    return [x for part in results for x in part or []]


def _train_shard_task(args: tuple[str, list[str], int, bool]) -> list[dict[str, Any]]:
    """`train_shard` with its arguments in one tuple (one task of `run_tasks`)."""
    root, run_ids, threads, evaluate = args
    return train_shard(root, run_ids, threads, evaluate)


def _ray_cpus() -> int:
    """The Ray cluster's CPUs: one shard (a `FleetTrainer` with one thread) per CPU."""
    import ray

    return max(1, int(ray.cluster_resources().get("CPU", 1)))
