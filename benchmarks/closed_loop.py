"""Closed loop in SUMO (issue 11): does each style's agent drive safely, and like its style?

Through the real command line:

1. `laneprint simulate --engine sumo --drivers 9 --seed S` (a study nobody tuned on
   with S = 7), `ingest`, `analyze`;
2. per style, `laneprint train --style STYLE` with the default settings;
3. per agent, `laneprint drive RUN --engine sumo --minutes 10 --seed S` (four
   sections), then `ingest` of its MCAPs as a new driver (`agent-<style>`);
4. `analyze` again, on the study plus the three drives.

Prints one row per style: lane changes made, SUMO's collisions and emergency
brakes, the indicators at the agent's changes against its target's lines (median
and mean absolute difference), and the style the analysis assigns to the agent's
drive; then whether the acceptance holds (no collision, 3 of 3 in their style).

Run: python benchmarks/closed_loop.py [--seed 7] [--drivers 9] [--minutes 10] [--workdir /tmp/lp-closed-loop]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAPRINT = [sys.executable, "-m", "laneprint.cli"]
STYLES = ("Defensive", "Normal", "Aggressive")


def cli(*args: str) -> dict:
    """Run a laneprint command with --json and return its document (exit on failure)."""
    proc = subprocess.run([*LAPRINT, *args, "--json"], capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        sys.exit(f"laneprint {' '.join(args)} failed: {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout)


def fmt(x: float | None, spec: str = ".1f") -> str:
    return "-" if x is None else format(x, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=7, help="seed of the study, the training and the drives")
    ap.add_argument("--drivers", type=int, default=9)
    ap.add_argument("--minutes", type=float, default=10.0, help="minutes of driving per section")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/lp-closed-loop"))
    args = ap.parse_args()
    work = args.workdir
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    study, ws = work / "study", work / "ws"
    t0 = time.monotonic()
    cli("simulate", "--engine", "sumo", "--out", str(study), "--drivers", str(args.drivers),
        "--seed", str(args.seed))
    cli("ingest", str(study), "-w", str(ws))
    first = cli("analyze", "-w", str(ws))
    print(f"study: {args.drivers} drivers, seed {args.seed}; styles "
          + ", ".join(f"{d} {v['style']}" for d, v in first["drivers"].items()), flush=True)
    drives = {}
    for style in STYLES:
        run = cli("train", "--style", style, "--seed", str(args.seed), "--run-id", f"closed-loop-{style.lower()}",
                  "-w", str(ws))
        driver = f"agent-{style.lower()}"
        drives[style] = cli("drive", run["run_id"], "--engine", "sumo", "--minutes", f"{args.minutes:g}",
                            "--seed", str(args.seed), "--driver-id", driver, "--out", str(work / "drives" / driver),
                            "-w", str(ws))
        print(f"{style}: trained {run['episodes']} episodes in {run['wall_s']} s; drove "
              f"{drives[style]['totals']['lane_changes']} lane changes", flush=True)
    for style, d in drives.items():
        cli("ingest", *d["files"], "--driver", d["driver_id"], "-w", str(ws))
    final = cli("analyze", "-w", str(ws))
    print(f"\n## Closed loop in SUMO (study seed {args.seed}, {args.minutes:g} min per section, "
          f"4 sections, {time.monotonic() - t0:.0f} s in all)")
    print("| style | lane changes (L/R) | collisions | emergency brakes | not started | "
          "t_f agent / line [s] (MAE) | t_nf agent / line [s] (MAE) | dv_nb agent / line [m/s] (MAE) | assigned style |")
    print("|---|---|---|---|---|---|---|---|---|")
    checks = []
    for style, d in drives.items():
        tot, ind = d["totals"], d["indicators"]
        assigned = final["drivers"].get(d["driver_id"], {}).get("style")
        cells = [f"{fmt(ind[k]['median'])} / {fmt(ind[k]['line_median'])} ({fmt(ind[k]['mae'])}, n={ind[k]['n']})"
                 for k in ("t_f", "t_nf", "dv_nb")]
        print(f"| {style} | {tot['lane_changes']} ({tot['left']}/{tot['right']}) | {tot['collisions']} "
              f"| {tot['emergency_brakes']} | {tot['not_started']} | {' | '.join(cells)} | {assigned} |")
        checks.append((style, tot["collisions"] == 0, assigned == style))
    study_styles = {d: v["style"] for d, v in final["drivers"].items() if not d.startswith("agent-")}
    changed = {d: (first["drivers"][d]["style"], s) for d, s in study_styles.items()
               if first["drivers"][d]["style"] != s}
    print(f"\nstudy drivers whose style changed when the drives joined: {changed or 'none'}")
    print(f"no collision: {sum(c for _, c, _ in checks)} of 3; in its own style: {sum(s for _, _, s in checks)} of 3")
    print("acceptance:", "met" if all(c and s for _, c, s in checks) else "NOT met")


if __name__ == "__main__":
    main()
