"""Every command's `--json` on the shipped study, normalised, for comparing two trees.

    python benchmarks/cli_json.py --out before.json      # on the old tree
    python benchmarks/cli_json.py --out after.json       # on the new tree
    python benchmarks/cli_json.py --compare before.json after.json

Runs simulate, ingest, analyze, train (one run and a fleet), evaluate, crossval,
export, annotate, drive (when SUMO is installed), runs and check with fixed seeds in
a fresh workspace, and keeps each command's JSON document with what varies between
two identical runs removed: wall times, dates, absolute paths of the temporary
workspace, the date-time in the ids, and the versions/fingerprints of the code. A refactoring that changes
no behaviour gives two equal files (`--compare` exits 0).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LANEPRINT = [sys.executable, "-m", "laneprint.app.cli"]
VOLATILE = re.compile(
    r"(seconds|_s_wall|wall|elapsed|duration|started|finished|_at$|^at$|time_s$|code_version|"
    r"git|pid|host|created|updated|modified|version)",
    re.I,
)
STAMP = re.compile(r"\d{8}-\d{6}(-\d{6})?-")  # the date-time that begins run, fleet and cross-validation ids


def normalise(value, tmp: str):
    """Drop volatile keys and the temporary folder's path from a JSON value."""
    if isinstance(value, dict):
        return {k: normalise(v, tmp) for k, v in value.items() if not VOLATILE.search(k)}
    if isinstance(value, list):
        return [normalise(v, tmp) for v in value]
    if isinstance(value, str):
        return STAMP.sub("<stamp>-", value.replace(tmp, "<tmp>"))
    if isinstance(value, float):
        return round(value, 9) if value == value else "NaN"  # NaN != NaN would make equal documents differ
    return value


def run(args: list[str], tmp: str) -> object:
    """One command's JSON document (or its exit status and stderr when it failed)."""
    proc = subprocess.run([*LANEPRINT, *args, "--json"], cwd=ROOT, capture_output=True, text=True)
    print(f"  {' '.join(args)[:90]} -> exit {proc.returncode}", file=sys.stderr)
    if proc.returncode != 0:
        return {"exit": proc.returncode, "stderr": proc.stderr.strip().splitlines()[-1:]}
    return normalise(json.loads(proc.stdout), tmp)


def snapshot() -> dict[str, object]:
    """Run every command once in a fresh workspace."""
    with tempfile.TemporaryDirectory(prefix="lp-json-") as tmp:
        ws = ["--workspace", f"{tmp}/ws"]
        out: dict[str, object] = {}
        out["simulate"] = run(["simulate", "--out", f"{tmp}/sim", "--drivers", "3", "--seed", "1"], tmp)
        out["ingest"] = run(["ingest", "sample_logs", *ws], tmp)
        out["analyze"] = run(["analyze", *ws], tmp)
        out["train"] = run(
            ["train", "--style", "Normal", "--episodes", "300", "--seed", "0", "--run-id", "r1", *ws], tmp
        )
        out["evaluate"] = run(["evaluate", "r1", *ws], tmp)
        out["crossval"] = run(
            [
                "crossval",
                "--style",
                "Aggressive",
                "--folds",
                "2",
                "--episodes",
                "150",
                "--seed",
                "0",
                "--bootstrap",
                "50",
                *ws,
            ],
            tmp,
        )
        out["export"] = run(["export", "r1", "--out", f"{tmp}/export", *ws], tmp)
        rec = json.loads(
            subprocess.run([*LANEPRINT, "runs", "--json", *ws], cwd=ROOT, capture_output=True, text=True).stdout
            or "null"
        )
        recordings = sorted(p.name for p in Path(f"{tmp}/ws/recordings").iterdir())
        out["annotate"] = run(["annotate", "r1", recordings[0], "--out", f"{tmp}/a.mcap", *ws], tmp)
        out["fleet"] = run(["train", "--styles", "all", "--seeds", "1", "--episodes", "150", "--seed", "0", *ws], tmp)
        try:
            import libsumo  # noqa: F401

            out["drive"] = run(
                [
                    "drive",
                    "r1",
                    "--engine",
                    "sumo",
                    "--minutes",
                    "0.3",
                    "--seed",
                    "0",
                    "--section",
                    "80",
                    "--out",
                    f"{tmp}/drive",
                    *ws,
                ],
                tmp,
            )
        except ImportError:
            print("  drive skipped (no SUMO)", file=sys.stderr)
        out["runs"] = normalise(rec, tmp)
        out["check"] = run(["check", *ws], tmp)
        return out


def compare(a: Path, b: Path, record: str = "", commits: tuple[str, str] = ("", "")) -> int:
    """Print the commands whose documents differ; 0 when none. `record`: also write the verdicts to
    benchmarks/results/`record`.json with the commits the two snapshots were taken at."""
    left, right = (normalise(json.loads(p.read_text()), "<tmp>") for p in (a, b))
    differ = [k for k in sorted(set(left) | set(right)) if left.get(k) != right.get(k)]
    for k in sorted(set(left) | set(right)):
        print(f"{k:10s} {'DIFFERS' if k in differ else 'same'}")
    if record:
        from results_file import write_result  # beside this file

        verdicts = {k: ("differs" if k in differ else "same") for k in sorted(set(left) | set(right))}
        write_result(record, {"before_commit": commits[0], "after_commit": commits[1], "commands": verdicts})
    return 1 if differ else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="write the snapshot here")
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    parser.add_argument("--record", default="", help="--compare: write the verdicts to benchmarks/results/NAME.json")
    parser.add_argument(
        "--commits", nargs=2, default=("", ""), metavar=("BEFORE", "AFTER"), help="--record: the trees' commits"
    )
    args = parser.parse_args()
    if args.compare:
        return compare(*args.compare, record=args.record, commits=tuple(args.commits))
    snap = snapshot()
    text = json.dumps(snap, indent=1, sort_keys=True)
    if args.out:
        args.out.write_text(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
