"""Time to first render of each dashboard page on a workspace of 100 drivers x 50 decisions.

    python benchmarks/dashboard.py [--drivers 100] [--decisions 50] [--repeat 5]

The workspace is generated in a temporary folder: one short recording per driver
(`indicators.synthetic.make_recording`), the analysis of a synthetic decisions
table (`make_decision_table` + the real `analyze_tables`), and two finished runs
with metrics and evaluation. Each page is rendered with Streamlit's AppTest (the
script run, not the browser's drawing): 'cold' clears Streamlit's caches first (the
first visit after the workspace changed), 'warm' is a second visit. Medians [s].
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

# this file is named like the package it measures: keep its folder off the import path
sys.path = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import streamlit as st  # noqa: E402
from streamlit.testing.v1 import AppTest  # noqa: E402

from laneprint.workspace import Workspace, atomic_write_json  # noqa: E402

PAGES = Path(__file__).resolve().parents[1] / "dashboard" / "app_pages"


def build(root: Path, n_drivers: int, n_decisions: int) -> Workspace:
    from clustering.pipeline import analyze_tables
    from indicators.synthetic import make_decision_table, make_recording

    ws = Workspace(root).ensure()
    for i in range(n_drivers):
        meta, ego, traffic = make_recording(
            60.0, 20.0, 20.0 + (i % 7), [(0, 0), (30.0, 1)], presses=[(25.0, 0.5, "left")],
            vehicles=[("lead", 80.0, 17.0, 0, 4.5), ("nb", -40.0, 19.0, 1, 4.5)],
            recording_id=f"{i:016x}", driver_id=f"D{i:04d}")
        meta.update(simulator="bench", source_name=f"r{i}.csv", source_path=f"/b/r{i}.csv", format="csv",
                    n_samples=len(ego), duration_s=60.0, n_presses=1, n_vehicles=2, status="ok",
                    warnings="", ingested_at="2026-01-01T00:00:00+00:00")
        ws.write_recording(meta, ego, traffic)
    decisions, _ = make_decision_table(n_drivers, n_decisions, seed=0)
    ws.write_tables("analysis", analyze_tables(decisions), {"settings": {}})
    for r in range(2):
        d = ws.runs_dir / f"bench-{r}"
        d.mkdir(parents=True)
        atomic_write_json(d / "status.json", {"state": "done", "pid": None, "episode": 2000, "episodes": 2000,
                                              "message": ""})
        with open(d / "metrics.jsonl", "w") as fh:
            for e in range(1, 2001):
                fh.write(json.dumps({"episode": e, "loss": 1 / e, "mean_step_reward": 1.4, "epsilon": 0.1,
                                     "length": 20, "changed": True, "return": 3.0, "env_steps": 20 * e,
                                     "wall_s": e / 100}) + "\n")
        atomic_write_json(d / "evaluation.json", {"summary": [
            {"who": w, "recall": 0.9, "balanced_accuracy": 0.8, "timing_mae_s": 1.0}
            for w in ("agent", "greedy", "driver")]})
    return ws


def render(page: str, cold: bool) -> float:
    if cold:
        st.cache_data.clear()
    at = AppTest.from_file(str(PAGES / f"{page}.py"), default_timeout=300)
    t0 = time.perf_counter()
    at.run()
    dt = time.perf_counter() - t0
    if at.exception:
        raise SystemExit(f"{page}: {at.exception[0].value}")
    return dt


def main() -> None:
    import logging

    logging.disable(logging.WARNING)  # AppTest's "missing ScriptRunContext" and cache notices
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drivers", type=int, default=100)
    ap.add_argument("--decisions", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        ws = build(Path(tmp) / "ws", args.drivers, args.decisions)
        print(f"workspace: {args.drivers} drivers x {args.decisions} decisions, "
              f"{len(ws.read_table('analysis', 'decisions'))} decision rows, built in {time.perf_counter() - t0:.1f} s")
        os.environ["LANEPRINT_WORKSPACE"] = str(ws.root)
        for page in ("data", "drivers", "styles", "training", "results"):
            render(page, cold=True)  # imports and first compile out of the way
        print(f"{'page':<10} {'cold [s]':>9} {'warm [s]':>9}   (median of {args.repeat})")
        for page in ("data", "drivers", "styles", "training", "results"):
            cold = statistics.median(render(page, cold=True) for _ in range(args.repeat))
            warm = statistics.median(render(page, cold=False) for _ in range(args.repeat))
            print(f"{page:<10} {cold:>9.3f} {warm:>9.3f}")


if __name__ == "__main__":
    main()
