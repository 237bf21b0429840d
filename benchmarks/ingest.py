"""Ingest throughput vs the floor, side by side in one run.

Generates a 10-minute, 20-vehicle, 50 Hz recording in memory, writes it as CSV,
CSV.gz and MCAP to a temporary folder, then times (median of several repetitions):

- our ingest: `ingest.pipeline.ingest_paths` into a fresh workspace (read, map,
  validate, hash, store as Parquet), and its read+validate part alone;
- the floor for the same bytes: `pyarrow.csv.read_csv` (after gunzip for .csv.gz),
  and the `mcap` reader iterating every message and `json.loads`-ing it without
  building any table (and, beside it, the same with msgspec's decoder);
- with `--baseline REV` (repeatable), the ingest of git revision REV (its `ingest/`
  package and `laneprint/workspace.py`, the store, loaded under another name, everything
  else shared), interleaved with ours: before and after in one run.

Goals: our ingest at least half as fast as the floor (ratio >= 0.5); MCAP at least 3x. The table is
written to `benchmarks/results/<--out>.json` (default `ingest`).

    .venv/bin/python benchmarks/ingest.py [--reps 5] [--minutes 10] [--vehicles 20] [--baseline c330a54 ...]
                                          [--formats csv,csv.gz,mcap]
"""

from __future__ import annotations

import argparse
import gzip
import importlib
import io
import json
import shutil
import statistics
import subprocess
import tarfile
import tempfile
import time
from pathlib import Path

import sys

from results_file import write_result  # beside this file: imported before the folder leaves the path

# this script is named like the `ingest` package: keep its own folder off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import msgspec  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pyarrow.csv as pacsv  # noqa: E402
from mcap.reader import make_reader  # noqa: E402

from ingest.mapping import IDENTITY  # noqa: E402
from ingest.pipeline import ingest_paths, read_log, session_stem  # noqa: E402
from ingest.validate import canonicalise  # noqa: E402
from ingest.writers import write_csv, write_mcap  # noqa: E402
from laneprint.workspace import Workspace  # noqa: E402


def make_recording(minutes: float, n_vehicles: int, hz: int = 50, seed: int = 0):
    """A synthetic two-lane recording: ego plus `n_vehicles` cars present the whole time."""
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * hz)
    t = np.arange(n) / hz
    v = 22.0 + 2.0 * np.sin(t / 30.0) + rng.normal(0, 0.05, n)
    x = np.cumsum(v) / hz
    lane = ((t // 40) % 2).astype(np.int64)
    button = np.zeros(n, dtype=bool)
    for s in np.flatnonzero(np.diff(lane) != 0):
        button[max(s - 100, 0) : max(s - 90, 1)] = True
    ego = pd.DataFrame(
        {
            "t_s": t,
            "ego_x_m": x,
            "ego_y_m": lane * 3.5,
            "ego_v_mps": v,
            "ego_lane": lane,
            "ego_length_m": 4.5,
            "steer_rad": rng.normal(0, 0.01, n),
            "throttle": rng.uniform(0, 0.5, n),
            "brake": np.zeros(n),
            "lc_button": button,
            "lc_direction": None,
        }
    )
    vv = rng.uniform(15, 30, n_vehicles)
    x0 = rng.uniform(-300, 300, n_vehicles)
    vlane = rng.integers(0, 2, n_vehicles)
    ids = np.array([f"v{k}" for k in range(n_vehicles)], dtype=object)
    traffic = pd.DataFrame(
        {
            "t_s": np.repeat(t, n_vehicles),
            "vehicle_id": np.tile(ids, n),
            "x_m": (x0[None, :] + vv[None, :] * t[:, None]).ravel(),
            "y_m": np.tile(vlane * 3.5, n),
            "v_mps": np.tile(vv, n),
            "lane": np.tile(vlane, n),
            "length_m": np.tile(rng.uniform(4, 5, n_vehicles), n),
        }
    )
    meta = {"driver_id": "B01", "session_id": None, "speed_limit_kph": 80, "simulator": "benchmark"}
    return meta, ego, traffic


def interleaved(fns, reps: int) -> list[tuple[float, float]]:
    """(median wall, median CPU) seconds of each function, run in turn `reps` times after a warm-up
    (in the listed order, then the reverse order, alternately).

    CPU time (all threads of this process) is less disturbed by other load on the machine.
    """
    for fn in fns:
        fn()
    wall: list[list[float]] = [[] for _ in fns]
    cpu: list[list[float]] = [[] for _ in fns]
    for r in range(reps):
        # forwards, then backwards: no function always runs right after the same one
        for i in range(len(fns)) if r % 2 == 0 else reversed(range(len(fns))):
            fn = fns[i]
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            wall[i].append(time.perf_counter() - t0)
            cpu[i].append(time.process_time() - c0)
    return [(statistics.median(w), statistics.median(c)) for w, c in zip(wall, cpu)]


def floor_csv(data: bytes, gz: bool) -> None:
    pacsv.read_csv(io.BytesIO(gzip.decompress(data) if gz else data))


def floor_mcap(data: bytes) -> None:
    reader = make_reader(io.BytesIO(data))
    for _, _, msg in reader.iter_messages():
        json.loads(msg.data)


def floor_mcap_msgspec(data: bytes) -> None:
    decode = msgspec.json.Decoder().decode
    reader = make_reader(io.BytesIO(data))
    for _, _, msg in reader.iter_messages():
        decode(msg.data)


def load_baseline(rev: str, into: Path):
    """(`ingest_paths`, `Workspace`) of git revision `rev`: its `ingest/` package imported as
    `ingest_<rev>` and its `laneprint/workspace.py` (the store) as that package's `_workspace`."""
    repo = Path(__file__).resolve().parent.parent
    name = f"ingest_{rev.replace('-', '_').replace('.', '_')}"
    tar = subprocess.run(
        ["git", "-C", str(repo), "archive", rev, "ingest", "laneprint/workspace.py"], capture_output=True, check=True
    ).stdout
    with tarfile.open(fileobj=io.BytesIO(tar)) as tf:
        tf.extractall(into, filter="data")
    (into / "ingest").rename(into / name)
    (into / "laneprint" / "workspace.py").rename(into / name / "_workspace.py")
    for f in (into / name).rglob("*.py"):
        f.write_text(
            f.read_text()
            .replace("from ingest.", f"from {name}.")
            .replace("import ingest.", f"import {name}.")
            .replace("from laneprint.workspace import", f"from {name}._workspace import")
        )
    sys.path.insert(0, str(into))
    pipeline, store = importlib.import_module(f"{name}.pipeline"), importlib.import_module(f"{name}._workspace")
    return pipeline.ingest_paths, store.Workspace


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--vehicles", type=int, default=20)
    ap.add_argument(
        "--baseline",
        metavar="REV",
        action="append",
        default=[],
        help="also time the ingest (and store) of this git revision (before/after); repeatable",
    )
    ap.add_argument("--formats", default="csv,csv.gz,mcap", help="comma-separated subset of csv,csv.gz,mcap")
    ap.add_argument("--out", default="ingest", help="result file name under benchmarks/results/")
    args = ap.parse_args()

    meta, ego, traffic = make_recording(args.minutes, args.vehicles)
    n = len(ego)
    tmp = Path(tempfile.mkdtemp(prefix="lp-bench-"))
    bases = [(rev, *load_baseline(rev, tmp / f"base{i}")) for i, rev in enumerate(args.baseline)]
    try:
        files = {fmt: tmp / f"rec.{fmt}" for fmt in ("csv", "csv.gz", "mcap") if fmt in args.formats.split(",")}
        for fmt, path in files.items():
            t0 = time.perf_counter()
            (write_mcap if fmt == "mcap" else write_csv)(path, meta, ego, traffic)
            print(f"wrote {path.name}: {path.stat().st_size / 1e6:.1f} MB in {time.perf_counter() - t0:.2f} s")
        print(
            f"{n} samples ({args.minutes:g} min at 50 Hz), {args.vehicles} vehicles, "
            f"{len(traffic)} traffic rows; median of {args.reps} runs\n"
        )

        rows = []
        for fmt, path in files.items():
            data = path.read_bytes()
            mb = len(data) / 1e6
            k = [0]
            used: list[Path] = []

            def floor(d=data, f=fmt) -> None:
                floor_mcap(d) if f == "mcap" else floor_csv(d, f == "csv.gz")

            def read(d=data, f=fmt, p=path) -> None:
                canonicalise(read_log(d, f, IDENTITY), IDENTITY, session_stem(p), None)

            def full(p=path, run=ingest_paths, store=Workspace) -> None:
                k[0] += 1
                ws = store(tmp / f"ws{k[0]}")
                rep = run([p], ws)
                assert rep.files[0].status in ("ingested", "warning"), rep.files[0].reason
                used.append(ws.root)

            fns, labels = [floor, read, full], ["read + validate", "ingest (stored)"]
            if fmt == "mcap":
                fns.insert(1, lambda d=data: floor_mcap_msgspec(d))
                labels.insert(0, "mcap iter + msgspec (floor, msgspec)")
            for rev, base_ingest, base_ws in bases:
                fns.append(lambda p=path, r=base_ingest, w=base_ws: full(p, r, w))
                labels.append(f"ingest (stored), {rev}")
            # interleaved, so a busy machine slows all alike
            times = interleaved(fns, args.reps)
            for root in used:
                shutil.rmtree(root, ignore_errors=True)
            floor_name = "pyarrow.csv.read_csv" if fmt != "mcap" else "mcap iter + json.loads"
            for label, (secs, cpu) in zip([floor_name + " (floor)"] + labels, times):
                rows.append((fmt, label, secs, mb / secs, n / secs, times[0][0] / secs, cpu, times[0][1] / cpu))
        print(
            f"{'format':7} {'what':38} {'wall s':>8} {'MB/s':>8} {'samples/s':>11} {'vs floor':>9}"
            f" {'cpu s':>7} {'vs floor':>9}"
        )
        for fmt, label, secs, mbs, sps, ratio, cpu, cpu_ratio in rows:
            print(f"{fmt:7} {label:38} {secs:8.3f} {mbs:8.1f} {sps:11,.0f} {ratio:9.2f} {cpu:7.3f} {cpu_ratio:9.2f}")
        print(
            "\nvs floor = floor time / this time, from medians of wall-clock time and of CPU time "
            "(all threads; steadier when the machine is busy)"
        )
        print("goals: 'ingest (stored)' >= 0.5 x floor for each format; >= 3 x the json.loads floor for mcap")
        write_result(
            args.out,
            {
                "minutes": args.minutes,
                "vehicles": args.vehicles,
                "reps": args.reps,
                "samples": n,
                "traffic_rows": len(traffic),
                "baselines": args.baseline,
                "rows": [
                    {
                        "format": fmt,
                        "what": label,
                        "wall_s": secs,
                        "mb_per_s": mbs,
                        "samples_per_s": sps,
                        "vs_floor_wall": ratio,
                        "cpu_s": cpu,
                        "vs_floor_cpu": cpu_ratio,
                    }
                    for fmt, label, secs, mbs, sps, ratio, cpu, cpu_ratio in rows
                ],
            },
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
