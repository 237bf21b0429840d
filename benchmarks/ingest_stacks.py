"""Ingest of ROS 2 (CDR) and protobuf MCAP files vs the same recording as v1 JSON MCAP.

Writes the 10-minute, 20-vehicle, 50 Hz recording of `benchmarks/ingest.py` as the
worked examples of ingest/README.md (`tests/support/stack_examples.py`) and as v1 JSON, then
times (medians, interleaved):

- the floor: mcap's reader with the decoder factories (`iter_decoded_messages`),
  decoding every message and building nothing; for ROS 2 also the same with
  laneprint's decoder (rosbags, mcap_ros2 behind it: `FastRos2DecoderFactory`);
- `laneprint ingest`'s work (`ingest.pipeline.ingest_paths` into a fresh workspace),
  and with `--baseline REV` the ingest of git revision REV in the same run.

Writes the table to `benchmarks/results/<--out>.json` (default `ingest_stacks`).

    python benchmarks/ingest_stacks.py [--reps 3] [--minutes 10] [--vehicles 20] [--baseline REV]
                                         [--files json,ros2,protobuf]
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import shutil
import sys
import tempfile
import time
from pathlib import Path

from results_file import write_result  # beside this file: imported before the folder leaves the path

# this folder holds a script named like the `ingest` package: keep it off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout: the test tools (tests.support)

from mcap.reader import make_reader  # noqa: E402
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory  # noqa: E402
from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory  # noqa: E402

from ingest.mcap_decoding import FastRos2DecoderFactory, JsonDecoderFactory  # noqa: E402
from ingest.pipeline import ingest_paths  # noqa: E402
from tests.support.stack_examples import PROTOBUF_MAPPING, ROS2_MAPPING, write_protobuf, write_ros2  # noqa: E402
from ingest.writers import write_mcap  # noqa: E402
from laneprint.workspace import Workspace  # noqa: E402

_spec = importlib.util.spec_from_file_location("bench_ingest", Path(__file__).with_name("ingest.py"))
bench_ingest = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_ingest)


def floor(data: bytes, ros2=Ros2DecoderFactory) -> None:
    """Decode every message with the libraries' decoder factories, as mcap's reader does."""
    factories = [ros2(), ProtobufDecoderFactory(), JsonDecoderFactory()]
    for _ in make_reader(io.BytesIO(data), decoder_factories=factories).iter_decoded_messages(log_time_order=False):
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--vehicles", type=int, default=20)
    ap.add_argument(
        "--baseline", metavar="REV", help="also time the ingest (and store) of this git revision (before/after)"
    )
    ap.add_argument("--files", default="json,ros2,protobuf", help="comma-separated subset of json,ros2,protobuf")
    ap.add_argument("--out", default="ingest_stacks", help="result file name under benchmarks/results/")
    args = ap.parse_args()
    meta, ego, traffic = bench_ingest.make_recording(args.minutes, args.vehicles)
    meta = {**meta, "session_id": "bench"}
    tmp = Path(tempfile.mkdtemp(prefix="lp-bench-stacks-"))
    base = bench_ingest.load_baseline(args.baseline, tmp / "base") if args.baseline else None
    try:
        (tmp / "ros2.toml").write_text(ROS2_MAPPING)
        (tmp / "protobuf.toml").write_text(PROTOBUF_MAPPING)
        files = {
            "json (v1)": (tmp / "v1.mcap", write_mcap, None),
            "ros2 cdr": (tmp / "ros2.mcap", write_ros2, tmp / "ros2.toml"),
            "protobuf": (tmp / "protobuf.mcap", write_protobuf, tmp / "protobuf.toml"),
        }
        files = {name: f for name, f in files.items() if name.split()[0] in args.files.split(",")}
        for path, write, _ in files.values():
            t0 = time.perf_counter()
            write(path, meta, ego, traffic)
            print(f"wrote {path.name}: {path.stat().st_size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s")
        print(f"{len(ego)} samples, {len(traffic)} traffic rows; median of {args.reps} runs\n")
        print(f"{'file':10} {'what':34} {'wall s':>8} {'cpu s':>7} {'samples/s (cpu)':>16} {'floor/this (cpu)':>17}")
        k = [0]
        rows = []
        for name, (path, _, mapping) in files.items():
            data = path.read_bytes()

            def full(p=path, m=mapping, run=ingest_paths, store=Workspace) -> None:
                k[0] += 1
                ws = store(tmp / f"ws{k[0]}")
                rep = run([p], ws, mapping=m)
                assert rep.files[0].status in ("ingested", "warning"), rep.files[0].reason
                shutil.rmtree(ws.root)

            fns = {"floor (mcap decoder factories)": lambda d=data: floor(d)}
            if name == "ros2 cdr":
                fns["floor, laneprint's CDR decoder"] = lambda d=data: floor(d, FastRos2DecoderFactory)
            fns["ingest (stored)"] = full
            if base is not None:
                fns[f"ingest (stored), {args.baseline}"] = lambda p=path, m=mapping: full(p, m, *base)
            times = bench_ingest.interleaved(list(fns.values()), args.reps)
            for label, (wall, cpu) in zip(fns, times):
                print(f"{name:10} {label:34} {wall:8.2f} {cpu:7.2f} {len(ego) / cpu:16,.0f} {times[0][1] / cpu:17.2f}")
                rows.append(
                    {
                        "file": name,
                        "what": label,
                        "wall_s": wall,
                        "cpu_s": cpu,
                        "samples_per_cpu_s": len(ego) / cpu,
                        "floor_over_this_cpu": times[0][1] / cpu,
                    }
                )
        print("\nsamples/s and the ratio on CPU time (steadier than wall time on a shared machine)")
        write_result(
            args.out,
            {
                "minutes": args.minutes,
                "vehicles": args.vehicles,
                "reps": args.reps,
                "samples": len(ego),
                "traffic_rows": len(traffic),
                "baseline": args.baseline,
                "rows": rows,
            },
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
