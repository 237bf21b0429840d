"""Benchmark: a whole study's agents, one by one vs as one batched fleet vs a fleet on Ray.

A simulated study of `--drivers` drivers (laneprint's own simulator, seed 0) is
ingested and analysed once (kept in `--workdir`); then one agent per driver,
seed 0, default settings (`laneprint train --driver D`), trained and evaluated:

1. one by one with `train_run` (today's trainer): `--sample` drivers timed, the
   total scaled to all drivers (printed as such);
2. one batched fleet in this process (`train_fleet`, backend local);
3. the same fleet on a local Ray instance (backend ray, one shard per core).

Then how a fleet's time grows with its size: `--scaling` fleets (agents cycle
over the drivers with extra seeds) run `--scaling-steps` vector steps after
learning starts; a whole run's time is projected from the time per vector step
and the vector steps a whole run takes (measured in 2.), and printed as projected.

    python benchmarks/fleet.py                         # 100 drivers, ~15-25 min on 2 cores
    python benchmarks/fleet.py --drivers 10 --sample 2 --skip-ray --scaling 5,10   # a quick look

Prints wall times, agents per minute, env steps per second, ratios, and per agent
whether it meets its target (recall >= 95 %, balanced accuracy >= greedy + 5 points);
writes them to `benchmarks/results/fleet.json` (`--out NAME`) with the command, commit, date and machine.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from results_file import write_result  # beside this file
from laneprint.workspace import Workspace
from rl.problem.env import formulation_config
from rl.fleet.batch import FleetMember, FleetTrainer
from rl.fleet.store import fleet_table
from rl.fleet.runs import _load_members, create_fleet, fleet_targets, train_fleet
from rl.runs import Target, resolve_lines, train_run
from rl.settings import DQNSettings


def cli(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "laneprint.app.cli", *args], check=True, stdout=subprocess.DEVNULL)


def prepare(workdir: Path, drivers: int) -> Workspace:
    """Simulate, ingest and analyse the study once (reused when the workspace has an analysis)."""
    logs, ws_root = workdir / f"study{drivers}", workdir / f"ws{drivers}"
    ws = Workspace(ws_root)
    if ws.has_table("analysis", "styles"):
        return ws
    t = time.perf_counter()
    if not logs.exists():
        cli("simulate", "--out", str(logs), "--drivers", str(drivers), "--seed", "0")
    cli("ingest", str(logs), "-w", str(ws_root))
    cli("analyze", "-w", str(ws_root))
    print(f"study of {drivers} drivers simulated, ingested and analysed in {time.perf_counter() - t:.0f} s")
    return ws


def fresh_runs(ws: Workspace) -> None:
    """Drop earlier runs and fleets so every method starts from the same workspace."""
    for name in ("runs", "fleets"):
        shutil.rmtree(ws.root / name, ignore_errors=True)


def meets(ev_rows: list[dict]) -> tuple[bool, float | None, float | None, float | None]:
    rows = {r["who"]: r for r in ev_rows or []}
    a, g = rows.get("agent", {}), rows.get("greedy", {})
    ok = bool(a and g and a["recall"] >= 0.95 and a["balanced_accuracy"] >= g["balanced_accuracy"] + 0.05)
    return ok, a.get("recall"), a.get("balanced_accuracy"), g.get("balanced_accuracy")


def one_by_one(ws: Workspace, drivers: list[str]) -> dict:
    results, steps = [], 0
    t, cpu = time.perf_counter(), time.process_time()
    for d in drivers:
        target = Target("driver", d)
        env = formulation_config(resolve_lines(ws, target, "analysis"))
        res = train_run(ws, target, env, DQNSettings(seed=0))
        steps += res["env_steps"]
        results.append({"driver": d, **dict(zip(("ok", "recall", "agent_ba", "greedy_ba"), meets(res["evaluation"])))})
    return {
        "wall_s": time.perf_counter() - t,
        "cpu_s": time.process_time() - cpu,
        "env_steps": steps,
        "agents": results,
    }


def fleet(ws: Workspace, backend: str, threads: int | None) -> dict:
    targets = fleet_targets(ws, drivers="all")
    t, cpu = time.perf_counter(), time.process_time()
    record = create_fleet(ws, targets, [0], DQNSettings(), backend=backend)
    res = train_fleet(ws, record["fleet_id"], backend=backend, threads=threads)
    wall, cpu = time.perf_counter() - t, time.process_time() - cpu
    table = fleet_table(ws, record["fleet_id"]).rename(
        columns={
            "agent_balanced_accuracy": "agent_ba",
            "greedy_balanced_accuracy": "greedy_ba",
            "imitation_balanced_accuracy": "imitation_ba",
            "agent_recall": "recall",
        }
    )
    steps = sum(s.get("env_steps", 0) for s in res["summaries"])
    return {
        "wall_s": wall,
        "cpu_s": cpu if backend == "local" else None,
        "env_steps": steps,
        "table": table,
        "runs": res["runs"],
    }


def vector_steps_per_run(ws: Workspace, run_ids: list[str]) -> float:
    """Mean vector steps a whole run took (env steps / environments)."""
    vals = []
    for rid in run_ids:
        cfg = json.loads((ws.runs_dir / rid / "config.json").read_text())
        status = ws.runs_dir / rid / "metrics.jsonl"
        last = status.read_text().strip().splitlines()[-1]
        vals.append(json.loads(last)["env_steps"] / cfg["dqn"]["num_envs"])
    return float(np.mean(vals))


def scaling(ws: Workspace, sizes: list[int], steps: int, shards: int) -> list[dict]:
    """Seconds per vector step (after learning starts) of fleets of `sizes` agents, trained as the
    local backend trains them: `shards` `FleetTrainer`s of one torch thread each, in threads at once."""
    targets = fleet_targets(ws, drivers="all")
    fresh_runs(ws)
    record = create_fleet(ws, targets, [0], DQNSettings())
    base_members, _ = _load_members(ws, record["runs"])
    out = []
    for k in sizes:
        members = [
            FleetMember(m.env_config, replace(m.settings, seed=i // len(base_members)), m.approaches)
            for i, m in zip(range(k), (base_members * (k // len(base_members) + 1)))
        ]
        parts = [members[i::shards] for i in range(min(shards, k))]
        s = members[0].settings
        warm = int(np.ceil(s.learning_starts / s.num_envs)) + 2
        per_shard: list[float] = [0.0] * len(parts)

        def run(i: int) -> None:
            marks: list[float] = []

            def tick(f: FleetTrainer) -> bool:
                marks.append(time.perf_counter())
                return len(marks) >= warm + steps

            FleetTrainer(parts[i], threads=1).train(on_vector_step=tick)
            per_shard[i] = (marks[-1] - marks[warm - 1]) / steps

        workers = [threading.Thread(target=run, args=(i,)) for i in range(len(parts))]
        for w in workers:
            w.start()
        for w in workers:
            w.join()
        per_step = max(per_shard)
        out.append({"agents": k, "s_per_vector_step": per_step})
        print(
            f"  {k:5d} agents ({len(parts)} shards of <= {len(parts[0])}): {per_step * 1000:.1f} ms per vector step",
            flush=True,
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drivers", type=int, default=100)
    ap.add_argument("--sample", type=int, default=10, help="drivers trained one by one (scaled to all)")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/lp-fleet"))
    ap.add_argument("--threads", type=int, default=None, help="torch threads of the local fleet (default: cores)")
    ap.add_argument("--skip-ray", action="store_true")
    ap.add_argument("--scaling", default="10,100,1000", help="fleet sizes for the growth figures ('' = skip)")
    ap.add_argument("--scaling-steps", type=int, default=10, help="vector steps timed per size (one shard per core)")
    ap.add_argument("--out", default="fleet", help="result file name under benchmarks/results/")
    args = ap.parse_args()
    cores = os.cpu_count() or 1
    ws = prepare(args.workdir, args.drivers)
    drivers = sorted(fleet_targets(ws, drivers="all"), key=lambda t: t.name)
    n = len(drivers)
    print(
        f"{n} drivers, one agent each (seed 0, default settings), {cores} cores; "
        f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())} (1/5/15 min)\n"
    )

    rows = []
    fresh_runs(ws)
    sample = [t.name for t in drivers[: args.sample]]
    obo = one_by_one(ws, sample)
    scale = n / len(sample)
    rows.append(
        (
            "one by one (today's trainer)",
            obo["wall_s"] * scale,
            obo["cpu_s"] * scale,
            obo["env_steps"] * scale,
            f"{len(sample)} timed, x{scale:g}",
        )
    )
    print(f"one by one: {len(sample)} agents in {obo['wall_s']:.0f} s", flush=True)

    fresh_runs(ws)
    local = fleet(ws, "local", args.threads)
    rows.append(
        (
            "batched fleet (local)",
            local["wall_s"],
            local["cpu_s"],
            local["env_steps"],
            f"{args.threads or cores} threads",
        )
    )
    print(f"fleet local: {n} agents in {local['wall_s']:.0f} s", flush=True)
    steps_per_run = vector_steps_per_run(ws, local["runs"])
    local_table = local["table"]

    same = None
    if not args.skip_ray:
        fresh_runs(ws)
        ray = fleet(ws, "ray", 1)
        rows.append(("fleet on local Ray", ray["wall_s"], None, ray["env_steps"], f"{cores} workers x 1 thread"))
        print(f"fleet ray: {n} agents in {ray['wall_s']:.0f} s", flush=True)
        same = bool(
            np.allclose(
                ray["table"]["agent_ba"].to_numpy(float),
                local_table["agent_ba"].to_numpy(float),
                atol=1e-9,
                equal_nan=True,
            )
        )
        print(f"ray agents' balanced accuracy equal to the local fleet's: {same}")

    figures: dict = {
        "drivers": n,
        "sample": len(sample),
        "cores": cores,
        "methods": [
            {
                "method": name,
                "wall_s": wall,
                "agents_per_min": 60 * n / wall,
                "env_steps_per_s": steps / wall,
                "speed_up": rows[0][1] / wall,
                "cpu_s": cpu,
                "cpu_ratio": rows[0][2] / cpu if cpu else None,
                "projected": name.startswith("one by one"),
                "note": note,
            }
            for name, wall, cpu, steps, note in rows
        ],
        "ray_balanced_accuracy_equal_to_local": same,
    }
    base = rows[0][1]
    # CPU seconds of this process (all its threads): the work done, whatever else loads the machine
    # (Ray's workers are other processes: not counted)
    base_cpu = rows[0][2]
    print(
        f"\n{'method':32s} {'wall [s]':>9s} {'agents/min':>11s} {'env steps/s':>12s} {'speed-up':>9s} "
        f"{'CPU [s]':>8s} {'CPU ratio':>9s}  note"
    )
    for name, wall, cpu, steps, note in rows:
        cpu_cols = f"{cpu:8.0f} {base_cpu / cpu:8.1f}x" if cpu else f"{'-':>8s} {'-':>9s}"
        print(
            f"{name:32s} {wall:9.0f} {60 * n / wall:11.1f} {steps / wall:12.0f} {base / wall:8.1f}x {cpu_cols}  {note}"
        )

    met = int(local_table["meets_target"].sum())
    print(
        f"\nfleet agents meeting the target (recall >= 95 %, bal. acc. >= greedy + 5 points): {met} of {len(local_table)}"
    )
    worst = local_table.assign(margin=local_table["agent_ba"] - local_table["greedy_ba"]).sort_values("margin").head(5)
    print(
        "closest to missing:\n" + worst[["run_id", "recall", "agent_ba", "greedy_ba", "margin"]].to_string(index=False)
    )
    by_driver = pd.DataFrame(obo["agents"]).set_index("driver")
    fleet_ba = local_table.assign(driver=[r.rsplit("-", 2)[-2].upper() for r in local_table["run_id"]]).set_index(
        "driver"
    )
    diff = (fleet_ba.loc[by_driver.index, "agent_ba"] - by_driver["agent_ba"]).abs()
    print(
        f"same drivers alone vs in the fleet: max |bal. acc. difference| {diff.max():.4f} "
        f"(one by one met the target {int(by_driver['ok'].sum())} of {len(by_driver)})"
    )
    figures.update(
        {
            "fleet_agents_meeting_target": met,
            "fleet_agents": len(local_table),
            "max_abs_balanced_accuracy_difference_alone_vs_fleet": float(diff.max()),
            "one_by_one_meeting_target": int(by_driver["ok"].sum()),
            "median_balanced_accuracy": {
                w: float(statistics.median(local_table[f"{w}_ba"])) for w in ("agent", "greedy", "imitation")
            },
        }
    )
    print(
        f"median agent bal. acc. {statistics.median(local_table['agent_ba']):.3f}, greedy "
        f"{statistics.median(local_table['greedy_ba']):.3f}, imitation {statistics.median(local_table['imitation_ba']):.3f}"
    )

    sizes = [int(x) for x in args.scaling.split(",") if x.strip()]
    if sizes:
        print(
            f"\nfleet growth ({args.scaling_steps} vector steps after learning starts, {args.threads or cores} shards "
            f"of one thread; a whole run is ~{steps_per_run:.0f} vector steps):"
        )
        grow = scaling(ws, sizes, args.scaling_steps, args.threads or cores)
        figures["growth"] = [
            {
                "agents": g["agents"],
                "s_per_vector_step": g["s_per_vector_step"],
                "projected_min_per_run": g["s_per_vector_step"] * steps_per_run / 60,
            }
            for g in grow
        ]
        figures["vector_steps_per_run"] = steps_per_run
        for g in grow:
            print(
                f"  {g['agents']:5d} agents: projected {g['s_per_vector_step'] * steps_per_run / 60:.1f} min "
                f"for a whole run (training only, projected)"
            )
    print(f"\nload average at the end {' '.join(f'{x:.1f}' for x in os.getloadavg())} (1/5/15 min)")
    figures["load_average_at_end"] = [round(x, 2) for x in os.getloadavg()]
    write_result(args.out, figures)


if __name__ == "__main__":
    main()
