"""Do the agents decide like drivers on data laneprint did not write? Held out by session.

For each study (a SUMO study generated with a seed nobody tuned on, and the shipped
synthetic study), through the real command line:

1. `laneprint ingest` + `laneprint analyze`; on a study with ground truth, the
   adjusted Rand index of the styles;
2. `laneprint crossval --all` (sessions in K folds; lines, scenes, agent and
   imitation classifier from the other folds): per style, balanced accuracy of
   agent / greedy / imitation with bootstrap 95 % intervals, timing error, share
   of decisions scored;
3. on the shipped study, the in-sample figures of `laneprint train --style S`
   (recall at the typical driver's presses vs the study's, balanced accuracy vs greedy).

Prints a table per study and whether each acceptance line holds (agent >= greedy + 10
points and >= imitation - 5, timing error below greedy's, 95 % of decisions scored, styles
ARI >= 0.9); with several SUMO seeds (never judge on one), a last table of every seed's
margins and which checks failed. The figures and checks are written to
`benchmarks/results/generalization.json` (`--out NAME`) with the command, commit, date and machine.

Each world of the zoo (`benchmarks/zoo.py`), one study per world from its cache, instead of the SUMO
seeds: `--zoo all --zoo-root /tmp/laneprint-zoo-final --zoo-seed 9501 --skip-sumo`.

Run: python benchmarks/generalization.py [--sumo-seed 7 [8 ...]] [--jobs 2] [--drivers 9]
     [--episodes 10000] [--learner auto|dqn|trees] [--folds 4] [--seed 0] [--workdir /tmp/lp-generalization]
     [--skip-shipped] [--skip-sumo]

The bar per style and direction from stored `crossval --all --json` documents
(agent >= greedy + 10 points and >= imitation - 5), one column per document:

     python benchmarks/generalization.py --direction-table A.json [B.json ...] [--labels a b ...]
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path
from typing import TextIO

from results_file import write_result  # beside this file

from sklearn.metrics import adjusted_rand_score

ROOT = Path(__file__).resolve().parents[1]
LAPRINT = [sys.executable, "-m", "laneprint.app.cli"]
STUDY_RECALL = {"Defensive": 0.959, "Normal": 1.0, "Aggressive": 0.986}  # the paper's agents (section 5)


def cli(*args: str) -> dict:
    """Run a laneprint command with --json and return its document (exit on failure)."""
    proc = subprocess.run([*LAPRINT, *args, "--json"], capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        sys.exit(f"laneprint {' '.join(args)} failed: {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout)


def learner_option(args: argparse.Namespace) -> list[str]:
    """`--learner NAME` when one was asked for; otherwise the commands' own default ('auto')."""
    return ["--learner", args.learner] if args.learner else []


def ari(ws: Path, logs: Path) -> float | None:
    truth_path = logs / "ground_truth.json"
    if not truth_path.exists():
        return None
    truth = {d["driver_id"]: d["style"] for d in json.loads(truth_path.read_text())["drivers"]}
    sys.path.insert(0, str(ROOT))
    from laneprint.workspace import Workspace

    st = Workspace(ws).read_table("analysis", "styles")
    st = st[st["driver_id"].isin(truth)]
    return float(adjusted_rand_score([truth[d] for d in st["driver_id"]], st["style"]))


def pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f}"


Checks = list[tuple[str, bool]]


def held_out_table(name: str, results: list[dict], out: TextIO) -> Checks:
    """Print one study's held-out table to `out`; returns the acceptance checks, named."""
    say = partial(print, file=out)
    say(f"\n## {name}: held out by session")
    say(
        "| style | agent bal. acc. [95 % CI] | greedy | imitation | agent - greedy | agent - imitation "
        "| timing MAE agent / greedy [s] | recall agent | scored |"
    )
    say("|---|---|---|---|---|---|---|---|---|")
    checks = []
    for res in results:
        rows = {r["who"]: r for r in res["summary"]}
        a, g, m = rows["agent"], rows["greedy"], rows["imitation"]
        lo, hi = a["balanced_accuracy_ci"]
        d_g = a["balanced_accuracy"] - g["balanced_accuracy"]
        d_m = a["balanced_accuracy"] - m["balanced_accuracy"]
        ta, tg = a["timing_mae_s"], g["timing_mae_s"]
        say(
            f"| {res['target']['name']} | {pct(a['balanced_accuracy'])} [{pct(lo)}, {pct(hi)}] "
            f"| {pct(g['balanced_accuracy'])} | {pct(m['balanced_accuracy'])} | {100 * d_g:+.1f} | {100 * d_m:+.1f} "
            f"| {ta if ta is None else round(ta, 2)} / {tg if tg is None else round(tg, 2)} | {pct(a['recall'])} "
            f"| {res['n_decisions_scored']}/{res['n_decisions_total']} |"
        )
        style = res["target"]["name"]
        checks += [
            (f"{style}: agent >= greedy + 10", d_g >= 0.10),
            (f"{style}: agent >= imitation - 5", d_m >= -0.05),
            (f"{style}: timing error below greedy's", ta is not None and tg is not None and ta < tg),
            (f"{style}: 95 % scored", res["scored_share"] >= 0.95),
        ]
    return checks


def study(
    name: str, logs: Path, ws: Path, args: argparse.Namespace, out: TextIO = sys.stdout
) -> tuple[Checks, list[dict], float | None]:
    say = partial(print, file=out)
    t0 = time.perf_counter()
    if not (ws / "analysis" / "styles.parquet").exists():
        cli("ingest", str(logs), "-w", str(ws))
        cli("analyze", "-w", str(ws))
    score = ari(ws, logs)
    say(f"\n# {name} ({logs}); styles ARI vs ground truth: {score if score is None else round(score, 3)}")
    extra = (["--episodes", str(args.episodes)] if args.episodes else []) + learner_option(args)
    res = cli("crossval", "--all", "--folds", str(args.folds), "--seed", str(args.seed), "-w", str(ws), *extra)
    checks = held_out_table(name, res["results"], out)
    if score is not None:
        checks.append(("styles ARI >= 0.9", score >= 0.9))
    say(f"({time.perf_counter() - t0:.0f} s)")
    return checks, res["results"], score


def held_out_rows(results: list[dict]) -> list[dict]:
    """Per style: the held-out balanced accuracy of agent / greedy / imitation, the agent's interval,
    timing errors, recall and the share scored (a crossval --all document's `results`)."""
    rows = []
    for res in results:
        who = {r["who"]: r for r in res["summary"]}
        a, g, m = who["agent"], who["greedy"], who["imitation"]
        rows.append(
            {
                "style": res["target"]["name"],
                "agent": a["balanced_accuracy"],
                "agent_lo": a["balanced_accuracy_ci"][0],
                "agent_hi": a["balanced_accuracy_ci"][1],
                "greedy": g["balanced_accuracy"],
                "imitation": m["balanced_accuracy"],
                "timing_mae_agent_s": a["timing_mae_s"],
                "timing_mae_greedy_s": g["timing_mae_s"],
                "recall_agent": a["recall"],
                "scored_share": res["scored_share"],
            }
        )
    return rows


def in_sample_shipped(ws: Path, args: argparse.Namespace, table: list[dict] | None = None) -> Checks:
    print("\n## shipped study: in-sample (`laneprint train --style S`, typical driver)")
    print("| style | recall (study) | balanced acc. agent / greedy / imitation | timing MAE agent / greedy [s] |")
    print("|---|---|---|---|")
    checks = []
    for style in ("Defensive", "Normal", "Aggressive"):
        extra = (["--episodes", str(args.episodes)] if args.episodes else []) + learner_option(args)
        run = cli("train", "--style", style, "--seed", str(args.seed), "-w", str(ws), *extra)
        rows = {r["who"]: r for r in run["evaluation"]}
        a, g = rows["agent"], rows["greedy"]
        m = rows.get("imitation", {}).get("balanced_accuracy")
        print(
            f"| {style} | {pct(a['recall'])} ({pct(STUDY_RECALL[style])}) | {pct(a['balanced_accuracy'])} / "
            f"{pct(g['balanced_accuracy'])} / {pct(m)} | {a['timing_mae_s']:.2f} / {g['timing_mae_s']:.2f} |"
        )
        if table is not None:
            table.append(
                {
                    "style": style,
                    "recall_agent": a["recall"],
                    "recall_study": STUDY_RECALL[style],
                    "agent": a["balanced_accuracy"],
                    "greedy": g["balanced_accuracy"],
                    "imitation": m,
                    "timing_mae_agent_s": a["timing_mae_s"],
                    "timing_mae_greedy_s": g["timing_mae_s"],
                }
            )
        checks += [
            (f"{style}: in-sample recall >= the study's", a["recall"] >= STUDY_RECALL[style] - 1e-9),
            (f"{style}: in-sample >= greedy + 5", a["balanced_accuracy"] >= g["balanced_accuracy"] + 0.05),
        ]
    return checks


def sumo_study(seed: int, args: argparse.Namespace) -> tuple[str, Checks, list[dict], float | None]:
    """Simulate (once), analyse and cross-validate one SUMO study; its printout is returned, not printed."""
    logs = args.workdir / f"sumo{args.drivers}_s{seed}"
    out = io.StringIO()  # studies run in threads: each writes its own printout
    if not (logs / "ground_truth.json").exists():
        cli("simulate", "--engine", "sumo", "--out", str(logs), "--drivers", str(args.drivers), "--seed", str(seed))
    checks, results, score = study(
        f"SUMO study, seed {seed}", logs, args.workdir / f"ws_sumo{args.drivers}_s{seed}", args, out
    )
    return out.getvalue(), checks, results, score


def zoo_study(world: str, args: argparse.Namespace) -> tuple[Checks, list[dict], float | None]:
    """Analyse and cross-validate the zoo's study of `world` at `--zoo-seed` (generated once, cached)."""
    import zoo  # beside this file

    logs, _ = zoo.study(world, args.zoo_seed, args.zoo_root)
    return study(f"{world}, seed {args.zoo_seed}", logs, args.workdir / f"ws_{world}_{args.zoo_seed}", args)


def seeds_table(runs: dict[int, tuple[Checks, list[dict], float | None]]) -> None:
    """One row per SUMO seed: ARI, per style agent - greedy / agent - imitation, failed checks."""
    print("\n## SUMO seeds: agent - greedy / agent - imitation, balanced accuracy points")
    styles = ("Defensive", "Normal", "Aggressive")
    print("| seed | ARI | " + " | ".join(styles) + " | checks failed |")
    print("|---|---|" + "---|" * len(styles) + "---|")
    for seed, (checks, results, score) in runs.items():
        cells = []
        for style in styles:
            res = next((r for r in results if r["target"]["name"] == style), None)
            if res is None:
                cells.append("-")
                continue
            rows = {r["who"]: r["balanced_accuracy"] for r in res["summary"]}
            cells.append(
                f"{100 * (rows['agent'] - rows['greedy']):+.1f} / {100 * (rows['agent'] - rows['imitation']):+.1f}"
            )
        failed = [n for n, ok in checks if not ok]
        print(
            f"| {seed} | {score if score is None else round(score, 2)} | "
            + " | ".join(cells)
            + f" | {'; '.join(failed) or 'none'} |"
        )
    held = sum(all(ok for _, ok in c) for c, _, _ in runs.values())
    print(f"\nevery check holds on {held} of {len(runs)} SUMO seeds")


def direction_table(paths: list[Path], labels: list[str] | None) -> None:
    """Balanced accuracy (%) of agent / greedy / imitation per style, pooled and per direction, from crossval
    documents; then how many (style, direction) cells meet agent >= greedy + 10 and >= imitation - 5."""
    docs = [json.loads(p.read_text()) for p in paths]
    labels = labels or [p.stem for p in paths]
    print(
        "| style | direction | " + " | ".join(f"{lab}: agent [95 % CI] / greedy / imitation" for lab in labels) + " |"
    )
    print("|---|---|" + "---|" * len(docs))
    met = {lab: [] for lab in labels}
    styles = [r["target"]["name"] for r in docs[0]["results"]]
    for style in styles:
        for direction in ("pooled", "left", "right"):
            cells = []
            for lab, doc in zip(labels, docs):
                res = next(r for r in doc["results"] if r["target"]["name"] == style)
                rows = (
                    res["summary"]
                    if direction == "pooled"
                    else [r for r in res["summary_by_direction"] if r["direction"] == direction]
                )
                ba = {r["who"]: r for r in rows}
                if "agent" not in ba:
                    cells.append("-")
                    continue
                a, g, i = (100 * ba[w]["balanced_accuracy"] for w in ("agent", "greedy", "imitation"))
                lo, hi = (100 * x for x in ba["agent"]["balanced_accuracy_ci"])
                ok = a >= g + 10 and a >= i - 5
                if direction != "pooled":
                    met[lab].append((f"{style} {direction}", ok))
                cells.append(
                    f"{'**' if ok else ''}{a:.1f}{'**' if ok else ''} [{lo:.1f}, {hi:.1f}] / {g:.1f} / {i:.1f}"
                )
            print(f"| {style} | {direction} | " + " | ".join(cells) + " |")
    print("\n(bold: agent >= greedy + 10 and >= imitation - 5)")
    for lab, checks in met.items():
        failed = [n for n, ok in checks if not ok]
        print(
            f"- {lab}: {sum(ok for _, ok in checks)} of {len(checks)} style x direction cells meet the bar"
            + (f" (not: {'; '.join(failed)})" if failed else "")
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--direction-table",
        type=Path,
        nargs="+",
        help="crossval --all --json documents: the bar per style and direction",
    )
    ap.add_argument("--labels", nargs="+", help="--direction-table: a column name per document")
    ap.add_argument(
        "--sumo-seed", type=int, nargs="+", default=[7], help="seed(s) of the SUMO studies (ones nobody tuned on)"
    )
    ap.add_argument("--jobs", type=int, default=1, help="SUMO studies run at once (each is one process)")
    ap.add_argument("--drivers", type=int, default=9)
    ap.add_argument("--episodes", type=int, default=None, help="episodes per agent (default: train's)")
    ap.add_argument(
        "--learner",
        choices=("auto", "dqn", "trees"),
        default=None,
        help="who learns the agents (train/crossval --learner; default: theirs)",
    )
    ap.add_argument("--folds", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0, help="seed of folds, agents, classifier, bootstrap")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/lp-generalization"))
    ap.add_argument("--skip-sumo", action="store_true")
    ap.add_argument("--zoo", default="", help="worlds of benchmarks/zoo.py, comma-separated ('all': every one)")
    ap.add_argument("--zoo-root", type=Path, default=Path("/tmp/laneprint-zoo"), help="where zoo studies are cached")
    ap.add_argument("--zoo-seed", type=int, default=9501, help="the zoo study's seed (one per world)")
    ap.add_argument("--skip-shipped", action="store_true")
    ap.add_argument("--out", default="generalization", help="result file name under benchmarks/results/")
    args = ap.parse_args()
    if args.direction_table:
        direction_table(args.direction_table, args.labels)
        return
    args.workdir.mkdir(parents=True, exist_ok=True)
    checks: dict[str, Checks] = {}
    runs: dict[int, tuple[Checks, list[dict], float | None]] = {}
    held_out: list[dict] = []
    in_sample: list[dict] = []
    if not args.skip_sumo:
        with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            for seed, (text, c, results, score) in zip(
                args.sumo_seed, pool.map(lambda s: sumo_study(s, args), args.sumo_seed)
            ):
                print(text, end="", flush=True)
                checks[f"SUMO study, seed {seed}"] = c
                runs[seed] = (c, results, score)
                held_out += [{"study": f"SUMO seed {seed}", "styles_ari": score, **r} for r in held_out_rows(results)]
    if args.zoo:
        from zoo import WORLDS  # beside this file

        for world in list(WORLDS) if args.zoo == "all" else args.zoo.split(","):
            c, results, score = zoo_study(world, args)
            checks[f"{world}, seed {args.zoo_seed}"] = c
            held_out += [
                {"study": world, "seed": args.zoo_seed, "styles_ari": score, **r} for r in held_out_rows(results)
            ]
    if not args.skip_shipped:
        ws = args.workdir / "ws_shipped"
        checks["shipped study"], results, score = study("shipped study", ROOT / "sample_logs", ws, args)
        held_out += [{"study": "shipped", "styles_ari": score, **r} for r in held_out_rows(results)]
        checks["shipped in-sample"] = in_sample_shipped(ws, args, in_sample)
    print("\n## acceptance")
    for name, c in checks.items():
        failed = [n for n, ok in c if not ok]
        print(
            f"- {name}: {sum(ok for _, ok in c)} of {len(c)} checks hold"
            + (f" (not: {'; '.join(failed)})" if failed else "")
        )
    if len(runs) > 1:
        seeds_table(runs)
    write_result(
        args.out,
        {
            "sumo_seeds": [] if args.skip_sumo else args.sumo_seed,
            "zoo": args.zoo.split(",") if args.zoo else [],
            "zoo_seed": args.zoo_seed if args.zoo else None,
            "drivers": args.drivers,
            "folds": args.folds,
            "seed": args.seed,
            "episodes": args.episodes or "train's",
            "learner": args.learner or "auto",
            "held_out": held_out,
            "in_sample_shipped": in_sample,
            "checks": [
                {
                    "study": name,
                    "held": sum(ok for _, ok in c),
                    "of": len(c),
                    "failed": "; ".join(n for n, ok in c if not ok),
                }
                for name, c in checks.items()
            ],
        },
    )


if __name__ == "__main__":
    main()
