"""How long the test lanes take: the fast lane (`pytest -m "not slow"`) and, with `--full`, everything.

    python benchmarks/lanes.py [--full] [--repeats 1]

Each lane runs in a subprocess from the repository's root; its wall time, CPU time (children's user +
system), the tests it ran and the load average before and after go to `benchmarks/results/lanes.json`
(the median over `--repeats`). The load average says how busy the machine was: the lanes share it.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from results_file import write_result  # beside this file

ROOT = Path(__file__).resolve().parents[1]
LANES = {"fast": ["-m", "not slow"], "full": []}


def run_lane(args: list[str]) -> dict[str, float | int | str]:
    """One pytest run: wall and CPU seconds, tests passed and failed, load average before and after."""
    before_cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    wall = time.perf_counter() - t0
    after_cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    tail = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    count = {k: int(n) for n, k in re.findall(r"(\d+) (passed|failed|skipped|deselected|error)", tail)}
    return {
        "wall_s": round(wall, 1),
        "cpu_s": round((after_cpu.ru_utime - before_cpu.ru_utime) + (after_cpu.ru_stime - before_cpu.ru_stime), 1),
        "passed": count.get("passed", 0),
        "failed": count.get("failed", 0) + count.get("error", 0),
        "deselected": count.get("deselected", 0),
        "load_before": round(load_before, 2),
        "load_after": round(os.getloadavg()[0], 2),
        "summary": tail,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="time the full suite too (what CI runs)")
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    lanes = ["fast", "full"] if args.full else ["fast"]
    figures: dict[str, dict] = {}
    for lane in lanes:
        runs = []
        for i in range(args.repeats):
            print(f"{lane} lane, run {i + 1} of {args.repeats} ...", flush=True)
            runs.append(run_lane(LANES[lane]))
            print(f"  {runs[-1]['summary']} ({runs[-1]['wall_s']} s wall, {runs[-1]['cpu_s']} s CPU)", flush=True)
        figures[lane] = {
            "pytest_args": " ".join(LANES[lane]) or "(none)",
            "median_wall_s": statistics.median(r["wall_s"] for r in runs),
            "median_cpu_s": statistics.median(r["cpu_s"] for r in runs),
            "runs": runs,
        }
    write_result("lanes", figures)


if __name__ == "__main__":
    main()
