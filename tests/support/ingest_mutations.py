"""Damaged copies of logs, for robustness tests: every way a file can go wrong on its way in.

`mutate(data, fmt, kind, rng)` returns a mutated copy of a log's bytes. Kinds work on
the bytes (truncate, flip, drop, duplicate, insert), on a CSV's rows and columns
(drop, duplicate, reorder, shuffle, rename, change units, extreme values, ragged
rows, re-encode the text) or on an MCAP's messages (drop, duplicate, reorder,
change units, extreme values, drop fields, rename topics, bad JSON, other encodings,
no index). Every choice comes from `rng`, so a (seed, case) pair replays a file.

Used by tests/ingest/test_ingest_fuzz.py (a few dozen files) and benchmarks/fuzz.py
(tens of thousands). `excerpts` cuts the shipped sample logs into small seed files.
"""

from __future__ import annotations

import gzip
import io
import json
import random
import re
import traceback
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable

from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

from laneprint.workspace import Workspace

BYTE_KINDS = ("truncate", "flip_bytes", "drop_bytes", "duplicate_bytes", "insert_bytes")
CSV_KINDS = (
    "drop_rows",
    "duplicate_rows",
    "swap_rows",
    "shuffle_rows",
    "drop_column",
    "duplicate_column",
    "shuffle_columns",
    "rename_column",
    "change_units",
    "extreme_values",
    "ragged_row",
    "reencode_text",
    "sparse_traffic",
)
MCAP_KINDS = (
    "drop_messages",
    "duplicate_messages",
    "swap_times",
    "shuffle_messages",
    "change_units",
    "extreme_values",
    "drop_field",
    "rename_topic",
    "bad_json",
    "other_encoding",
    "drop_metadata",
    "unindexed",
)
EXTREMES = (
    "inf",
    "-inf",
    "nan",
    "1e308",
    "-1e308",
    "1e999",
    "0",
    "-0",
    "9" * 40,
    "",
    " ",
    "abc",
    "1,5",
    "0x10",
    "١٢",
    "true",
    "None",
    "1e-320",
    "-1",
)
JSON_EXTREMES: tuple[Any, ...] = (
    float("inf"),
    float("-inf"),
    float("nan"),
    1e308,
    -1e308,
    0,
    -1,
    10**40,
    "abc",
    "",
    None,
    True,
    [],
    {},
    [1.0],
    {"x": 1},
)
UNITS = (3.6, 1 / 3.6, 1000.0, 0.001, 100.0, 0.3048, -1.0, 1e6)


def kinds_for(fmt: str) -> tuple[str, ...]:
    """The mutation kinds that apply to a log format ('csv', 'csv.gz', 'mcap')."""
    return BYTE_KINDS + (MCAP_KINDS if fmt == "mcap" else CSV_KINDS)


# --- bytes ---------------------------------------------------------------------


def _span(rng: random.Random, n: int) -> tuple[int, int]:
    a = rng.randrange(max(n, 1))
    return a, min(n, a + rng.choice((1, 2, 8, 64, 512, 4096)))


def _bytes(data: bytes, kind: str, rng: random.Random) -> bytes:
    n = len(data)
    if kind == "truncate":
        return data[: rng.randrange(n)] if n else data
    if kind == "flip_bytes":
        out = bytearray(data)
        for _ in range(rng.choice((1, 1, 2, 4, 16))):
            if out:
                i = rng.randrange(len(out))
                out[i] ^= rng.randrange(1, 256)
        return bytes(out)
    a, b = _span(rng, n)
    if kind == "drop_bytes":
        return data[:a] + data[b:]
    if kind == "duplicate_bytes":
        return data[:b] + data[a:b] + data[b:]
    junk = bytes(rng.randrange(256) for _ in range(rng.choice((1, 3, 17, 300))))
    return data[:a] + junk + data[a:]  # insert_bytes


# --- CSV -----------------------------------------------------------------------


def _csv(text: str, kind: str, rng: random.Random) -> str | bytes:
    lines = text.splitlines()
    header, rows = lines[0].split(","), [r.split(",") for r in lines[1:]]
    if not rows:
        return text
    n, k = len(rows), len(header)
    i = rng.randrange(n)
    if kind == "drop_rows":
        a = rng.randrange(n)
        del rows[a : a + rng.choice((1, 1, 5, n))]
    elif kind == "duplicate_rows":
        rows.insert(i, list(rows[i]))
    elif kind == "swap_rows":
        j = rng.randrange(n)
        rows[i], rows[j] = rows[j], rows[i]
    elif kind == "shuffle_rows":
        rng.shuffle(rows)
    elif kind in ("drop_column", "duplicate_column", "shuffle_columns", "rename_column"):
        table = [header] + rows
        c = rng.randrange(k)
        if kind == "drop_column":
            table = [r[:c] + r[c + 1 :] for r in table]
        elif kind == "duplicate_column":
            table = [r + [r[c]] for r in table]
        elif kind == "shuffle_columns":
            order = list(range(k))
            rng.shuffle(order)
            table = [[r[o] for o in order] for r in table]
        else:
            table[0][c] = rng.choice(("", "x", table[0][c].upper(), table[0][c] + " ", "ego_v", "t"))
        header, rows = table[0], table[1:]
    elif kind == "change_units":
        c = rng.randrange(k)
        f = rng.choice(UNITS)
        for r in rows:
            try:
                r[c] = repr(float(r[c]) * f)
            except (ValueError, IndexError):
                pass
    elif kind == "extreme_values":
        for _ in range(rng.choice((1, 1, 3, 20))):
            rows[rng.randrange(n)][rng.randrange(k)] = rng.choice(EXTREMES)
    elif kind == "ragged_row":
        if rng.random() < 0.5:
            rows[i].append("1")
        elif len(rows[i]) > 1:
            rows[i].pop()
    elif kind == "sparse_traffic":  # a traffic vehicle leaves the scene for a while: its cells go empty
        c = rng.randrange(k)
        a = rng.randrange(n)
        for r in rows[a : a + rng.choice((1, 10, n))]:
            r[c] = ""
    out = "\n".join(",".join(r) for r in [header] + rows) + "\n"
    if kind == "reencode_text":
        how = rng.choice(("crlf", "bom", "utf16", "latin1", "semicolon", "tab", "no_final_newline", "quotes"))
        if how == "crlf":
            return out.replace("\n", "\r\n").encode()
        if how == "bom":
            return b"\xef\xbb\xbf" + out.encode()
        if how == "utf16":
            return out.encode("utf-16")
        if how == "latin1":
            return out.replace(",D", ",Dé", 1).encode("latin-1")
        if how == "semicolon":
            return out.replace(",", ";").encode()
        if how == "tab":
            return out.replace(",", "\t").encode()
        if how == "quotes":
            return "\n".join(",".join(f'"{v}"' for v in line.split(",")) for line in out.splitlines()).encode()
        return out.rstrip("\n").encode()
    return out


# --- MCAP ----------------------------------------------------------------------


@lru_cache(maxsize=16)
def _mcap_parts(data: bytes) -> tuple[tuple[tuple[str, int, bytes], ...], tuple[tuple[str, tuple], ...]]:
    """(messages as (topic, log_time, data), metadata records) of a well-formed MCAP."""
    reader = make_reader(io.BytesIO(data))
    msgs = tuple((ch.topic, m.log_time, m.data) for _, ch, m in reader.iter_messages(log_time_order=False))
    meta = tuple((md.name, tuple(sorted(md.metadata.items()))) for md in reader.iter_metadata())
    return msgs, meta


def _write_mcap(
    msgs: list[tuple[str, int, bytes]], meta: list[tuple[str, dict]], encodings: dict[str, str], indexed: bool = True
) -> bytes:
    out = io.BytesIO()
    w = (
        Writer(out, compression=CompressionType.ZSTD)
        if indexed
        else Writer(out, index_types=IndexType.NONE, use_chunking=False, use_summary_offsets=False)
    )
    w.start()
    channels: dict[str, int] = {}
    for topic, t, payload in msgs:
        if topic not in channels:
            channels[topic] = w.register_channel(topic, encodings.get(topic, "json"), 0)
        w.add_message(channels[topic], max(0, t), payload, max(0, t))
    for name, md in meta:
        w.add_metadata(name, md)
    w.finish()
    return out.getvalue()


def _set_field(msg: dict, rng: random.Random, value: Any) -> None:
    """Set a random leaf of a decoded message (or of a vehicle in it) to `value`."""
    target = msg
    if isinstance(msg.get("vehicles"), list) and msg["vehicles"] and rng.random() < 0.7:
        target = rng.choice(msg["vehicles"])
        if not isinstance(target, dict):
            return
    if target:
        target[rng.choice(sorted(target))] = value


def _mcap(data: bytes, kind: str, rng: random.Random) -> bytes:
    base, base_meta = _mcap_parts(data)
    msgs = list(base)
    meta = [(name, dict(items)) for name, items in base_meta]
    encodings: dict[str, str] = {}
    n = len(msgs)
    i = rng.randrange(n)
    topics = sorted({m[0] for m in msgs})
    if kind == "drop_messages":
        a = rng.randrange(n)
        del msgs[a : a + rng.choice((1, 1, 10, n))]
    elif kind == "duplicate_messages":
        msgs.insert(i, msgs[i])
    elif kind == "swap_times":
        j = rng.randrange(n)
        (ta, ti, da), (tb, tj, db) = msgs[i], msgs[j]
        msgs[i], msgs[j] = (ta, tj, da), (tb, ti, db)
    elif kind == "shuffle_messages":
        rng.shuffle(msgs)
    elif kind in ("change_units", "extreme_values", "drop_field"):
        topic = rng.choice(topics)
        f = rng.choice(UNITS)
        picked = [j for j, m in enumerate(msgs) if m[0] == topic]
        chosen = picked if kind == "change_units" else rng.sample(picked, min(len(picked), rng.choice((1, 3))))
        key = None
        for j in chosen:
            msg = json.loads(msgs[j][2])
            if kind == "change_units":
                key = key or rng.choice(sorted(msg) or ["x"])
                if isinstance(msg.get(key), (int, float)) and not isinstance(msg.get(key), bool):
                    msg[key] = msg[key] * f
            elif kind == "extreme_values":
                _set_field(msg, rng, rng.choice(JSON_EXTREMES))
            elif msg:
                del msg[rng.choice(sorted(msg))]
            msgs[j] = (topic, msgs[j][1], json.dumps(msg).encode())
    elif kind == "rename_topic":
        old, new = rng.choice(topics), rng.choice(("/ego", "/x", topics[0] + "2", "")) or "/"
        msgs = [(new if t == old else t, lt, d) for t, lt, d in msgs]
    elif kind == "bad_json":
        t, lt, d = msgs[i]
        msgs[i] = (t, lt, rng.choice((d[: len(d) // 2], d + b"}", b"", b"\xff\xfe", d.replace(b":", b"=", 1))))
    elif kind == "other_encoding":
        encodings[rng.choice(topics)] = rng.choice(("protobuf", "cdr", "", "JSON"))
    elif kind == "drop_metadata":
        meta = (
            []
            if rng.random() < 0.5
            else [(name, {k: v for k, v in md.items() if k != "driver_id"}) for name, md in meta]
        )
    return _write_mcap(msgs, meta, encodings, indexed=kind != "unindexed")


def mutate(data: bytes, fmt: str, kind: str, rng: random.Random) -> bytes:
    """A mutated copy of the log `data` in format `fmt`; `kind` from `kinds_for(fmt)`."""
    if kind in BYTE_KINDS:
        return _bytes(data, kind, rng)
    if fmt == "mcap":
        return _mcap(data, kind, rng)
    text = (gzip.decompress(data) if fmt == "csv.gz" else data).decode()
    out = _csv(text, kind, rng)
    raw = out if isinstance(out, bytes) else out.encode()
    return gzip.compress(raw, compresslevel=1) if fmt == "csv.gz" else raw


def excerpts(sample_dir: Path, seconds: tuple[float, ...] = (4.0, 20.0), n_logs: int = 2) -> dict[str, bytes]:
    """Seed files: the first `seconds` of `n_logs` CSV and `n_logs` MCAP sample logs, written in every format.

    Keys are file names ('D02_S60_4s.csv', ...). The excerpts are read and written
    with laneprint's own reader and writers, so they are logs of the format.
    """
    import tempfile

    from ingest.mapping import IDENTITY
    from ingest.pipeline import log_format, read_log, session_stem
    from ingest.validate import canonicalise
    from ingest.writers import write_csv, write_mcap

    files = sorted(p for p in sample_dir.iterdir() if log_format(p))
    picked = [p for p in files if log_format(p) == "csv.gz"][:n_logs] + [p for p in files if log_format(p) == "mcap"][
        :n_logs
    ]
    out: dict[str, bytes] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for p in picked:
            rec = canonicalise(read_log(p.read_bytes(), log_format(p) or "", IDENTITY), IDENTITY, session_stem(p), None)
            for s in seconds:
                ego = rec.ego[rec.ego["t_s"] < s]
                traffic = rec.traffic[rec.traffic["t_s"] < s]
                stem = f"{session_stem(p)}_{s:g}s"
                writers: dict[str, Callable[[Path], None]] = {
                    ".csv": lambda q: write_csv(q, rec.meta, ego, traffic),
                    ".csv.gz": lambda q: write_csv(q, rec.meta, ego, traffic),
                    ".mcap": lambda q: write_mcap(q, rec.meta, ego, traffic),
                }
                for suffix, write in writers.items():
                    q = Path(tmp) / f"{stem}{suffix}"
                    write(q)
                    out[q.name] = q.read_bytes()
    return out


# --- running one file and judging the outcome ----------------------------------------

OUTCOMES = ("ingested", "refused", "refused_unlocated", "unexpected", "traceback", "partial", "bad_output")
# a reason "names a signal or a byte offset" when it matches this
LOCATED = re.compile(
    r"byte \d|offset \d|bytes? \(|line \d|message \d|column|field '|topic|vehicle '|time '|signal|"
    r"driver_id|header|/ego/|/traffic/|/driver/|\bt=|ego_|speed|sample rate|no samples|"
    r"gzip|MCAP",
    re.IGNORECASE,
)


@dataclass
class Outcome:
    """How one file ended: one of OUTCOMES, with the reason or the traceback text."""

    outcome: str
    detail: str = ""


def check_workspace(ws: Workspace, stored: str | None) -> str:
    """'' when the workspace holds exactly the recording `stored` (or none), whole and valid; else what is wrong."""
    from ingest.values import EGO_REQUIRED_SCHEMA, TRAFFIC_SCHEMA, failures
    from laneprint.schemas import EGO, TRAFFIC, validate

    leftovers = [p.name for p in (ws.root / ".tmp").iterdir()] if (ws.root / ".tmp").exists() else []
    if leftovers:
        return f"leftovers under .tmp: {leftovers[:3]}"
    folders = sorted(p for p in ws.recordings_dir.iterdir()) if ws.recordings_dir.exists() else []
    if [p.name for p in folders] != ([stored] if stored else []):
        return f"recording folders {[p.name for p in folders]}, expected {[stored] if stored else []}"
    for d in folders:
        missing = [f for f in ("meta.parquet", "ego.parquet", "traffic.parquet") if not (d / f).exists()]
        if missing:
            return f"recording {d.name} lacks {missing}"
        _, ego, traffic = ws.load_recording(d.name)
        validate(ego, EGO)
        validate(traffic, TRAFFIC)
        bad = {
            **failures(ego.astype({"ego_lane": float}), EGO_REQUIRED_SCHEMA),
            **failures(traffic.astype({"lane": float}), TRAFFIC_SCHEMA),
        }
        if bad:
            return f"stored values out of bounds in {sorted(bad)}"
        if len(ego) and not (ego["t_s"].diff().iloc[1:] > 0).all():
            return "stored time not strictly increasing"
    return ""


def try_ingest(path: Path, ws_root: Path) -> Outcome:
    """Ingest one file into a fresh workspace at `ws_root` and judge how it ended (never raises)."""
    from ingest.mapping import IDENTITY
    from ingest.pipeline import FileResult, _Batch, parse_log

    ws = Workspace(ws_root).ensure()
    try:  # what `ingest_paths` does with one file on the local backend
        batch = _Batch(ws, IDENTITY, None)
        got = batch.prepare(path)
        res = got if isinstance(got, FileResult) else batch.store(path, got[1], parse_log(got[0]))
    except BaseException:  # noqa: BLE001 - a traceback is what the fuzzing looks for
        return Outcome("traceback", traceback.format_exc())
    stored = res.recording_id if res.status in ("ingested", "warning") else None
    try:
        wrong = check_workspace(ws, stored)
    except Exception:  # noqa: BLE001 - a stored recording that cannot be read back is partial
        wrong = traceback.format_exc()
    if wrong:
        return Outcome(
            "partial" if "leftovers" in wrong or "lacks" in wrong or "folders" in wrong else "bad_output", wrong
        )
    if stored:
        return Outcome("ingested", "; ".join(res.warnings))
    if res.status != "rejected" or not res.reason.strip():
        return Outcome("refused_unlocated", f"status {res.status} with reason {res.reason!r}")
    if res.reason.startswith("unexpected content"):
        return Outcome("unexpected", res.reason)
    return Outcome("refused" if LOCATED.search(res.reason) else "refused_unlocated", res.reason)
