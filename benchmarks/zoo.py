"""The analysis judged on a zoo of worlds, one world out (`python benchmarks/analysis.py --zoo ...`).

Worlds (`WORLDS`): laneprint's own generator, SUMO's `ttc`, `acceptance` and `sublane`
families, and highway-env's IDM + MOBIL (a simulator written by others), on two and three
lanes where the generator has them. Each (world, seed) study is generated with
`laneprint simulate`, ingested and its decisions extracted once (cached under `--root`);
then every method (`--methods`: values of `laneprint analyze --features`) reads its styles.

Reported, and written to `benchmarks/results/analysis_zoo.json` with the command, commit,
date and machine:
- per world and method: mean and minimum ARI over the seeds, and the share of drivers whose
  style name is right (Defensive the most cautious group);
- leave-one-world-out: for each world, the method with the best mean ARI on the *other*
  worlds, and its ARI on this one (a choice made without the world it is judged on);
- reliability: stated confidence (binned) against the share of drivers right, pooled over the
  zoo, per method.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from contextlib import nullcontext
from pathlib import Path

import pandas as pd
from sklearn.metrics import adjusted_rand_score

from results_file import write_result  # beside this file

ROOT = Path(__file__).resolve().parents[1]
#: world -> `laneprint simulate` options
WORLDS: dict[str, list[str]] = {
    "synthetic-2": [],
    "sumo-ttc-2": ["--engine", "sumo", "--family", "ttc", "--lanes", "2"],
    "sumo-ttc-3": ["--engine", "sumo", "--family", "ttc", "--lanes", "3"],
    "sumo-acceptance-2": ["--engine", "sumo", "--family", "acceptance", "--lanes", "2"],
    "sumo-acceptance-3": ["--engine", "sumo", "--family", "acceptance", "--lanes", "3"],
    "sumo-sublane-2": ["--engine", "sumo", "--family", "sublane", "--lanes", "2"],
    "sumo-sublane-3": ["--engine", "sumo", "--family", "sublane", "--lanes", "3"],
    "highway-2": ["--engine", "highway", "--lanes", "2"],
    "highway-3": ["--engine", "highway", "--lanes", "3"],
}
METHODS: tuple[str, ...] = ("auto", "heldout", "behaviour")
BINS = (0.0, 0.5, 0.7, 0.8, 0.9, 1.0001)


def laneprint(*args: str) -> None:
    exe = Path(sys.executable).with_name("laneprint")
    subprocess.run([str(exe), *args], check=True, stdout=subprocess.DEVNULL)


def paths(world: str, seed: int, root: Path, shares: str = "") -> tuple[Path, Path]:
    """(study folder, workspace) where the study of `world`, `seed` (and style `shares`, e.g. "2,4,3"; ""
    the world's own) is cached."""
    out = root / (f"{world}-{seed}" + (f"-shares{shares.replace(',', '')}" if shares else ""))
    return out, out.with_name(out.name + ".ws")


def study(world: str, seed: int, root: Path, shares: str = "") -> tuple[Path, Path]:
    """(study folder, workspace) of one world and seed, generated and ingested unless cached."""
    out, ws = paths(world, seed, root, shares)
    if not (out / "ground_truth.json").exists():
        extra = ["--shares", shares] if shares else []
        laneprint(
            "simulate", "--out", str(out), "--seed", str(seed), "--format", "csv", "--force", *WORLDS[world], *extra
        )
    if not (ws / "recordings").is_dir():
        laneprint("ingest", str(out), "-w", str(ws), "--json")
    return out, ws


def decisions_of(ws: Path) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """The workspace's decisions and following episodes (cached beside it) and its drivers."""
    from clustering.pipeline import extract_all
    from indicators.settings import AnalysisSettings
    from laneprint.workspace import Workspace

    cache_d, cache_f = ws / "zoo_decisions.parquet", ws / "zoo_following.parquet"
    w = Workspace(ws)
    drivers = sorted(w.recordings()["driver_id"].astype(str).unique())
    if cache_d.exists() and cache_f.exists():
        dec = pd.read_parquet(cache_d)
        if "drive_s" in dec:  # else cached before the decisions carried the drive time: extracted again
            return dec, pd.read_parquet(cache_f), drivers
    dec, _, _, following = extract_all(w, AnalysisSettings())
    dec.to_parquet(cache_d)
    following.to_parquet(cache_f)
    return dec, following, drivers


def judge(world: str, seed: int, root: Path, methods: tuple[str, ...], shares: str = "") -> list[dict]:
    """One row per (method, driver): truth, style, confidence, presses; plus the method's ARI."""
    from clustering.pipeline import analyze_tables
    from indicators.settings import AnalysisSettings

    out, ws = study(world, seed, root, shares)
    truth = {d["driver_id"]: d["style"] for d in json.loads((out / "ground_truth.json").read_text())["drivers"]}
    dec, following, drivers = decisions_of(ws)
    rows = []
    for method in methods:
        t0 = time.perf_counter()
        st = analyze_tables(dec, AnalysisSettings(features=method), drivers=drivers, following=following)["styles"]
        seconds = time.perf_counter() - t0
        st = st[st["driver_id"].isin(truth)]
        a = float(adjusted_rand_score([truth[d] for d in st["driver_id"]], st["style"]))
        for r in st.itertuples():
            rows.append(
                {
                    "world": world,
                    "seed": seed,
                    "shares": shares or "world",
                    "method": method,
                    "driver": r.driver_id,
                    "truth": truth[r.driver_id],
                    "style": r.style,
                    "confidence": float(r.confidence),
                    "presses": int(r.n_decisions),
                    "ari": a,
                    "seconds": seconds,
                    "unsure": str(r.unsure),
                }
            )
    return rows


def summarise(df: pd.DataFrame) -> dict:
    """Per world and method, leave-one-world-out, and reliability tables (JSON-ready)."""
    if "shares" not in df:
        df = df.assign(shares="world")
    studies = df.groupby(["world", "method", "seed", "shares"]).agg(
        ari=("ari", "first"), named=("right", "mean"), seconds=("seconds", "first")
    )
    per = (
        studies.groupby(["world", "method"])
        .agg(
            mean_ari=("ari", "mean"),
            min_ari=("ari", "min"),
            names_right=("named", "mean"),
            seeds=("ari", "size"),
            median_seconds=("seconds", "median"),
        )
        .reset_index()
    )
    lowo = []
    for world in sorted(per["world"].unique()):
        others = per[per["world"] != world].groupby("method")["mean_ari"].mean()
        if others.empty:
            continue
        pick = str(others.idxmax())
        here = per[(per["world"] == world) & (per["method"] == pick)].iloc[0]
        lowo.append(
            {
                "world": world,
                "method_chosen_elsewhere": pick,
                "mean_ari": float(here["mean_ari"]),
                "min_ari": float(here["min_ari"]),
                "names_right": float(here["names_right"]),
            }
        )
    rel = []
    for method, g in df.groupby("method"):
        bins = pd.cut(g["confidence"], BINS, right=False)
        for interval, h in g.groupby(bins, observed=True):
            rel.append(
                {
                    "method": method,
                    "confidence": f"[{interval.left:.1f}, {min(interval.right, 1.0):.1f})",
                    "drivers": int(len(h)),
                    "share_right": float(h["right"].mean()),
                }
            )
        hi = g[g["confidence"] >= 0.9]
        rel.append(
            {
                "method": method,
                "confidence": ">= 0.9",
                "drivers": int(len(hi)),
                "share_right": float(hi["right"].mean()) if len(hi) else None,
            }
        )
    by_shares = (
        studies.groupby(["world", "method", "shares"])
        .agg(mean_ari=("ari", "mean"), min_ari=("ari", "min"), names_right=("named", "mean"), seeds=("ari", "size"))
        .reset_index()
    )
    return {
        "per_world": per.to_dict("records"),
        "per_world_and_shares": by_shares.to_dict("records"),
        "leave_one_world_out": lowo,
        "reliability": rel,
    }


def cached(world: str, seed: int, root: Path, shares: str = "") -> bool:
    """Whether the study of `world` and `seed` is generated, ingested and its decisions extracted under `root`."""
    out, ws = paths(world, seed, root, shares)
    return (out / "ground_truth.json").exists() and (ws / "zoo_decisions.parquet").exists()


def run(
    worlds: list[str],
    seeds: list[int],
    root: Path,
    methods: tuple[str, ...],
    out_name: str,
    cached_only: bool = False,
    shares: tuple[str, ...] = ("",),
    jobs: int = 1,
) -> dict:
    """Judge every method on every (world, seed), generating what is not cached (`cached_only`: skip it),
    `jobs` studies at a time (each in its own process; the rows are the same as one at a time)."""
    root.mkdir(parents=True, exist_ok=True)
    todo = []
    for world, share, seed in ((w, sh, s) for w in worlds for sh in shares for s in seeds):
        if cached_only and not cached(world, seed, root, share):
            print(f"  {world:<18} seed {seed:5d} {share} not generated yet: left out", flush=True)
            continue
        todo.append((world, seed, root, methods, share))
    rows = []
    with ProcessPoolExecutor(max_workers=jobs) if jobs > 1 else nullcontext() as pool:
        results = pool.map(_timed_judge, todo) if pool else map(_timed_judge, todo)
        for (world, seed, _, _, share), (study_rows, seconds, error) in zip(todo, results):
            if study_rows is None:
                print(f"  {world} seed {seed} {share}: generation failed ({error})", flush=True)
                continue
            rows += study_rows
            print(
                f"  {world:<18} seed {seed:5d} {share:6s}"
                + "  ".join(f"{m} {next(r['ari'] for r in study_rows if r['method'] == m):.2f}" for m in methods)
                + f"  ({seconds:.0f} s)",
                flush=True,
            )
    df = pd.DataFrame(rows)
    df["right"] = df["style"] == df["truth"]
    result = {
        "worlds": worlds,
        "seeds": seeds,
        "shares": [sh or "world" for sh in shares],
        "methods": list(methods),
        **summarise(df),
        "drivers": df.to_dict("records"),
    }
    write_result(out_name, result)
    print_tables(result)
    return result


def _timed_judge(task: tuple) -> tuple[list[dict] | None, float, str]:
    """(`judge(*task)`, its seconds, ""); (None, seconds, why) for a study that could not be generated."""
    t0 = time.perf_counter()
    try:
        return judge(*task), time.perf_counter() - t0, ""
    except subprocess.CalledProcessError as exc:
        return None, time.perf_counter() - t0, str(exc)


def print_tables(result: dict) -> None:
    per = pd.DataFrame(result["per_world"])
    print("\nmean ARI (min) per world and method; share of drivers named right")
    for world, g in per.groupby("world"):
        print(
            f"  {world:<18} "
            + "  ".join(
                f"{r.method} {r.mean_ari:.2f} ({r.min_ari:.2f}) {100 * r.names_right:.0f} %" for r in g.itertuples()
            )
        )
    by_shares = pd.DataFrame(result.get("per_world_and_shares", []))
    if not by_shares.empty and by_shares["shares"].nunique() > 1:
        print("\nper style shares (the world's own, or Defensive,Normal,Aggressive): mean ARI (min), names right")
        for r in by_shares.itertuples():
            print(
                f"  {r.world:<18} {r.shares:<7} {r.method:<10} {r.mean_ari:.2f} ({r.min_ari:.2f}) "
                f"{100 * r.names_right:.0f} %  {r.seeds} seeds"
            )
    print("\nleave one world out: the method best on the other worlds, judged on this one")
    for r in result["leave_one_world_out"]:
        print(
            f"  {r['world']:<18} {r['method_chosen_elsewhere']:<10} mean ARI {r['mean_ari']:.2f}, "
            f"min {r['min_ari']:.2f}, names right {100 * r['names_right']:.0f} %"
        )
    print("\nreliability: stated confidence against the share of drivers right (pooled over the zoo)")
    for r in result["reliability"]:
        share = "-" if r["share_right"] is None else f"{100 * r['share_right']:.0f} %"
        print(f"  {r['method']:<10} {r['confidence']:<12} {r['drivers']:4d} drivers  right {share}")
