"""What the default learner costs: `train` and `crossval` timed per learner, side by side in one run.

`laneprint train --style S --learner L` and `laneprint crossval --style S --learner L` for each
learner (`auto`, the default; `dqn`; `trees`) on the shipped study (`sample_logs`, ingested and
analysed once into a temporary workspace), each command a fresh process timed from start to end
(PyTorch's import, the scenes, the learner choice, the training and the evaluation). The commands
are interleaved (repeat by repeat, code by code, learner by learner) so a busy machine's load falls
on all of them alike; the medians over `--repeats` are reported with the ratios auto / dqn.

`--base PATH` also times another checkout of laneprint (e.g. `git worktree add /tmp/base c0eff12`)
in the same run, on the same workspace: before and after, side by side.

Quick by default (`--episodes 2000`: every agent capped at 2,000 episodes, one repeat, train only
with `--quick`); `--full` takes the study's episodes (30 per recorded approach), and `--repeats 3`
medians over three. Written to `benchmarks/results/learners.json` (`--out`) with the command,
commit, date and machine, and the held-out / in-sample figures of each command, so a faster
learner choice that chose differently shows.

    python benchmarks/learners.py                                    # quick: train and crossval, 1 repeat
    python benchmarks/learners.py --full --repeats 3 --base /tmp/base
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import median
from typing import Any

from results_file import write_result  # beside this file

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
LEARNERS = ("auto", "dqn", "trees")
COMMANDS = ("train", "crossval")


def laneprint(code: Path, *args: str, timeout: float = 3600) -> tuple[float, dict[str, Any]]:
    """(wall seconds, its --json output) of `python -m laneprint.app.cli ARGS` with `code` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    t0 = time.perf_counter()
    out = subprocess.run(
        [sys.executable, "-m", "laneprint.app.cli", *args, "--json"],
        cwd=code,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    wall = time.perf_counter() - t0
    if out.returncode:
        raise RuntimeError(f"laneprint {' '.join(args)} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return wall, json.loads(out.stdout)


def workspace(root: Path) -> Path:
    """The shipped study ingested and analysed (by this checkout) under `root`."""
    ws = root / "ws"
    laneprint(ROOT, "ingest", str(ROOT / "sample_logs"), "-w", str(ws))
    laneprint(ROOT, "analyze", "-w", str(ws))
    return ws


def figures(command: str, res: dict[str, Any]) -> dict[str, Any]:
    """What a command's --json says about the agent: learner(s) chosen and balanced accuracy."""
    res = (res.get("results") or [res])[0]
    if command == "train":
        agent = next((r for r in res.get("evaluation") or [] if r.get("who") == "agent"), {})
        choice = res.get("learner_choice") or {}
        return {
            "chosen": res.get("learner"),
            "in_sample_balanced_accuracy": agent.get("balanced_accuracy"),
            "choice_scores": choice.get("scores"),
            "choice_stopped": choice.get("stopped", ""),
        }
    agent = next((r for r in res.get("summary") or [] if r.get("who") == "agent"), {})
    return {
        "learners": [f.get("learner") for f in res.get("per_fold", [])],
        "held_out_balanced_accuracy": agent.get("balanced_accuracy"),
        "stopped": [f.get("learner_stopped", "") for f in res.get("per_fold", [])],
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    codes = {"this": ROOT, **({"base": Path(args.base).resolve()} if args.base else {})}
    root = Path(tempfile.mkdtemp(prefix="laneprint-learners-"))
    rows: list[dict[str, Any]] = []
    partial = RESULTS / (Path(args.out).stem + ".partial.json")
    RESULTS.mkdir(parents=True, exist_ok=True)
    try:
        ws = workspace(root)
        capped = root / "episodes.toml"  # `crossval` takes the DQN's episodes from a config file only
        capped.write_text(f"[dqn]\nepisodes = {args.episodes}\n")
        for repeat in range(args.repeats):
            for code_name, code in codes.items():
                for command in args.commands:
                    for learner in args.learners:
                        opts = ["--style", args.style, "--learner", learner, "--seed", str(args.seed), "-w", str(ws)]
                        if args.episodes:
                            opts += ["--config", str(capped)]
                        if command == "crossval" and args.folds:
                            opts += ["--folds", str(args.folds)]
                        wall, res = laneprint(code, command, *opts)
                        rows.append(
                            {
                                **figures(command, res),
                                "code": code_name,
                                "command": command,
                                "learner": learner,
                                "repeat": repeat,
                                "wall_s": round(wall, 1),
                            }
                        )
                        partial.write_text(json.dumps(rows, indent=1) + "\n")  # a crash keeps what was timed
                        print(
                            f"  {code_name:<5} {command:<9} {learner:<6} {wall:6.1f} s  "
                            f"{json.dumps(figures(command, res))[:110]}",
                            flush=True,
                        )
    finally:
        shutil.rmtree(root, ignore_errors=True)
    medians = []
    for code_name in codes:
        for command in args.commands:
            m = {
                lr: median(
                    [r["wall_s"] for r in rows if (r["code"], r["command"], r["learner"]) == (code_name, command, lr)]
                )
                for lr in args.learners
            }
            ratio = round(m["auto"] / m["dqn"], 2) if "auto" in m and "dqn" in m else None
            medians.append({"code": code_name, "command": command, "median_s": m, "auto_over_dqn": ratio})
    result = {
        **({"base_commit": _commit(codes["base"])} if "base" in codes else {}),
        "load_average_at_end": [round(x, 2) for x in os.getloadavg()],
        "style": args.style,
        "seed": args.seed,
        "episodes": args.episodes or "the study's",
        "folds": args.folds or "crossval's default",
        "repeats": args.repeats,
        "medians": medians,
        "runs": rows,
    }
    out = write_result(args.out, result)
    partial.unlink(missing_ok=True)
    print("\nmedian wall time [s] per learner; auto / dqn")
    for m in medians:
        print(
            f"  {m['code']:<5} {m['command']:<9} "
            + "  ".join(f"{lr} {s:6.1f}" for lr, s in m["median_s"].items())
            + (f"   auto/dqn {m['auto_over_dqn']:.2f}" if m["auto_over_dqn"] else "")
        )
    print(f"written to {out}")
    return result


def _commit(path: Path) -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=path, capture_output=True, text=True).stdout.strip()
    except OSError:
        return ""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--style", default="Normal")
    p.add_argument("--learners", type=lambda s: tuple(s.split(",")), default=LEARNERS)
    p.add_argument("--commands", type=lambda s: tuple(s.split(",")), default=COMMANDS)
    p.add_argument("--repeats", type=int, default=1)
    p.add_argument("--episodes", type=int, default=2000, help="cap every agent's episodes (0: the study's, as --full)")
    p.add_argument("--full", action="store_true", help="the study's episodes (30 per recorded approach)")
    p.add_argument("--quick", action="store_true", help="train only")
    p.add_argument("--folds", type=int, default=0, help="crossval's folds (0: its default)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--base", help="another laneprint checkout, timed side by side (before / after)")
    p.add_argument("--out", default="learners.json")
    args = p.parse_args()
    if args.full:
        args.episodes = 0
    if args.quick:
        args.commands = ("train",)
    run(args)


if __name__ == "__main__":
    main()
