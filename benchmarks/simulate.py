"""How long `laneprint simulate` takes: generating the default study in memory, and writing it.

Run: `python benchmarks/simulate.py [--repeats N]`. Prints medians over the repeats
for generation (10 drivers, 40 recordings, 500 decisions) and for writing the study
as CSV (gzip) and as MCAP, side by side in one run, plus sizes and samples/s; writes them to
`benchmarks/results/<--out>.json` (default `simulate`) with the command, commit, date and machine.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

from results_file import write_result  # beside this file (imported before the folder leaves the path)

# benchmarks/ingest.py would shadow the `ingest` package: keep this folder off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

from laneprint.app.simulator.output import write_study  # noqa: E402
from laneprint.simulator import StudySettings, simulate_study  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="simulate", help="result file name under benchmarks/results/")
    args = parser.parse_args()

    gen, study = [], None
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        study = simulate_study(StudySettings(), seed=0)
        gen.append(time.perf_counter() - t0)
    assert study is not None
    samples = sum(len(ego) for _, ego, _ in study.recordings)
    rows = sum(len(tr) for _, _, tr in study.recordings)
    figures = {
        "repeats": args.repeats,
        "recordings": len(study.recordings),
        "ego_samples": samples,
        "traffic_rows": rows,
        "generate_median_s": statistics.median(gen),
        "generate_samples_per_s": samples / statistics.median(gen),
        "write": [],
    }
    print(
        f"generate: median {statistics.median(gen):.2f} s over {args.repeats} runs; "
        f"{len(study.recordings)} recordings, {samples} ego samples, {rows} traffic rows, "
        f"{samples / statistics.median(gen):,.0f} samples/s"
    )

    for fmt in ("csv", "mcap", "mixed"):
        times, size = [], 0
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                summary = write_study(study, Path(tmp) / "s", fmt)
                times.append(time.perf_counter() - t0)
                size = summary["log_bytes"]
        med = statistics.median(times)
        figures["write"].append({"format": fmt, "median_s": med, "log_mb": size / 1e6, "samples_per_s": samples / med})
        print(f"write {fmt:5s}: median {med:.2f} s, {size / 1e6:.1f} MB of logs, {samples / med:,.0f} samples/s")
    write_result(args.out, figures)


if __name__ == "__main__":
    main()
