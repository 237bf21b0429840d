"""The records of an MCAP file, read in file order: channels, schemas, messages, metadata.

One linear walk over the top-level records (chunks decompressed and walked in turn)
reads every valid MCAP the same way, whatever its writer left out: no summary, no
chunk index, channels and schemas that the summary does not repeat, no statistics,
padding after known fields, compression none / lz4 / zstd. A chunk whose Message Index
records (written after it by most writers) check out against its bytes is cut with numpy
from those offsets; otherwise its message records are cut with one `struct` call each
(the mcap library builds a dataclass per record through a stream, 4-5x slower). Channel,
schema and metadata records (a handful) are parsed by the mcap library's own record
classes.

Anything the walk does not understand sends the file to mcap's `StreamReader`, whose
failure is turned into a one-line reason with the byte offset (`Rejected`).
"""

from __future__ import annotations

import io
import struct
from typing import Any

import numpy as np

from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk

from ingest.rawlog import Rejected, first_line

MAGIC = b"\x89MCAP0\r\n"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_METADATA, _OP_FOOTER = 0x03, 0x04, 0x05, 0x06, 0x0C, 0x02
_OP_MESSAGE_INDEX = 0x07
_HEAD = struct.Struct("<BQ")  # opcode, record length
_REC = struct.Struct("<BQH4xQ")  # opcode, record length, then a message's channel id, (sequence), log_time
_MSG_FIXED = 22  # bytes before a message's data
_CHUNK_HEAD = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, length of the compression name


class Unreadable(Exception):
    """The fast walk met something it does not handle; the stream reader then names it."""


class Collected:
    """Messages grouped by channel id, plus the channels, schemas and Metadata records."""

    def __init__(self) -> None:
        self.channels: dict[int, Channel] = {}
        self.schemas: dict[int, Schema] = {}
        self.times: dict[int, list[int]] = {}
        self.datas: dict[int, list[bytes]] = {}
        self.metadata: dict[str, dict[str, str]] = {}

    def add(self, channel_id: int, log_time: int, data: bytes) -> None:
        times = self.times.get(channel_id)
        if times is None:
            times = self.times[channel_id] = []
            self.datas[channel_id] = []
        times.append(log_time)
        self.datas[channel_id].append(data)

    def add_channel(self, ch: Channel) -> None:
        """Keep a Channel record; `Rejected` when its id was declared before as another channel (the
        summary repeats each channel as it was: the same record again is fine)."""
        known = self.channels.get(ch.id)
        if known is not None and (known.topic, known.message_encoding, known.schema_id) != (
            ch.topic,
            ch.message_encoding,
            ch.schema_id,
        ):
            raise Rejected(
                f"corrupt MCAP: channel id {ch.id} is declared twice, as {known.topic!r} and as "
                f"{ch.topic!r}: its messages cannot be told apart; write each channel with its own id"
            )
        self.channels[ch.id] = ch

    def take(self, rec: Any) -> None:
        """Keep one record parsed by the mcap library."""
        if isinstance(rec, Message):
            self.add(rec.channel_id, rec.log_time, rec.data)
        elif isinstance(rec, Channel):
            self.add_channel(rec)
        elif isinstance(rec, Schema):
            self.schemas[rec.id] = rec
        elif isinstance(rec, Metadata):
            self.metadata[rec.name] = dict(rec.metadata)


def _parse(cls: Any, buf: bytes, body: int, end: int) -> Any:
    """One record by the mcap library's parser, bounded to its own bytes (padding allowed)."""
    return cls.read(ReadDataStream(io.BytesIO(buf[body:end])))


def _inflate(compression: str, raw: memoryview, size: int) -> bytes:
    if compression == "":
        return bytes(raw)
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(raw, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(raw, max_length=size)  # no larger than it claims
    raise Unreadable(f"compression {compression!r}")


class _Messages:
    """Message records grouped by channel id as the walk meets them: (log times, payloads) per channel."""

    def __init__(self) -> None:
        self.by_channel: dict[int, tuple[list[int], list[bytes]]] = {}

    def into(self, got: Collected) -> None:
        for cid, (times, datas) in self.by_channel.items():
            got.times.setdefault(cid, []).extend(times)
            got.datas.setdefault(cid, []).extend(datas)


def _walk(buf: bytes, pos: int, stop: int, got: Collected, msgs: _Messages) -> None:
    """Read the messages, channels and schemas in buf[pos:stop] (a chunk's records, or one top-level record)."""
    rec, head = _REC.unpack_from, _HEAD.unpack_from
    by_channel = msgs.by_channel
    while pos < stop:
        try:  # a message's header with its record's: one call per message
            op, length, cid, log_time = rec(buf, pos)
        except struct.error:  # fewer than 23 bytes left in the buffer
            if pos + 9 > stop:
                raise Unreadable("record header cut") from None
            op, length = head(buf, pos)
        body, end = pos + 9, pos + 9 + length
        if end > stop:
            raise Unreadable("record past its end")
        if op == _OP_MESSAGE:
            if length < _MSG_FIXED:
                raise Unreadable("short message")
            lists = by_channel.get(cid)  # a dict look-up per message: cheaper than grouping afterwards
            if lists is None:
                lists = by_channel[cid] = ([], [])
            lists[0].append(log_time)
            lists[1].append(buf[body + _MSG_FIXED : end])
        elif op == _OP_CHANNEL:
            got.take(_parse(Channel, buf, body, end))
        elif op == _OP_SCHEMA:
            got.take(_parse(Schema, buf, body, end))
        pos = end


def _index_entries(data: bytes, indexes: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(channel id, log time, offset) of every entry of a chunk's Message Index records
    (`indexes`: their (body offset, length) in `data`); None when one does not fit its record
    (an index is only a shortcut: the chunk is then walked)."""
    cids, times, offsets = [], [], []
    for body, length in indexes:
        if length < 6:
            return None
        cid, nbytes = struct.unpack_from("<HI", data, body)
        if nbytes % 16 or 6 + nbytes > length:
            return None
        pairs = np.frombuffer(data, dtype="<u8", count=nbytes // 8, offset=body + 6).reshape(-1, 2)
        cids.append(np.full(len(pairs), cid, dtype=np.int64))
        times.append(pairs[:, 0])
        offsets.append(pairs[:, 1])
    if not cids:
        return np.zeros(0, np.int64), np.zeros(0, np.uint64), np.zeros(0, np.uint64)
    return np.concatenate(cids), np.concatenate(times), np.concatenate(offsets)


def _gather_u64(buf: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The little-endian uint64 at each byte offset `at` of `buf` (uint8)."""
    return np.ascontiguousarray(buf[at[:, None] + np.arange(8)]).view("<u8").ravel()


def _walk_indexed(
    inner: bytes, entries: tuple[np.ndarray, np.ndarray, np.ndarray] | None, got: Collected, msgs: _Messages
) -> bool:
    """Cut a chunk's messages at the offsets its Message Index records give, checked against the
    chunk's own bytes (each offset a message record on that channel at that log time, the records
    in order without overlap); the bytes between them (channels, schemas) are walked. False, with
    nothing taken, when anything does not match: the caller then walks the whole chunk."""
    if entries is None:
        return False
    cids, times, offsets = entries
    size = len(inner)
    if len(offsets) == 0 or int(offsets.max()) + 9 + _MSG_FIXED > size:
        return False
    order = np.argsort(offsets, kind="stable")
    cids, times, at = cids[order], times[order], offsets[order].astype(np.int64)
    buf = np.frombuffer(inner, dtype=np.uint8)
    lengths = _gather_u64(buf, at + 1)
    ends = at + 9 + lengths.astype(np.int64)
    rec_cid = buf[at + 9].astype(np.int64) | (buf[at + 10].astype(np.int64) << 8)
    if (
        (buf[at] != _OP_MESSAGE).any()
        or (lengths < _MSG_FIXED).any()
        or (lengths > size).any()
        or ends[-1] > size
        or (ends[:-1] > at[1:]).any()
        or (rec_cid != cids).any()
        or (_gather_u64(buf, at + 15) != times).any()
    ):
        return False
    between = Collected()
    gap_starts = np.concatenate(([0], ends))
    gap_ends = np.concatenate((at, [size]))
    for g in np.flatnonzero(gap_ends > gap_starts).tolist():
        gap_msgs = _Messages()
        _walk(inner, int(gap_starts[g]), int(gap_ends[g]), between, gap_msgs)
        if gap_msgs.by_channel:  # a message the index does not list: keep the walk's file order
            return False
    for ch in between.channels.values():
        got.add_channel(ch)
    got.schemas.update(between.schemas)
    starts = (at + 9 + _MSG_FIXED).tolist()
    end_list = ends.tolist()
    time_list = times.tolist()
    for cid in np.unique(cids).tolist():
        rows = np.flatnonzero(cids == cid).tolist()
        lists = msgs.by_channel.get(cid)
        if lists is None:
            lists = msgs.by_channel[cid] = ([], [])
        lists[0].extend([time_list[i] for i in rows])
        lists[1].extend([inner[starts[i] : end_list[i]] for i in rows])
    return True


def top_records(data: bytes) -> list[tuple[int, int, int]]:
    """(opcode, byte offset, length) of the top-level records after the leading magic, up to the footer.

    Headers only. The walk stops after the footer, after a record claiming more bytes
    than the file holds (listed last, for the caller to name), or with fewer than 9
    bytes left. The limits (`ingest.limits.check_mcap_records`) and the reader
    (`read_records`) both take this one list.
    """
    heads: list[tuple[int, int, int]] = []
    head = _HEAD.unpack_from
    pos, n = len(MAGIC), len(data)
    while pos + 9 <= n:
        op, length = head(data, pos)
        heads.append((op, pos, length))
        if op == _OP_FOOTER or length > n - pos - 9:
            break
        pos += 9 + length
    return heads


def read_records(data: bytes, heads: list[tuple[int, int, int]] | None = None) -> Collected:
    """Every record of a complete MCAP file in file order; `Unreadable` on anything unexpected.

    `heads`: the file's `top_records`, when the caller has them already.
    """
    if not (data.startswith(MAGIC) and data.endswith(MAGIC)):
        raise Unreadable("no magic")
    heads = top_records(data) if heads is None else heads
    if not heads or heads[-1][0] != _OP_FOOTER or heads[-1][1] + 9 + heads[-1][2] + len(MAGIC) != len(data):
        raise Unreadable("no footer right before the closing magic")
    got = Collected()
    msgs = _Messages()
    for k, (op, pos, length) in enumerate(heads[:-1]):
        body, end = pos + 9, pos + 9 + length
        if op == _OP_CHUNK:
            _, _, size, _, clen = _CHUNK_HEAD.unpack_from(data, body)
            at = body + _CHUNK_HEAD.size
            compression = str(data[at : at + clen], "utf-8")
            (rlen,) = struct.unpack_from("<Q", data, at + clen)
            start = at + clen + 8
            if start + rlen > end:
                raise Unreadable("chunk records past the chunk")
            inner = _inflate(compression, memoryview(data)[start : start + rlen], size)  # no copy of the input
            if len(inner) != size:
                raise Unreadable("chunk size")
            indexes = []
            for op2, pos2, length2 in heads[k + 1 : -1]:  # the chunk's Message Index records follow it
                if op2 != _OP_MESSAGE_INDEX:
                    break
                indexes.append((pos2 + 9, length2))
            if not (indexes and _walk_indexed(inner, _index_entries(data, indexes), got, msgs)):
                _walk(inner, 0, len(inner), got, msgs)
        elif op == _OP_METADATA:
            got.take(_parse(Metadata, data, body, end))
        else:  # a message, channel or schema outside chunks (others are skipped)
            _walk(data, pos, end, got, msgs)
    msgs.into(got)
    return got


def read_stream(data: bytes) -> Collected:
    """Record by record with mcap's `StreamReader`: for files the fast walk refused, to locate damage."""
    got = Collected()
    bio = io.BytesIO(data)
    last_end = len(MAGIC)
    try:
        for rec in StreamReader(bio, emit_chunks=True).records:
            for inner in breakup_chunk(rec) if isinstance(rec, Chunk) else (rec,):
                got.take(inner)
            last_end = bio.tell()
    except Rejected:
        raise
    except Exception as exc:
        truncated = not data.endswith(MAGIC)
        if truncated and last_end >= len(data):
            raise Rejected(
                f"truncated MCAP: the file ends after the last complete record (byte {last_end}) "
                f"without a footer; the recorder did not finish it (try `mcap recover`)"
            ) from None
        if truncated:
            raise Rejected(
                f"truncated MCAP: stream ended inside a record at byte {last_end} of {len(data)} (try `mcap recover`)"
            ) from None
        raise Rejected(f"corrupt MCAP: unreadable record at byte {last_end} ({first_line(exc)})") from None
    return got


def _check_channels(got: Collected) -> None:
    """`Rejected` when messages use a channel id that no Channel record defines."""
    unknown = sorted(set(got.times) - set(got.channels))
    if unknown:
        n = sum(len(got.times[c]) for c in unknown)
        ids = ", ".join(map(str, unknown[:5])) + (" ..." if len(unknown) > 5 else "")
        raise Rejected(
            f"corrupt MCAP: {n} message(s) on channel id(s) {ids}, which no Channel record in the file defines"
        )


def collect(data: bytes, heads: list[tuple[int, int, int]] | None = None) -> Collected:
    """Channels, schemas, messages and metadata of MCAP bytes (`heads`: their `top_records`, if
    known); `Rejected` naming the damage."""
    try:
        got = read_records(data, heads)
    except (MemoryError, Rejected):
        raise
    except Exception:  # Unreadable, struct.error, a decompressor's own error...: the stream reader names it
        got = read_stream(data)
    _check_channels(got)
    return got
