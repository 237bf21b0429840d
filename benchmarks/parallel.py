"""`--backend local` vs `--backend ray`, side by side in one run, through the real command line.

- ingest: `laneprint ingest sample_logs` into a fresh workspace, each backend in turn
  (interleaved), median wall time of `--reps` runs; the catalogues must be equal;
- crossval: `laneprint crossval --style STYLE --episodes N` on a workspace of the
  sample study (ingested and analysed once), each backend `--cv-reps` times; the
  summaries must be equal (same seed);
- the start-up and shut-down of a local Ray instance alone (what `--backend ray`
  pays before the first task without `--ray-address`).

Wall times include the command's own start (a new Python process each time), as a
user sees them. The ray backend starts a local Ray instance with this machine's cores.

The figures are written to `benchmarks/results/<--out>.json` (default `parallel`).

    python benchmarks/parallel.py [--reps 3] [--cv-reps 1] [--episodes 2000] [--style Normal]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from results_file import write_result  # beside this file

ROOT = Path(__file__).resolve().parents[1]
LANEPRINT = [sys.executable, "-m", "laneprint.app.cli"]


def timed(args: list[str]) -> tuple[float, dict]:
    """Wall seconds and the JSON output of one `laneprint` command."""
    t = time.perf_counter()
    out = subprocess.run(LANEPRINT + args + ["--json"], capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t
    if out.returncode != 0:
        sys.exit(f"failed: laneprint {' '.join(args)}\n{out.stderr}")
    return wall, json.loads(out.stdout)


def ray_start_s() -> float:
    code = (
        "import time, os; t = time.perf_counter(); from laneprint.parallel import backend_session\n"
        "with backend_session('ray'): pass\nprint(time.perf_counter() - t)"
    )
    return float(
        subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
        ).stdout.split()[-1]
    )


def catalogue(ws: Path) -> list[dict]:
    from laneprint.workspace import Workspace

    return Workspace(ws).recordings().drop(columns=["ingested_at"]).to_dict("records")


def fmt(xs: list[float]) -> str:
    return f"{statistics.median(xs):6.1f} s (runs: {', '.join(f'{x:.1f}' for x in xs)})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3, help="ingest runs per backend")
    ap.add_argument("--cv-reps", type=int, default=1, help="crossval runs per backend")
    ap.add_argument("--episodes", type=int, default=2000, help="episodes per fold's agent")
    ap.add_argument("--folds", type=int, default=4)
    ap.add_argument("--style", default="Normal")
    ap.add_argument("--out", default="parallel", help="result file name under benchmarks/results/")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-parallel-"))
    logs = str(ROOT / "sample_logs")
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start")
    figures: dict = {
        "reps": a.reps,
        "cv_reps": a.cv_reps,
        "episodes": a.episodes,
        "folds": a.folds,
        "style": a.style,
        "load_average_start": os.getloadavg()[0],
    }
    try:
        walls: dict[str, list[float]] = {"local": [], "ray": []}
        cats = {}
        for rep in range(a.reps):
            for backend in ("local", "ray"):
                ws = tmp / f"ingest-{backend}-{rep}"
                wall, out = timed(["ingest", logs, "-w", str(ws), "--backend", backend])
                walls[backend].append(wall)
                cats[backend] = (out["counts"], catalogue(ws))
        same = cats["local"] == cats["ray"]
        figures["ingest"] = {
            "files": cats["local"][0]["ingested"],
            "catalogues_equal": same,
            **{f"{b}_median_s": statistics.median(w) for b, w in walls.items()},
            **{f"{b}_runs_s": w for b, w in walls.items()},
        }
        print(
            f"ingest sample_logs ({cats['local'][0]['ingested']} files): local {fmt(walls['local'])} | "
            f"ray {fmt(walls['ray'])} | catalogues equal: {same}"
        )

        ws = tmp / "study"
        timed(["ingest", logs, "-w", str(ws)])
        timed(["analyze", "-w", str(ws)])
        cv = ["crossval", "--style", a.style, "--episodes", str(a.episodes), "--folds", str(a.folds), "-w", str(ws)]
        walls = {"local": [], "ray": []}
        summaries = {}
        for _ in range(a.cv_reps):
            for backend in ("local", "ray"):
                wall, out = timed(cv + ["--backend", backend])
                walls[backend].append(wall)
                summaries[backend] = (out["summary"], out["per_fold"])
        same = summaries["local"] == summaries["ray"]
        figures["crossval"] = {
            "summaries_equal": same,
            **{f"{b}_median_s": statistics.median(w) for b, w in walls.items()},
            **{f"{b}_runs_s": w for b, w in walls.items()},
        }
        print(
            f"crossval --style {a.style} --folds {a.folds} --episodes {a.episodes}: local {fmt(walls['local'])} | "
            f"ray {fmt(walls['ray'])} | summaries equal: {same}"
        )
        figures["ray_start_stop_s"] = ray_start_s()
        print(f"local Ray instance start + shut-down alone: {figures['ray_start_stop_s']:.1f} s")
        print(f"load average {os.getloadavg()[0]:.1f} at the end")
        figures["load_average_end"] = os.getloadavg()[0]
        write_result(a.out, figures)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
