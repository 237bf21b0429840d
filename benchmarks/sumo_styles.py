"""Figures of a SUMO study after `laneprint ingest` and `laneprint analyze`: are its styles found?

    python benchmarks/sumo_styles.py STUDY:WORKSPACE [STUDY:WORKSPACE ...] [--json]

For each pair: the ARI of the analysis's styles (`analysis/styles.parquet`) against
`ground_truth.json`, the share of presses whose `t_f` / `t_nf` is undefined
(status not 'ok'), and per driver and style the median front gap (`f_gap_m`),
lead gap (`nf_gap_m`) and lag gap (`nb_gap_m`) at the presses (label 'change' of
`analysis/decisions.parquet`). It reads those files only; it does not import the
analysis (the generator knows nothing of it). Used to choose the `acceptance`
family's styles (docs/history/sumo.md). The figures are written to `benchmarks/results/<--out>.json` (default
`sumo_styles`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from results_file import write_result  # beside this file

GAPS: tuple[str, ...] = ("f_gap_m", "nf_gap_m", "nb_gap_m")


def adjusted_rand(truth: list[str], found: list[str]) -> float:
    """Adjusted Rand index of two labellings (sklearn's `adjusted_rand_score`)."""
    from sklearn.metrics import adjusted_rand_score

    return float(adjusted_rand_score(truth, found))


def _median(x: pd.Series) -> float | None:
    x = x.dropna()
    return round(float(x.median()), 1) if len(x) else None


def measure(study: Path, workspace: Path) -> dict[str, Any]:
    """The figures of one study and its analysed workspace."""
    gt = json.loads((study / "ground_truth.json").read_text())
    truth = {d["driver_id"]: d["style"] for d in gt["drivers"]}
    found = pd.read_parquet(workspace / "analysis" / "styles.parquet").set_index("driver_id")["style"]
    ids = sorted(truth)
    presses = pd.read_parquet(workspace / "analysis" / "decisions.parquet").query("label == 'change'").copy()
    presses["true_style"] = presses["driver_id"].map(truth)
    per_driver = (
        presses.groupby("driver_id")
        .agg(style=("true_style", "first"), presses=("label", "size"), **{g: (g, _median) for g in GAPS})
        .reset_index()
    )
    per_style = {
        s: {g: _median(grp[g]) for g in GAPS} | {"presses": int(len(grp))} for s, grp in presses.groupby("true_style")
    }
    return {
        "study": str(study),
        "seed": gt["seed"],
        "family": gt.get("family", "ttc"),
        "ari": round(adjusted_rand([truth[d] for d in ids], [str(found.get(d, "?")) for d in ids]), 3),
        "found": {d: str(found.get(d, "?")) for d in ids},
        "presses": int(len(presses)),
        "t_f_undefined": round(float((presses["t_f_status"] != "ok").mean()), 3),
        "t_nf_undefined": round(float((presses["t_nf_status"] != "ok").mean()), 3),
        "per_style": per_style,
        "per_driver": per_driver.replace({np.nan: None}).to_dict("records"),
    }


def overlap_free(per_driver: list[dict[str, Any]], column: str) -> bool:
    """Whether the styles' per-driver medians of `column` lie in disjoint ranges."""
    ranges = {}
    for row in per_driver:
        if row[column] is not None:
            lo, hi = ranges.get(row["style"], (np.inf, -np.inf))
            ranges[row["style"]] = (min(lo, row[column]), max(hi, row[column]))
    spans = sorted(ranges.values())
    return all(a[1] < b[0] for a, b in zip(spans, spans[1:]))


def render(m: dict[str, Any]) -> str:
    """A few lines for one study."""
    lines = [
        f"seed {m['seed']} ({m['family']}): ARI {m['ari']:.3f}, {m['presses']} presses, t_f undefined "
        f"{m['t_f_undefined']:.0%}, t_nf undefined {m['t_nf_undefined']:.0%}; separated by "
        + ", ".join(f"{g} {'yes' if overlap_free(m['per_driver'], g) else 'no'}" for g in GAPS)
    ]
    for s, v in m["per_style"].items():
        lines.append(f"  {s:<10} presses {v['presses']:>4}  median " + "  ".join(f"{g} {v[g]}" for g in GAPS))
    for r in m["per_driver"]:
        lines.append(
            f"    {r['driver_id']} {r['style']:<10} -> {m['found'][r['driver_id']]:<10} {r['presses']:>3} "
            + "  ".join(f"{g} {r[g]}" for g in GAPS)
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Command line: STUDY:WORKSPACE pairs, a table or --json."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pairs", nargs="+", help="STUDY:WORKSPACE (the study folder and its analysed workspace)")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--out", default="sumo_styles", help="result file name under benchmarks/results/")
    args = ap.parse_args(argv)
    results = []
    for pair in args.pairs:
        study, sep, ws = pair.partition(":")
        if not sep or not (Path(study) / "ground_truth.json").is_file() or not (Path(ws) / "analysis").is_dir():
            print(f"error: {pair!r} is not STUDY:WORKSPACE of a study and its analysed workspace", file=sys.stderr)
            return 2
        results.append(measure(Path(study), Path(ws)))
    write_result(args.out, {"mean_ari": float(np.mean([m["ari"] for m in results])), "studies": results}, argv)
    if args.json:
        print(json.dumps(results, indent=1))
    else:
        print("\n".join(render(m) for m in results))
        print(f"mean ARI {np.mean([m['ari'] for m in results]):.3f} over {len(results)} studies")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
