"""Resource limits of an ingest: what a log may cost before it is refused.

A hostile or broken log must be refused with a reason before it exhausts memory or
time: a small `.csv.gz` that inflates to gigabytes, an MCAP whose chunk or record
claims a huge size, a CSV with a million columns or a line of a gigabyte. Each limit
is a field of `IngestLimits`, settable through an environment variable
(`IngestLimits.from_env`); the defaults are far above any real log of the format.
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass, fields
from typing import Any
from typing import Mapping as TypingMapping

from ingest.mcap_records import top_records
from ingest.rawlog import Rejected, first_line
from laneprint.errors import UserError

MB = 1 << 20
RATIO_FLOOR_BYTES = 16 * MB  # [bytes] output below this may compress arbitrarily well (tiny or constant logs)
_INFLATE_STEP = 4 * MB  # [bytes] gunzip in steps of this much output, checking the limits after each
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_CHUNK = 0x06


@dataclass(frozen=True)
class IngestLimits:
    """How large a log may be; every field can be set by the environment variable in its comment."""

    max_file_mb: float = 2048.0
    """[MB] largest log file read at all (LANEPRINT_MAX_FILE_MB)."""
    max_inflated_mb: float = 2048.0
    """[MB] largest CSV after gunzip, and largest sum of an MCAP's uncompressed chunks (LANEPRINT_MAX_INFLATED_MB)."""
    max_inflate_ratio: float = 200.0
    """decompressed / compressed bytes beyond which a gzip stream or an MCAP chunk is taken for a
    decompression bomb, once past 16 MB (real logs compress 5-20x) (LANEPRINT_MAX_INFLATE_RATIO)."""
    max_record_mb: float = 1024.0
    """[MB] largest single MCAP record or uncompressed chunk (LANEPRINT_MAX_RECORD_MB)."""
    max_line_kb: float = 1024.0
    """[KB] longest CSV line, header included (LANEPRINT_MAX_LINE_KB)."""
    max_columns: int = 20_000
    """most CSV columns in the header (LANEPRINT_MAX_COLUMNS)."""

    @property
    def max_line_bytes(self) -> int:
        return int(self.max_line_kb * 1024)

    @classmethod
    def from_env(cls, environ: TypingMapping[str, str] | None = None) -> "IngestLimits":
        """Defaults overridden by `LANEPRINT_<FIELD>` variables; `UserError` for a value that is not a positive number."""
        env = os.environ if environ is None else environ
        values: dict[str, Any] = {}  # float or int, by the field's type
        for f in fields(cls):
            var = f"LANEPRINT_{f.name.upper()}"
            if var not in env:
                continue
            try:
                value = float(env[var])
            except ValueError:
                value = -1.0
            if not value > 0:
                raise UserError(f"{var}={env[var]!r} is not a positive number")
            values[f.name] = int(value) if f.type in ("int", int) else value
        return cls(**values)


def env_var(name: str) -> str:
    """The environment variable that sets the field `name` (for messages)."""
    return f"LANEPRINT_{name.upper()}"


def _mb(n: float) -> str:
    return f"{n / MB:.0f} MB" if n >= MB else f"{n / 1024:.0f} KB" if n >= 1024 else f"{n:.0f} bytes"


def check_file_size(size: int, limits: IngestLimits) -> None:
    """`Rejected` when a file is larger than `max_file_mb`, before it is read."""
    if size > limits.max_file_mb * MB:
        raise Rejected(
            f"file too large: {_mb(size)} > the {limits.max_file_mb:g} MB limit; split the recording "
            f"or raise {env_var('max_file_mb')}"
        )


def gunzip(data: bytes, limits: IngestLimits) -> bytes:
    """Decompress gzip bytes (all members) within the limits; `Rejected` with the reason otherwise.

    Output is produced in steps, so a decompression bomb is refused after at most
    16 MB (ratio) or `max_inflated_mb` of output, never inflated whole.
    """
    if data[:2] != b"\x1f\x8b":
        raise Rejected("not gzip-compressed although the name ends in .gz (no gzip magic bytes at byte 0)")
    cap = limits.max_inflated_mb * MB
    out = bytearray()
    pos = 0  # start of the current gzip member in `data`
    try:
        while True:
            d = zlib.decompressobj(wbits=31)
            buf: memoryview | bytes = memoryview(data)[pos:]
            while True:
                out += d.decompress(buf, _INFLATE_STEP)
                buf = d.unconsumed_tail
                used = len(data) - len(d.unused_data if d.eof else buf)  # input bytes consumed so far
                if len(out) > cap:
                    raise Rejected(
                        f"gzip inflates beyond the {limits.max_inflated_mb:g} MB limit (more than "
                        f"{_mb(len(out))} from the first {_mb(used)}); raise {env_var('max_inflated_mb')} "
                        f"if the file is genuine"
                    )
                if len(out) > RATIO_FLOOR_BYTES and len(out) > limits.max_inflate_ratio * max(used, 1):
                    raise Rejected(
                        f"gzip bomb: {_mb(len(out))} inflated from the first {used} bytes "
                        f"({len(out) / max(used, 1):.0f}x, limit {limits.max_inflate_ratio:g}x); raise "
                        f"{env_var('max_inflate_ratio')} if the file is genuine"
                    )
                if d.eof or not buf:
                    break
            if not d.eof:
                raise Rejected(
                    f"truncated gzip: the compressed stream ends early at byte {len(data)} "
                    f"({len(out)} bytes decompressed)"
                )
            rest = d.unused_data
            if not rest.strip(b"\x00"):  # padding after the last member is allowed
                return bytes(out)
            if rest[:2] != b"\x1f\x8b":
                raise Rejected(
                    f"corrupt gzip data: {len(rest)} bytes of garbage after the compressed stream "
                    f"at byte {len(data) - len(rest)}"
                )
            pos = len(data) - len(rest)
    except zlib.error as exc:
        raise Rejected(f"corrupt gzip data in the member starting at byte {pos}: {first_line(exc)}") from None


def check_csv_shape(data: bytes, delimiter: str, limits: IngestLimits) -> None:
    """`Rejected` when the header is longer than a line may be or has more columns than allowed.

    Data lines are bounded by the parser itself (its block size is `max_line_bytes`).
    """
    end = data.find(b"\n", 0, limits.max_line_bytes + 1)
    if end < 0 and len(data) > limits.max_line_bytes:
        raise Rejected(
            f"malformed CSV: the header (line 1) is longer than the {limits.max_line_kb:g} KB line limit; "
            f"is this a CSV log? (raise {env_var('max_line_kb')} if it is)"
        )
    header = data[: end if end >= 0 else len(data)]
    n = header.count(delimiter.encode()) + 1
    if n > limits.max_columns:
        raise Rejected(
            f"malformed CSV: the header has {n} columns, more than the {limits.max_columns} limit "
            f"(raise {env_var('max_columns')} if they are genuine)"
        )


def long_line(data: bytes, limits: IngestLimits) -> str | None:
    """'line N is longer than ...' for the first line over `max_line_bytes` (error path only)."""
    start, line = 0, 1
    while start < len(data):
        end = data.find(b"\n", start, start + limits.max_line_bytes + 1)
        if end < 0:
            if len(data) - start > limits.max_line_bytes:
                return (
                    f"line {line} (from byte {start}) is longer than the {limits.max_line_kb:g} KB line limit "
                    f"(raise {env_var('max_line_kb')} if it is genuine)"
                )
            return None
        start, line = end + 1, line + 1
    return None


def _check_zstd_frame(data: bytes, body: int, length: int, size: int, pos: int) -> None:
    """`Rejected` when a zstd chunk's frame header claims more than the chunk says (the
    decompressor would allocate what the frame claims)."""
    try:
        (clen,) = struct.unpack_from("<I", data, body + 28)
        compression = bytes(data[body + 32 : body + 32 + clen])
        frame = body + 32 + clen + 8
        if compression != b"zstd" or frame + 6 > body + length or data[frame : frame + 4] != b"\x28\xb5\x2f\xfd":
            return
        fhd = data[frame + 4]
        single, fcs_flag, did = (fhd >> 5) & 1, fhd >> 6, fhd & 3
        at = frame + 5 + (0 if single else 1) + (0, 1, 2, 4)[did]
        fcs_len = (1 if single else 0, 2, 4, 8)[fcs_flag]
        if not fcs_len or at + fcs_len > len(data):
            return
        claimed = int.from_bytes(data[at : at + fcs_len], "little") + (256 if fcs_len == 2 else 0)
    except struct.error:
        return
    if claimed > size:
        raise Rejected(
            f"corrupt MCAP: the chunk at byte {pos} says {size} bytes uncompressed but its zstd frame claims {claimed}"
        )


def check_mcap_records(data: bytes, limits: IngestLimits, heads: list[tuple[int, int, int]] | None = None) -> None:
    """`Rejected` when a top-level MCAP record claims more than the file or the limits allow.

    Cheap (headers only, nothing decompressed); what the records hold is the reader's
    to judge. `heads`: the file's `mcap_records.top_records` (walked here when not
    given). A walk that ends early (a file without footer) is left to the reader, which
    names the truncation.
    """
    n = len(data)
    total = 0
    record_cap = limits.max_record_mb * MB
    for op, pos, length in top_records(data) if heads is None else heads:
        body = pos + 9
        if length > n - body:
            if not data.endswith(_MCAP_MAGIC):
                raise Rejected(
                    f"truncated MCAP: stream ended inside a record at byte {pos} of {n} (try `mcap recover`)"
                )
            raise Rejected(
                f"corrupt MCAP: the record at byte {pos} (opcode 0x{op:02x}) claims {length} bytes, "
                f"past the end of the file ({n} bytes)"
            )
        if length > record_cap:
            raise Rejected(
                f"MCAP record at byte {pos} is {_mb(length)}, more than the {limits.max_record_mb:g} MB "
                f"record limit (raise {env_var('max_record_mb')})"
            )
        if op == _OP_CHUNK and length >= 24:
            size = struct.unpack_from("<Q", data, body + 16)[0]
            if size > record_cap:
                raise Rejected(
                    f"MCAP chunk at byte {pos} claims {_mb(size)} uncompressed, more than the "
                    f"{limits.max_record_mb:g} MB record limit (raise {env_var('max_record_mb')})"
                )
            if size > RATIO_FLOOR_BYTES and size > limits.max_inflate_ratio * length:
                raise Rejected(
                    f"MCAP chunk at byte {pos} claims {_mb(size)} uncompressed from {length} bytes "
                    f"({size / length:.0f}x, limit {limits.max_inflate_ratio:g}x): a forged size or a "
                    f"decompression bomb (raise {env_var('max_inflate_ratio')} if genuine)"
                )
            _check_zstd_frame(data, body, length, size, pos)
            total += size
            if total > limits.max_inflated_mb * MB:
                raise Rejected(
                    f"MCAP chunks hold more than the {limits.max_inflated_mb:g} MB limit uncompressed "
                    f"(reached at the chunk at byte {pos}; raise {env_var('max_inflated_mb')})"
                )
