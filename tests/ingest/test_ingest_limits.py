"""Resource limits: bombs, forged sizes, huge lines and headers are refused before memory runs out."""

from __future__ import annotations

import gzip
import json
import struct
import subprocess
import sys
import time

import pytest

from ingest.limits import IngestLimits
from ingest.pipeline import ingest_paths
from ingest.writers import write_csv, write_mcap
from laneprint.errors import UserError
from laneprint.workspace import Workspace

HEADER = b"t,driver_id,ego_x,ego_v,ego_lane\n"


def _ingest_one(path, ws_root, limits=None):
    (res,) = ingest_paths([path], Workspace(ws_root), limits=limits).files
    return res


# Runs the command in a grandchild and prints its peak RSS: a child forked straight from this
# (large) test process counts the parent's pages copied before exec in its own peak.
_MEASURE = (
    "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(r.returncode)"
)


def _peak_rss_mb(args: list[str]) -> tuple[int, str, float]:
    """Run `laneprint ARGS` in a child; (exit status, stdout, the child's peak RSS in MB)."""
    cli = [sys.executable, "-c", "from laneprint.app.cli import main; main()", *args]
    proc = subprocess.run([sys.executable, "-c", _MEASURE, *cli], capture_output=True, text=True)
    peak_kb = int(proc.stderr.strip().splitlines()[-1])  # ru_maxrss is in KB on Linux
    return proc.returncode, proc.stdout, peak_kb / 1024


def gzip_bomb(inflated_gb: float = 2.0) -> bytes:
    """A valid CSV .gz of a few MB that inflates to `inflated_gb` GB: one member repeated."""
    rows = b"0,D1,0,20,0\n" * ((8 << 20) // 12)
    member = gzip.compress(rows, compresslevel=9)
    return gzip.compress(HEADER) + member * int(inflated_gb * 1024 / 8)


def forged_chunk_mcap(tmp_path, recording, how: str) -> bytes:
    """An MCAP written by laneprint whose first chunk claims 1 TB (`size`) or whose record length does (`length`)."""
    write_mcap(tmp_path / "ok.mcap", *recording)
    data = bytearray((tmp_path / "ok.mcap").read_bytes())
    pos = 8
    while data[pos] != 0x06:  # walk to the first chunk record
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    if how == "size":
        struct.pack_into("<Q", data, pos + 9 + 16, 1 << 40)
    else:
        struct.pack_into("<Q", data, pos + 1, 1 << 40)
    return bytes(data)


@pytest.mark.slow
def test_gzip_bomb_is_refused_within_a_second_in_little_memory(tmp_path):
    bomb = tmp_path / "bomb.csv.gz"
    bomb.write_bytes(gzip_bomb(2.0))
    assert bomb.stat().st_size < 4 << 20
    t = time.perf_counter()
    res = _ingest_one(bomb, tmp_path / "ws")
    assert time.perf_counter() - t < 1.0
    assert res.status == "rejected"
    assert res.reason.startswith("gzip bomb: 16 MB inflated from the first ")
    status, out, rss = _peak_rss_mb(["ingest", str(bomb), "-w", str(tmp_path / "ws2"), "--json"])
    assert status == 0 and json.loads(out)["counts"]["rejected"] == 1
    assert rss < 500, f"peak RSS {rss:.0f} MB"

    small = tmp_path / "small.csv.gz"  # 1 KB inflating to 1 MB: a header line longer than a line may be
    small.write_bytes(gzip.compress(b"t," + b"0" * (1 << 20), 9))
    assert small.stat().st_size < 1100
    assert _ingest_one(small, tmp_path / "ws").reason.startswith(
        "malformed CSV: the header (line 1) is longer than the 1024 KB line limit"
    )


@pytest.mark.slow
def test_mcap_with_a_forged_chunk_size_is_refused_within_a_second_in_little_memory(tmp_path, recording):
    path = tmp_path / "forged.mcap"
    path.write_bytes(forged_chunk_mcap(tmp_path, recording, "size"))
    t = time.perf_counter()
    res = _ingest_one(path, tmp_path / "ws")
    assert time.perf_counter() - t < 1.0
    assert res.reason.startswith("MCAP chunk at byte ") and "claims 1048576 MB uncompressed" in res.reason
    status, out, rss = _peak_rss_mb(["ingest", str(path), "-w", str(tmp_path / "ws2"), "--json"])
    assert status == 0 and json.loads(out)["counts"]["rejected"] == 1
    assert rss < 500, f"peak RSS {rss:.0f} MB"

    path.write_bytes(forged_chunk_mcap(tmp_path, recording, "length"))
    res = _ingest_one(path, tmp_path / "ws")
    assert res.reason.startswith("corrupt MCAP: the record at byte ") and "past the end of the file" in res.reason


def test_zstd_frame_claiming_more_than_its_chunk_is_refused(tmp_path, recording):
    write_mcap(tmp_path / "ok.mcap", *recording)
    data = bytearray((tmp_path / "ok.mcap").read_bytes())
    frame = data.find(b"\x28\xb5\x2f\xfd")
    fhd = data[frame + 4]
    assert fhd >> 6 != 0, "the writer's frames carry their content size"
    at = frame + 5 + (0 if (fhd >> 5) & 1 else 1) + (0, 1, 2, 4)[fhd & 3]
    width = (1, 2, 4, 8)[fhd >> 6]
    data[at : at + width] = (256**width - 1).to_bytes(width, "little")
    (tmp_path / "frame.mcap").write_bytes(bytes(data))
    res = _ingest_one(tmp_path / "frame.mcap", tmp_path / "ws")
    assert res.reason.startswith("corrupt MCAP: the chunk at byte ") and "zstd frame claims" in res.reason


def test_wide_header_long_line_and_large_file_limits(tmp_path, recording):
    wide = tmp_path / "wide.csv"
    wide.write_bytes(b",".join(b"c%d" % i for i in range(30_000)) + b"\n")
    assert _ingest_one(wide, tmp_path / "ws").reason == (
        "malformed CSV: the header has 30000 columns, more than the 20000 limit (raise LANEPRINT_MAX_COLUMNS "
        "if they are genuine)"
    )
    long = tmp_path / "long.csv"
    long.write_bytes(HEADER + b"0,D1,0,20,0\n" + b"0.02,D1,0," + b"9" * (2 << 20) + b",0\n")
    assert _ingest_one(long, tmp_path / "ws").reason.startswith(
        "malformed CSV: line 3 (from byte 45) is longer than the 1024 KB line limit"
    )
    good = tmp_path / "good.csv"
    write_csv(good, *recording)
    limits = IngestLimits(max_file_mb=0.01)
    assert _ingest_one(good, tmp_path / "ws", limits).reason.startswith("file too large: ")


def test_limits_from_the_environment():
    assert IngestLimits.from_env({"LANEPRINT_MAX_COLUMNS": "50", "LANEPRINT_MAX_FILE_MB": "1.5"}) == IngestLimits(
        max_columns=50, max_file_mb=1.5
    )
    with pytest.raises(UserError, match="LANEPRINT_MAX_LINE_KB='lots' is not a positive number"):
        IngestLimits.from_env({"LANEPRINT_MAX_LINE_KB": "lots"})


def test_gzip_of_several_members_is_read_whole_and_garbage_after_it_refused(tmp_path, recording):
    write_csv(tmp_path / "r.csv", *recording)
    text = (tmp_path / "r.csv").read_bytes()
    cut = text.index(b"\n", len(text) // 2) + 1
    two = tmp_path / "two.csv.gz"
    two.write_bytes(gzip.compress(text[:cut]) + gzip.compress(text[cut:]))
    res = _ingest_one(two, tmp_path / "ws")
    assert res.status == "ingested" and res.n_samples == len(recording[1])
    tail = tmp_path / "tail.csv.gz"
    tail.write_bytes(gzip.compress(text) + b"junk")
    assert _ingest_one(tail, tmp_path / "ws").reason.startswith("corrupt gzip data: 4 bytes of garbage after")


def test_cli_with_a_bad_limit_is_one_error_line(tmp_path, recording):
    from typer.testing import CliRunner

    from laneprint.app.cli import app

    write_csv(tmp_path / "r.csv", *recording)
    out = CliRunner().invoke(
        app, ["ingest", str(tmp_path / "r.csv"), "-w", str(tmp_path / "ws")], env={"LANEPRINT_MAX_COLUMNS": "many"}
    )
    assert out.exit_code == 1
    assert out.output.strip() == "error: LANEPRINT_MAX_COLUMNS='many' is not a positive number"
    ok = CliRunner().invoke(
        app,
        ["ingest", str(tmp_path / "r.csv"), "-w", str(tmp_path / "ws"), "--json"],
        env={"LANEPRINT_MAX_COLUMNS": "5"},
    )
    assert json.loads(ok.output)["files"][0]["reason"].startswith("malformed CSV: the header has ")
