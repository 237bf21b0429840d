"""Fuzz the ingest: many mutated copies of the sample logs, each ingested into a fresh workspace.

    python benchmarks/fuzz.py [--cases 10000] [--seed 0] [--case N]

Seed files are short excerpts of the shipped sample logs written as .csv, .csv.gz and
.mcap (`tests.support.ingest_mutations.excerpts`). Each case picks a seed file and a mutation kind
and mutates it with `random.Random(f"{seed}:{case}")` (so `--case N` replays one
file), then runs it in-process through the ingest pipeline (`_Batch.prepare`, `parse_log`,
`_Batch.store`: what `laneprint ingest` runs per file) and judges the end (`tests.support.ingest_mutations.try_ingest`):

- ingested: stored, and the stored tables pass the canonical schemas and value bounds;
- refused: rejected with a reason naming a signal or a byte offset / line / message;
- refused_unlocated: rejected with a reason that names neither (to improve);
- unexpected: refused through the pipeline's catch-all for exceptions (a bug);
- traceback: an exception escaped the pipeline;
- partial / bad_output: the workspace holds a half-written or invalid recording.

Prints one row per mutation kind with how each case ended, then the totals and the
first example of every outcome other than ingested/refused, and writes the counts to
`benchmarks/results/<--out>.json` (default `fuzz`; not with `--case`). Exit status 1 when any
case ended in traceback, partial, bad_output, unexpected or refused_unlocated.
"""

from __future__ import annotations

import argparse
import collections
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

from results_file import write_result  # beside this file: imported before the folder leaves the path

# this script lives beside benchmarks/ingest.py, named like the `ingest` package: keep its folder off the path
sys.path = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout: the test tools (tests.support)

from tests.support.ingest_mutations import OUTCOMES, excerpts, kinds_for, mutate, try_ingest  # noqa: E402
from laneprint.cliutil import progress_bar  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
BAD = ("traceback", "partial", "bad_output", "unexpected", "refused_unlocated")


def log_fmt(name: str) -> str:
    return "mcap" if name.endswith(".mcap") else "csv.gz" if name.endswith(".gz") else "csv"


def run_case(
    seeds: dict[str, bytes], seed: int, case: int, tmp: Path, only: set[str] | None = None
) -> tuple[str, str, str, str] | None:
    """(seed file, kind, outcome, detail) of one case; None when its kind is not in `only`."""
    rng = random.Random(f"{seed}:{case}")
    name = rng.choice(sorted(seeds))
    kind = rng.choice(kinds_for(log_fmt(name)))
    if only and kind not in only:
        return None
    data = mutate(seeds[name], log_fmt(name), kind, rng)
    folder = tmp / str(case)
    folder.mkdir()
    try:
        (folder / name).write_bytes(data)
        out = try_ingest(folder / name, folder / "ws")
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return name, kind, out.outcome, out.detail


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=10_000, help="mutated files to try")
    ap.add_argument("--seed", type=int, default=0, help="seed of every random choice")
    ap.add_argument("--case", type=int, default=None, help="replay one case and print its detail")
    ap.add_argument("--kinds", default="", help="only these mutation kinds (comma separated), same cases otherwise")
    ap.add_argument("--seconds", default="2,8", help="lengths of the seed excerpts [s], comma separated")
    ap.add_argument("--out", default="fuzz", help="result file name under benchmarks/results/")
    args = ap.parse_args()

    t0 = time.perf_counter()
    seeds = excerpts(ROOT / "sample_logs", tuple(float(s) for s in args.seconds.split(",")))
    tmp = Path(tempfile.mkdtemp(prefix="lp-fuzz-"))
    try:
        if args.case is not None:
            name, kind, outcome, detail = run_case(seeds, args.seed, args.case, tmp) or ("", "", "", "")
            print(f"case {args.case}: {kind} of {name} -> {outcome}\n{detail}")
            return 0
        table: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
        examples: dict[str, tuple[int, str, str, str]] = {}
        t1 = time.perf_counter()
        with progress_bar(True) as progress:
            for case in range(args.cases):
                ran = run_case(seeds, args.seed, case, tmp, set(filter(None, args.kinds.split(","))))
                if ran is None:
                    continue
                name, kind, outcome, detail = ran
                table[kind][outcome] += 1
                if outcome in BAD:
                    examples.setdefault(f"{outcome}/{kind}", (case, name, kind, detail))
                if case % 20 == 0 or case == args.cases - 1:
                    progress(case + 1, args.cases, f"fuzz {kind}")
        elapsed = time.perf_counter() - t1
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    tried = sum(sum(c.values()) for c in table.values())
    print(
        f"\n{tried} mutated files (of cases 0-{args.cases - 1}) from {len(seeds)} seed files (seed {args.seed}) "
        f"in {elapsed:.0f} s ({elapsed / max(tried, 1) * 1000:.0f} ms per file; seed files {t1 - t0:.0f} s)\n"
    )
    print(f"{'kind':20}{'tried':>7}" + "".join(f"{o:>18}" for o in OUTCOMES))
    total: collections.Counter = collections.Counter()
    for kind in sorted(table):
        total.update(table[kind])
        print(f"{kind:20}{sum(table[kind].values()):7d}" + "".join(f"{table[kind][o]:18d}" for o in OUTCOMES))
    print(f"{'all':20}{sum(total.values()):7d}" + "".join(f"{total[o]:18d}" for o in OUTCOMES))
    for key, (case, name, kind, detail) in sorted(examples.items()):
        print(
            f"\n{key}: case {case} ({kind} of {name}; replay with --seed {args.seed} --case {case})\n{detail[-1500:]}"
        )
    write_result(
        args.out,
        {
            "cases": args.cases,
            "seed": args.seed,
            "kinds": args.kinds,
            "seconds": args.seconds,
            "seed_files": len(seeds),
            "tried": tried,
            "elapsed_s": elapsed,
            "ms_per_file": elapsed / max(tried, 1) * 1000,
            "totals": {o: total[o] for o in OUTCOMES},
            "bad": sum(total[o] for o in BAD),
            "per_kind": [
                {"kind": k, "tried": sum(table[k].values()), **{o: table[k][o] for o in OUTCOMES}}
                for k in sorted(table)
            ],
            "examples": [
                {"what": key, "case": case, "file": name, "detail": detail[-1500:]}
                for key, (case, name, kind, detail) in sorted(examples.items())
            ],
        },
    )
    return 1 if any(total[o] for o in BAD) else 0


if __name__ == "__main__":
    sys.exit(main())
