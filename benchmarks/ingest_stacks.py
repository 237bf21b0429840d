"""Ingest of ROS 2 (CDR) and protobuf MCAP files vs the same recording as v1 JSON MCAP.

Writes the 10-minute, 20-vehicle, 50 Hz recording of `benchmarks/ingest.py` as the
worked examples of ingest/README.md (`ingest/stack_examples.py`) and as v1 JSON, then
times (medians, interleaved):

- the floor: mcap's reader with the decoder factories (`iter_decoded_messages`),
  decoding every message and building nothing;
- `laneprint ingest`'s work (`ingest.pipeline.ingest_paths` into a fresh workspace).

    python benchmarks/ingest_stacks.py [--reps 3] [--minutes 10] [--vehicles 20]
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

# this folder holds a script named like the `ingest` package: keep it off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

from mcap.reader import make_reader  # noqa: E402
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory  # noqa: E402
from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory  # noqa: E402

from ingest.mcap_decoding import JsonDecoderFactory  # noqa: E402
from ingest.pipeline import ingest_paths  # noqa: E402
from ingest.stack_examples import PROTOBUF_MAPPING, ROS2_MAPPING, write_protobuf, write_ros2  # noqa: E402
from ingest.writers import write_mcap  # noqa: E402
from laneprint.workspace import Workspace  # noqa: E402

_spec = importlib.util.spec_from_file_location("bench_ingest", Path(__file__).with_name("ingest.py"))
bench_ingest = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_ingest)


def floor(data: bytes) -> None:
    """Decode every message with the libraries' decoder factories, as mcap's reader does."""
    factories = [Ros2DecoderFactory(), ProtobufDecoderFactory(), JsonDecoderFactory()]
    for _ in make_reader(io.BytesIO(data), decoder_factories=factories).iter_decoded_messages(log_time_order=False):
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--vehicles", type=int, default=20)
    args = ap.parse_args()
    meta, ego, traffic = bench_ingest.make_recording(args.minutes, args.vehicles)
    meta = {**meta, "session_id": "bench"}
    tmp = Path(tempfile.mkdtemp(prefix="lp-bench-stacks-"))
    try:
        (tmp / "ros2.toml").write_text(ROS2_MAPPING)
        (tmp / "protobuf.toml").write_text(PROTOBUF_MAPPING)
        files = {"json (v1)": (tmp / "v1.mcap", write_mcap, None),
                 "ros2 cdr": (tmp / "ros2.mcap", write_ros2, tmp / "ros2.toml"),
                 "protobuf": (tmp / "protobuf.mcap", write_protobuf, tmp / "protobuf.toml")}
        for path, write, _ in files.values():
            t0 = time.perf_counter()
            write(path, meta, ego, traffic)
            print(f"wrote {path.name}: {path.stat().st_size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s")
        print(f"{len(ego)} samples, {len(traffic)} traffic rows; median of {args.reps} runs\n")
        print(f"{'file':10} {'floor wall / cpu s':>19} {'ingest wall / cpu s':>20} {'samples/s':>10} "
              f"{'floor/ingest (cpu)':>19}")
        k = [0]
        for name, (path, _, mapping) in files.items():
            data = path.read_bytes()

            def full(p=path, m=mapping) -> None:
                k[0] += 1
                ws = Workspace(tmp / f"ws{k[0]}")
                rep = ingest_paths([p], ws, mapping=m)
                assert rep.files[0].status in ("ingested", "warning"), rep.files[0].reason
                shutil.rmtree(ws.root)

            (fw, fc), (iw, ic) = bench_ingest.interleaved([lambda d=data: floor(d), full], args.reps)
            print(f"{name:10} {fw:10.2f} / {fc:6.2f} {iw:11.2f} / {ic:6.2f} {len(ego) / ic:10,.0f} {fc / ic:19.2f}")
        print("\nsamples/s and the ratio on CPU time (steadier than wall time on a shared machine)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
