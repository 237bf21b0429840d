"""Benchmark and accuracy check of the analysis stage (`laneprint analyze`).

Prints:
1. the shipped study (optional, `--workspace W` holding `sample_logs/` ingested): ARI of the
   styles against `sample_logs/ground_truth.json`, and for the study's typical drivers
   whether Table 1's A and b fall inside the recovered 95 % intervals;
2. over `--seeds` simulator seeds (default 20): mean/min ARI, and how often each typical
   driver's true A and b fall inside the recovered intervals (per style x indicator);
   also decision-extraction time per recording (median) and agreement of the extracted
   indicators with the simulator's own ground truth;
3. timing of `analyze_tables` for 10 x 50 and 1,000 x 50 drivers x decisions (tables
   generated in memory, 10 keep states per press), median of `--repeats` runs.

4. optionally (`--messy N`), harder studies: ARI per clustering-feature variant;
5. optionally (`--study DIR WORKSPACE`, repeated), studies written by `laneprint simulate`
   (their ground_truth.json) and ingested into WORKSPACE: ARI per feature set (`--features`
   auto, ttc, paper, headway, acceptance, all, following), the set 'auto' chose, and the flagged per-driver
   lines of the study's three indicators.

6. optionally (`--zoo WORLD,... --zoo-seeds S ...`), the zoo of worlds judged one world out
   (`benchmarks/zoo.py`): ARI per world and method, the leave-one-world-out table and the
   reliability of the stated confidence, written to `benchmarks/results/analysis_zoo.json`.

Sections 1-5 are also written to `benchmarks/results/analysis.json` (`--out NAME`) with the command,
commit, date and machine.

Run: .venv/bin/python benchmarks/analysis.py [--seeds 20] [--workspace /tmp/ws] [--messy 12]
     [--study /tmp/s200 /tmp/ws200 ...] [--seeds 0 --repeats 0: only what is asked]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.metrics import adjusted_rand_score

from clustering.pipeline import analyze, analyze_tables
from indicators.decisions import extract_decisions
from indicators.settings import AnalysisSettings
from laneprint.reference import INDICATORS
from laneprint.simulator import StudySettings, simulate_study
from laneprint.workspace import Workspace

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout: the test tools (tests.support)

from tests.support.synthetic_decisions import make_decision_table  # noqa: E402
from results_file import write_result  # noqa: E402  (beside this file)


def coverage(fits: pd.DataFrame, drivers: list[dict]) -> list[dict]:
    """Per ground-truth typical driver and indicator: is the true A / b inside the 95 % CI?"""
    f = fits.set_index(["driver_id", "indicator"])
    rows = []
    for d in drivers:
        if not d["typical"]:
            continue
        for ind in INDICATORS:
            A, b = d["lines"][ind]["A"], d["lines"][ind]["b"]
            r = f.loc[(d["driver_id"], ind)] if (d["driver_id"], ind) in f.index else None
            ok = r is not None and r["status"] == "ok"
            rows.append(
                {
                    "style": d["style"],
                    "driver_id": d["driver_id"],
                    "indicator": ind,
                    "A_true": A,
                    "b_true": b,
                    "A": r["A"] if ok else np.nan,
                    "A_lo": r["A_lo"] if ok else np.nan,
                    "A_hi": r["A_hi"] if ok else np.nan,
                    "b": r["b"] if ok else np.nan,
                    "b_lo": r["b_lo"] if ok else np.nan,
                    "b_hi": r["b_hi"] if ok else np.nan,
                    "A_in": bool(ok and r["A_lo"] <= A <= r["A_hi"]),
                    "b_in": bool(ok and r["b_lo"] <= b <= r["b_hi"]),
                    "n": int(r["n"]) if ok else 0,
                }
            )
    return rows


def ari(styles: pd.DataFrame, drivers: list[dict]) -> float:
    truth = {d["driver_id"]: d["style"] for d in drivers}
    st = styles[styles["driver_id"].isin(truth)]
    return float(adjusted_rand_score([truth[d] for d in st["driver_id"]], st["style"]))


def shipped(workspace: Path) -> dict:
    gt = json.loads((ROOT / "sample_logs" / "ground_truth.json").read_text())
    ws = Workspace(workspace)
    t0 = time.perf_counter()
    analyze(ws, AnalysisSettings())
    dt = time.perf_counter() - t0
    styles = ws.read_table("analysis", "styles")
    fits = ws.read_table("analysis", "fits")
    print(f"== shipped study ({workspace}): analyze {dt:.1f} s")
    print(f"ARI against ground truth: {ari(styles, gt['drivers']):.3f}")
    named = dict(zip(styles["driver_id"], styles["style"]))
    truth = {d["driver_id"]: d["style"] for d in gt["drivers"]}
    print(f"style names equal to the true names: {sum(named.get(d) == s for d, s in truth.items())}/{len(truth)}")
    cov = coverage(fits, gt["drivers"])
    for r in cov:
        print(
            f"  {r['style']:<10} {r['driver_id']} {r['indicator']:<5} "
            f"A {r['A']:.3f} [{r['A_lo']:.3f}, {r['A_hi']:.3f}] true {r['A_true']:.2f} {'in' if r['A_in'] else 'OUT'}   "
            f"b {r['b']:.2f} [{r['b_lo']:.2f}, {r['b_hi']:.2f}] true {r['b_true']:.2f} {'in' if r['b_in'] else 'OUT'}"
            f"   n={r['n']}"
        )
    return {
        "analyze_s": dt,
        "ari": ari(styles, gt["drivers"]),
        "names_right": sum(named.get(d) == s for d, s in truth.items()),
        "drivers": len(truth),
        "typical_lines": [
            {k: r[k] for k in ("style", "driver_id", "indicator", "A", "A_true", "A_in", "b", "b_true", "b_in", "n")}
            for r in cov
        ],
    }


def seeds(n_seeds: int) -> dict:
    print(f"== {n_seeds} simulator seeds (default study settings)")
    aris, cov_rows, extract_times, samples, mism = [], [], [], [], 0
    n_checked = 0
    settings = AnalysisSettings()
    for seed in range(n_seeds):
        study = simulate_study(StudySettings(), seed=seed)
        frames = []
        for meta, ego, traffic in study.recordings:
            meta = dict(meta, recording_id=meta["session_id"])
            t0 = time.perf_counter()
            dec, _ = extract_decisions(meta, ego, traffic, settings)
            extract_times.append(time.perf_counter() - t0)
            samples.append(len(ego))
            frames.append(dec)
        dec = pd.concat(frames, ignore_index=True)
        # extracted indicators at the presses against the simulator's own values
        gt = pd.DataFrame(study.ground_truth["decisions"])
        pr = dec[dec["label"] == "change"].merge(gt, on=["session_id", "press_t_s"], suffixes=("", "_gt"))
        for c in ("t_f_s", "t_nf_s", "dv_nb_mps"):
            a, b = pr[c].to_numpy(float), pr[c + "_gt"].astype(float).to_numpy()
            mism += int((~np.isclose(a, b, atol=1e-6, equal_nan=True)).sum())
        n_checked += len(pr) * 3
        out = analyze_tables(dec, settings)
        aris.append(ari(out["styles"], study.ground_truth["drivers"]))
        cov_rows += coverage(out["fits"], study.ground_truth["drivers"])
        print(f"  seed {seed:2d}: ARI {aris[-1]:.3f}", flush=True)
    cov = pd.DataFrame(cov_rows)
    print(
        f"mean ARI {np.mean(aris):.3f} (min {np.min(aris):.3f}, ARI = 1 in {sum(a == 1.0 for a in aris)}/{len(aris)} seeds)"
    )
    print(f"extracted indicators equal to the simulator's at the presses: {n_checked - mism}/{n_checked}")
    print("true line inside the recovered 95 % CI, typical drivers (share of seeds):")
    tab = cov.groupby(["style", "indicator"])[["A_in", "b_in"]].mean().unstack("indicator")
    print(tab.round(2).to_string())
    print(f"overall: A {cov['A_in'].mean():.3f}, b {cov['b_in'].mean():.3f} (nominal 0.95)")
    ms = np.array(extract_times) * 1000
    print(
        f"decision extraction: median {np.median(ms):.1f} ms per recording "
        f"(median {int(np.median(samples))} samples at 50 Hz, ~12 presses), "
        f"{np.sum(samples) / np.sum(extract_times) / 1e3:.0f} k samples/s"
    )
    return {
        "seeds": n_seeds,
        "mean_ari": float(np.mean(aris)),
        "min_ari": float(np.min(aris)),
        "seeds_ari_1": sum(a == 1.0 for a in aris),
        "indicators_equal": n_checked - mism,
        "indicators_checked": n_checked,
        "ci_coverage_A": float(cov["A_in"].mean()),
        "ci_coverage_b": float(cov["b_in"].mean()),
        "extraction_median_ms_per_recording": float(np.median(ms)),
        "extraction_k_samples_per_s": float(np.sum(samples) / np.sum(extract_times) / 1e3),
    }


def timing(repeats: int) -> list[dict]:
    print("== analyze_tables timing (decision tables generated in memory, 10 keep states per press)")
    rows = []
    for n_drivers in (10, 1000):
        df, truth = make_decision_table(n_drivers, 50, seed=0)
        times = []
        for _ in range(repeats if n_drivers <= 10 else max(1, repeats // 2)):
            t0 = time.perf_counter()
            out = analyze_tables(df)
            times.append(time.perf_counter() - t0)
        a = adjusted_rand_score([truth[d] for d in out["styles"]["driver_id"]], out["styles"]["style"])
        print(
            f"  {n_drivers:5d} drivers x 50 decisions ({len(df):,} rows): median {statistics.median(times):.2f} s "
            f"over {len(times)} run(s), ARI {a:.3f}"
        )
        rows.append(
            {
                "drivers": n_drivers,
                "decisions_per_driver": 50,
                "rows": len(df),
                "median_s": statistics.median(times),
                "runs": len(times),
                "ari": float(a),
            }
        )
    return rows


MESSY = dict(
    share_slowed=0.25,
    share_no_target_leader=0.45,
    noise_ttc_s=0.8,
    noise_dv_mps=2.0,
    sample_rate_hz=10.0,
    slowed_creep_mps=(0.5, 3.0),
)


def messy(n_seeds: int) -> list[dict]:
    """Harder studies (more decisions behind slow leaders with TTCs of tens of seconds, no
    target-lane leader in 45 %, twice the noise, 10 Hz): ARI per feature-line variant."""
    from dataclasses import replace

    print(f"== messy studies ({MESSY}), {n_seeds} seeds: ARI per clustering-feature variant")
    base = AnalysisSettings(n_bootstrap=0)
    variants = {
        "huber on log TTC (default)": base,
        "huber, lines extrapolated": base.with_(feature_extrapolate=True),
        "theilsen on log TTC": base.with_(feature_fit="theilsen"),
        "median (flat line) of log TTC": base.with_(feature_fit="median"),
        "ols on log TTC": base.with_(feature_fit="ols"),
        "ols on raw TTC": base.with_(feature_fit="ols", feature_log=False),
        "huber, with dv_nb features": base.with_(feature_indicators=("t_f", "t_nf", "dv_nb")),
    }
    res: dict[str, list[float]] = {k: [] for k in variants}
    for seed in range(n_seeds):
        try:
            study = simulate_study(replace(StudySettings(), **MESSY), seed=seed)
        except RuntimeError as exc:  # the simulator cannot always place such scenes
            print(f"  seed {seed:2d}: simulator failed ({exc})")
            continue
        dec = pd.concat(
            [extract_decisions(dict(m, recording_id=m["session_id"]), e, t, base)[0] for m, e, t in study.recordings],
            ignore_index=True,
        )
        for name, s in variants.items():
            res[name].append(ari(analyze_tables(dec, s)["styles"], study.ground_truth["drivers"]))
    for name, v in res.items():
        print(f"  {name:<32} mean ARI {np.mean(v):.3f}, ARI = 1 in {sum(a == 1.0 for a in v)}/{len(v)}")
    return [
        {"variant": name, "mean_ari": float(np.mean(v)), "seeds_ari_1": sum(a == 1.0 for a in v), "seeds": len(v)}
        for name, v in res.items()
    ]


FEATURE_SPECS = ("auto", "ttc", "paper", "headway", "acceptance", "all", "following")


def study_aris(study: Path, workspace: Path, specs: tuple[str, ...] = FEATURE_SPECS) -> dict[str, object]:
    """ARI of each feature set on one simulated study, the set 'auto' chose and the flagged fits."""
    from clustering.pipeline import extract_all

    gt = json.loads((study / "ground_truth.json").read_text())
    ws = Workspace(workspace)
    dec, _, _, following = extract_all(ws, AnalysisSettings())
    drivers = list(ws.recordings()["driver_id"].astype(str))
    row: dict[str, object] = {"study": study.name}
    for spec in specs:
        out = analyze_tables(dec, AnalysisSettings(features=spec), drivers=drivers, following=following)
        row[spec] = ari(out["styles"], gt["drivers"])
        if spec == "auto":
            fs = out["feature_sets"]
            row["chosen"] = str(fs.loc[fs["chosen"], "name"].iloc[0])
            fits = out["fits"][(out["fits"]["status"] == "ok") & out["fits"]["indicator"].isin(INDICATORS)]
            row["flagged"] = f"{int((fits['flag'] != '').sum())}/{len(fits)}"
    presses = dec[dec["label"] == "change"]
    row["t_f undefined"] = float((presses["t_f_status"] != "ok").mean())
    row["t_nf undefined"] = float((presses["t_nf_status"] != "ok").mean())
    return row


def studies(pairs: list[tuple[str, str]], specs: tuple[str, ...] = FEATURE_SPECS) -> list[dict]:
    print(f"== {len(pairs)} simulated studies: ARI per feature set (--features)")
    rows = []
    for study, workspace in pairs:
        rows.append(study_aris(Path(study), Path(workspace), specs))
        r = rows[-1]
        print(
            f"  {r['study']:<8} "
            + "  ".join(f"{s} {r[s]:.3f}" for s in specs)
            + f"  chose {r['chosen']}  flagged {r['flagged']}  undefined at presses: t_f {100 * r['t_f undefined']:.0f} %"
            f", t_nf {100 * r['t_nf undefined']:.0f} %",
            flush=True,
        )
    for s in specs:
        v = [float(r[s]) for r in rows]
        print(
            f"  {s:<11} mean ARI {np.mean(v):.3f}, min {np.min(v):.3f}, ARI = 1 in {sum(a == 1.0 for a in v)}/{len(v)}"
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--messy", type=int, default=0, help="also run this many seeds of harder studies")
    ap.add_argument("--workspace", type=Path, default=None, help="workspace with sample_logs/ ingested")
    ap.add_argument(
        "--study",
        nargs=2,
        action="append",
        default=[],
        metavar=("DIR", "WORKSPACE"),
        help="a simulated study and the workspace it is ingested in (repeat for more)",
    )
    ap.add_argument(
        "--specs",
        default=",".join(FEATURE_SPECS),
        help="with --study: the --features values to measure, comma-separated (auto first)",
    )
    ap.add_argument("--zoo", default="", help="worlds of benchmarks/zoo.py, comma-separated ('all': every one)")
    ap.add_argument("--zoo-seeds", type=int, nargs="+", default=[9101, 9102, 9103])
    ap.add_argument("--zoo-root", type=Path, default=Path("/tmp/laneprint-zoo"), help="where studies are cached")
    ap.add_argument("--zoo-methods", default="auto,heldout,behaviour", help="--features values to judge")
    ap.add_argument("--zoo-out", default="analysis_zoo.json", help="file name under benchmarks/results/")
    ap.add_argument(
        "--zoo-shares",
        default="",
        help="style shares Defensive,Normal,Aggressive of the studies, ';'-separated sets judged in turn "
        "('world;2,4,3': each world's own and 2/4/3 of 9 drivers); default the world's own",
    )
    ap.add_argument(
        "--zoo-cached-only",
        action="store_true",
        help="judge only the studies already generated under --zoo-root (generate none)",
    )
    ap.add_argument("--zoo-jobs", type=int, default=1, help="studies judged at a time (one process each)")
    ap.add_argument("--out", default="analysis", help="result file name under benchmarks/results/ (sections 1-5)")
    args = ap.parse_args()
    if args.zoo:
        from zoo import WORLDS, run as run_zoo

        worlds = list(WORLDS) if args.zoo == "all" else args.zoo.split(",")
        run_zoo(
            worlds,
            args.zoo_seeds,
            args.zoo_root,
            tuple(args.zoo_methods.split(",")),
            args.zoo_out,
            args.zoo_cached_only,
            tuple("" if part in ("", "world") else part for part in args.zoo_shares.split(";")),
            args.zoo_jobs,
        )
        return
    figures: dict = {}
    if args.workspace:
        figures["shipped"] = shipped(args.workspace)
    if args.study:
        figures["studies"] = studies(args.study, tuple(args.specs.split(",")))
    if args.repeats:
        figures["timing"] = timing(args.repeats)
    if args.seeds:
        figures["simulator_seeds"] = seeds(args.seeds)
    if args.messy:
        figures["messy"] = messy(args.messy)
    if figures:
        write_result(args.out, figures)


if __name__ == "__main__":
    main()
