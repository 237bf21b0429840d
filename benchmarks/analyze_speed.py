"""`analyze` of the shipped study: this checkout against a git revision, side by side.

Ingests `sample_logs/` once, copies the workspace for each side, then runs the analysis stage
(`clustering.pipeline.analyze`, default settings) of each side in its own process, alternating
which goes first, `--reps` times; prints the median CPU and wall seconds of each and their ratio, and
writes them to `benchmarks/results/<--out>.json` (default `analyze_speed`).
The revision is checked out with `git worktree` in a temporary folder and removed afterwards.

Run: .venv/bin/python benchmarks/analyze_speed.py --baseline 3451c92 [--reps 5]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from results_file import write_result  # beside this file

ROOT = Path(__file__).resolve().parents[1]
#: One analysis in a fresh process: the code of argv[1], the workspace argv[2]; prints CPU and wall s.
ONE_RUN = (
    "import sys, time; sys.path.insert(0, sys.argv[1]); "
    "from clustering.pipeline import analyze; from laneprint.workspace import Workspace; "
    "ws = Workspace(sys.argv[2]); c, w = time.process_time(), time.perf_counter(); analyze(ws); "
    "print(time.process_time() - c, time.perf_counter() - w)"
)


def run_once(code_root: Path, workspace: Path) -> tuple[float, float]:
    out = subprocess.run(
        [sys.executable, "-c", ONE_RUN, str(code_root), str(workspace)],
        cwd=code_root,
        capture_output=True,
        text=True,
        check=True,
    )
    cpu, wall = out.stdout.split()[-2:]
    return float(cpu), float(wall)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, help="git revision to compare with")
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--out", default="analyze_speed", help="result file name under benchmarks/results/")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="lp-analyze-speed-") as tmp:
        tmp = Path(tmp)
        base = tmp / "baseline"
        subprocess.run(["git", "worktree", "add", "-q", "--detach", str(base), args.baseline], cwd=ROOT, check=True)
        try:
            ws = tmp / "ws"
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "laneprint.app.cli",
                    "ingest",
                    str(ROOT / "sample_logs"),
                    "-w",
                    str(ws),
                    "--json",
                ],
                cwd=ROOT,
                check=True,
                capture_output=True,
            )
            sides = {"this checkout": ROOT, args.baseline: base}
            spaces = {name: shutil.copytree(ws, tmp / f"ws-{i}") for i, name in enumerate(sides)}
            times: dict[str, list[tuple[float, float]]] = {name: [] for name in sides}
            for rep in range(args.reps):
                for name in list(sides) if rep % 2 == 0 else list(reversed(sides)):
                    times[name].append(run_once(sides[name], spaces[name]))
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=ROOT, check=False)
    med = {n: (statistics.median(c for c, _ in t), statistics.median(w for _, w in t)) for n, t in times.items()}
    print(f"analyze of the shipped study (40 recordings), median of {args.reps} alternating runs")
    print("| code | CPU s | wall s |\n|---|---|---|")
    for n, (c, w) in med.items():
        print(f"| {n} | {c:.2f} | {w:.2f} |")
    here, there = med["this checkout"], med[args.baseline]
    print(f"this checkout / {args.baseline}: CPU {here[0] / there[0]:.2f}, wall {here[1] / there[1]:.2f}")
    write_result(
        args.out,
        {
            "baseline": args.baseline,
            "reps": args.reps,
            "median": [{"code": n, "cpu_s": c, "wall_s": w} for n, (c, w) in med.items()],
            "ratio_cpu": here[0] / there[0],
            "ratio_wall": here[1] / there[1],
        },
    )


if __name__ == "__main__":
    main()
