"""SIGKILL laneprint commands at random moments and show the workspace survives.

For each kill (spread evenly over the commands, order and moments drawn from --seed):
a fresh copy of a prepared workspace (a simulated 3-driver study, all but two logs
ingested, analysed), the command started and SIGKILLed at a random moment of its work
(a fraction of its CPU time, measured; an attempt that finished first is redrawn, not
counted), `laneprint check --repair`,
the killed training runs checked to show as interrupted (CLI and dashboard) and
resumed from their checkpoint, the command re-run, `laneprint check` again. See
`tests/crash/crash_harness.py` (a new command is one line of its COMMANDS).

    .venv/bin/python benchmarks/crash.py [--kills 50] [--seed 0] [--commands ingest,analyze,train,crossval,fleet]
        [--jobs 1] [--out crash.json]

Prints one line per kill and a summary: kills per command, how many hit a live process
(and how many had finished first), consistent workspaces
(no `check` problem after the kill, a clean `check` after recovery, the command's own
postcondition), interrupted trainings resumed, leftovers repaired. Exit 1 if a workspace
was inconsistent or an interrupted training was not resumed. The summary is written to
`benchmarks/results/<--result>.json` (default `crash`; `--out` keeps every kill's result).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from dataclasses import asdict
from pathlib import Path

from results_file import write_result  # beside this file: imported before the folder leaves the path

# benchmarks/ holds scripts named like packages (dashboard.py, ingest.py): keep it off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "crash"))  # the harness lives beside its tests
from crash_harness import COMMANDS, run_kills  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--commands", default=",".join(COMMANDS), help=f"comma-separated, of: {', '.join(COMMANDS)}")
    ap.add_argument("--jobs", type=int, default=1, help="kills under way at once (each on its own workspace)")
    ap.add_argument("--out", type=Path, help="write every kill's result here as JSON")
    ap.add_argument("--result", default="crash", help="the summary's file name under benchmarks/results/")
    args = ap.parse_args()
    names = [n.strip() for n in args.commands.split(",") if n.strip()]
    unknown = [n for n in names if n not in COMMANDS]
    if unknown:
        ap.error(f"unknown command(s) {', '.join(unknown)}: choose from {', '.join(COMMANDS)}")
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="laneprint-crash-") as tmp:
        results = run_kills(names, args.kills, args.seed, Path(tmp), args.jobs, log=lambda m: print(m, flush=True))
    by_cmd = Counter(r.command for r in results)
    live_by_cmd = Counter(r.command for r in results if r.live)
    live = sum(live_by_cmd.values())
    bad = [r for r in results if not r.consistent]
    interrupted = sum(len(r.interrupted_runs) for r in results)
    resumed = sum(1 for r in results for rid in r.interrupted_runs if rid in r.resumed)
    fractions = sorted(r.work_fraction for r in results if r.live)
    print(
        f"\n{len(results)} SIGKILLs in {time.monotonic() - t0:.0f} s: "
        + ", ".join(f"{k} {v} ({live_by_cmd[k]} live)" for k, v in by_cmd.items())
    )
    print(
        f"live (into a process at work): {live}; finished before their kill: {len(results) - live}; "
        f"attempts that finished first and were redrawn (not counted as kills): {sum(r.retries for r in results)}"
        + (
            f"; kill moments {fractions[0]:.0%}..{fractions[-1]:.0%} of the work, median "
            f"{fractions[len(fractions) // 2]:.0%}"
            if fractions
            else ""
        )
    )
    print(
        f"inconsistent workspaces: {len(bad)}; leftovers repaired: {sum(r.repaired for r in results)} "
        f"(in {sum(r.repaired > 0 for r in results)} kills); interrupted trainings: {interrupted}, "
        f"resumed from their checkpoint: {resumed}; slowest recovery: {max(r.recovery_s for r in results):.1f} s"
    )
    write_result(
        args.result,
        {
            "kills": len(results),
            "seed": args.seed,
            "commands": names,
            "jobs": args.jobs,
            "seconds": time.monotonic() - t0,
            "per_command": {k: {"kills": v, "live": live_by_cmd[k]} for k, v in by_cmd.items()},
            "live": live,
            "finished_before_kill": len(results) - live,
            "redrawn": sum(r.retries for r in results),
            "kill_moment_median": fractions[len(fractions) // 2] if fractions else None,
            "inconsistent": len(bad),
            "repaired": sum(r.repaired for r in results),
            "interrupted_trainings": interrupted,
            "resumed": resumed,
            "slowest_recovery_s": max((r.recovery_s for r in results), default=0.0),
        },
    )
    if args.out:
        args.out.write_text(json.dumps([asdict(r) | {"live": r.live} for r in results], indent=2))
    return 1 if bad or resumed < interrupted else 0


if __name__ == "__main__":
    sys.exit(main())
