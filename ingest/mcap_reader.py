"""Read an MCAP log (JSON messages) into a `RawLog`.

Files with ROS 2 (CDR) or protobuf messages, and any file read by a `[mcap.signals]`
mapping, are decoded through their schemas by `mcap_decoding`.

Records are read in file order by `mcap_records.collect` (every valid file the same
way, with or without summary, index or repeated channels). A file that ends without
the closing footer magic is truncated: it is rejected with the byte offset where the
last complete record ends (`mcap recover` can salvage it).
"""

from __future__ import annotations

import io
import json
import re
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.json as pajson

from ingest.logformat import (
    DEFAULT_LENGTH_M,
    NS_PER_S,
    TOPIC_BUTTON,
    TOPIC_CONTROLS,
    TOPIC_EGO,
    TOPIC_TRAFFIC,
)
from ingest.alignment import asof, place_presses
from ingest.jsondecode import float_columns, loads_many
from ingest.mapping import Mapping
from ingest.limits import IngestLimits, check_mcap_records
from ingest.mcap_records import MAGIC, Collected, collect, top_records
from ingest.object_ids import id_array
from ingest.rawlog import RawLog, Rejected, check_log_bytes, first_line

PART_MIN_BYTES = 4 << 20  # [bytes] a topic's JSON is read in parts side by side from 2 x this size

__all__ = ["MAGIC", "Collected", "read_collected", "read_mcap_file", "read_mcap_log"]


def _getter(path: str) -> Callable[[dict], Any]:
    if "." not in path:
        return lambda m: m.get(path)
    parts = path.split(".")

    def get(m: Any) -> Any:
        for p in parts:
            if not isinstance(m, dict):
                return None
            m = m.get(p)
        return m

    return get


def _decode(topic: str, datas: list[bytes], times: list[int]) -> list[Any]:
    """JSON-decode all messages of a topic in one call (falling back to locate a bad one)."""
    try:
        return loads_many(datas)
    except (ValueError, UnicodeDecodeError):
        for i, d in enumerate(datas):
            try:
                json.loads(d)
            except (ValueError, UnicodeDecodeError) as exc:
                raise Rejected(
                    f"message {i} on {topic} (log_time {times[i]} ns) is not valid JSON: {first_line(exc)}"
                ) from None
        raise Rejected(f"messages on {topic} are not valid JSON") from None


_OBJECT_SEAM = re.compile(rb"\}\s*\{")  # two objects side by side (inside a message, only ever in a list: '},{')
_BLANK_MESSAGE = re.compile(rb"(?:\A|\n)[ \t\r]*(?:\n|\Z)")


def _arrow_table(datas: list[bytes], schema: pa.Schema) -> pa.Table | None:
    """Decode JSON messages into columns with Arrow's JSON reader (C++, one pass).

    Many messages are cut into one part per core, each read by a single-threaded reader
    in its own thread (Arrow releases the GIL): ~10 % less CPU than Arrow's own threaded
    reader on the benchmark's traffic (41 MB), as for CSV (`csv_reader._parse`). None
    when the messages do not fit this fast path (a newline inside a message, a value of
    another type, invalid JSON): the caller then decodes them one by one with
    `json.loads`, which also names the offending message.
    """
    if not datas or len(set(schema.names)) != len(schema.names):
        return None
    size = sum(map(len, datas))
    parts = max(1, min(pa.cpu_count(), size // PART_MIN_BYTES, len(datas)))
    bounds = [len(datas) * i // parts for i in range(parts + 1)]
    parse = pajson.ParseOptions(explicit_schema=schema, unexpected_field_behavior="ignore")

    def read(i: int) -> pa.Table | None:
        piece = datas[bounds[i] : bounds[i + 1]]
        blob = b"\n".join(piece)
        # one object per message: no newline inside a message, and no message that holds two objects
        # or part of one (JSON that is only valid once messages are joined goes to the slow path, which refuses it)
        if (
            blob.count(b"\n") != len(piece) - 1
            or len(_OBJECT_SEAM.findall(blob)) != len(piece) - 1
            or _BLANK_MESSAGE.search(blob)
            or blob.lstrip()[:1] != b"{"
            or blob.rstrip()[-1:] != b"}"
        ):
            return None
        try:
            table = pajson.read_json(
                io.BytesIO(blob),
                parse_options=parse,
                read_options=pajson.ReadOptions(use_threads=False, block_size=max(1 << 20, 2 * max(map(len, piece)))),
            )
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError, pa.ArrowTypeError):
            return None
        return table if table.num_rows == len(piece) else None

    if parts == 1:
        return read(0)
    with ThreadPoolExecutor(parts - 1) as pool:
        rest = [pool.submit(read, i) for i in range(1, parts)]
        tables = [read(0), *(f.result() for f in rest)]
    return None if any(t is None for t in tables) else pa.concat_tables(tables)


def _column_floats(col: pa.ChunkedArray | pa.Array, scale: float = 1.0) -> np.ndarray:
    a = col.to_numpy() if isinstance(col, pa.ChunkedArray) else col.to_numpy(zero_copy_only=False)
    a = a.astype(float, copy=False)
    return a * scale if scale != 1.0 else a


def _floats(values: list[Any], scale: float = 1.0) -> np.ndarray:
    try:
        a = np.array(values, dtype=float)
    except (TypeError, ValueError):
        a = np.array(
            [v if isinstance(v, (int, float)) and not isinstance(v, bool) else None for v in values], dtype=float
        )
    return a * scale if scale != 1.0 else a


def read_mcap_file(data: bytes, limits: IngestLimits) -> Collected:
    """The records of one MCAP file; `Rejected`, in this order, for: no bytes, a Git LFS pointer, no
    MCAP magic, a top-level record beyond the file or `limits` (headers only, before anything is
    decompressed), damage met while reading the records."""
    check_log_bytes(data)
    if not data.startswith(MAGIC):
        raise Rejected("not an MCAP file: it does not start with the MCAP magic bytes")
    heads = top_records(data)  # walked once, for the limits and the reader
    check_mcap_records(data, limits, heads)
    return collect(data, heads)


def read_mcap_log(data: bytes, mapping: Mapping, limits: IngestLimits | None = None) -> RawLog:
    """Parse MCAP bytes into a `RawLog`; `Rejected` with a precise reason on bad input."""
    return read_collected(read_mcap_file(data, limits or IngestLimits()), mapping)


def read_collected(got: Collected, mapping: Mapping, warnings: list[str] | None = None) -> RawLog:
    """A `RawLog` from the records of one MCAP file (or of a split bag's parts), with `warnings` about them."""
    by_topic: dict[str, list[int]] = {}
    for cid, ch in got.channels.items():
        by_topic.setdefault(ch.topic, []).append(cid)
    meta, meta_warnings = _session_meta(got.metadata, mapping)
    warnings = list(warnings or []) + meta_warnings
    read_topics = {mapping.topic(t) for t in (TOPIC_EGO, TOPIC_TRAFFIC, TOPIC_CONTROLS, TOPIC_BUTTON)}
    if mapping.topic(TOPIC_EGO) not in by_topic:  # a stack's own layout: its reason should point at [mcap.signals]
        read_topics = set(by_topic)
    if mapping.mcap_signals is not None or any(
        got.channels[cid].message_encoding != "json" for t in read_topics for cid in by_topic.get(t, [])
    ):
        from ingest.mcap_decoding import read_decoded_mcap  # loads the ROS 2 / protobuf decoders only when needed

        return read_decoded_mcap(got, mapping, meta, warnings)

    def messages(canonical: str, required: bool) -> tuple[list[int], list[bytes]] | None:
        topic = mapping.topic(canonical)
        cids = by_topic.get(topic)
        if not cids:
            if not required:
                return None
            known = ", ".join(sorted(by_topic)) or "none"
            hint = f'"{canonical}" = "<your topic>" under [mcap.topics] {mapping.hint()}'
            looked = f" (looked for {topic})" if topic != canonical else ""
            raise Rejected(
                f"missing required topic {canonical}{looked}; topics in the file: {known}; map it with {hint}"
            )
        times: list[int] = []
        datas: list[bytes] = []
        for cid in cids:
            times += got.times.get(cid, [])
            datas += got.datas.get(cid, [])
        return times, datas

    ego_raw = messages(TOPIC_EGO, True)
    traffic_raw = messages(TOPIC_TRAFFIC, True)
    assert ego_raw is not None and traffic_raw is not None
    if not ego_raw[0]:
        raise Rejected(f"no messages on {mapping.topic(TOPIC_EGO)}: the log has no ego samples")

    ego_times = np.asarray(ego_raw[0], dtype=np.int64)
    order = np.argsort(ego_times, kind="stable")
    sorted_already = bool(np.all(order[1:] > order[:-1]))
    ego_times = ego_times[order]
    t0 = int(ego_times[0])
    t_s = (ego_times - t0) / NS_PER_S
    t_abs = ego_times / NS_PER_S

    f = lambda fld: mapping.msg_field(TOPIC_EGO, fld)  # noqa: E731
    ego_fields = (
        ("x", "ego_x_m", mapping.position_scale),
        ("y", "ego_y_m", mapping.position_scale),
        ("v", "ego_v_mps", mapping.speed_scale),
        ("lane", "ego_lane", 1.0),
        ("length", "ego_length_m", mapping.position_scale),
    )
    table = None
    columns = float_columns(ego_raw[1], [f(fld) for fld, _, _ in ego_fields])
    if columns is None and all("." not in f(fld) for fld, _, _ in ego_fields):
        table = _arrow_table(ego_raw[1], pa.schema([(f(fld), pa.float64()) for fld, _, _ in ego_fields]))
    ego_msgs = (
        None if columns is not None or table is not None else _decode(mapping.topic(TOPIC_EGO), ego_raw[1], ego_raw[0])
    )
    ego: dict[str, np.ndarray] = {}
    for fld, key, scale in ego_fields:
        if columns is not None:
            vals = columns[f(fld)] * scale if scale != 1.0 else columns[f(fld)]
        elif table is not None:
            vals = _column_floats(table.column(f(fld)), scale)
        else:
            assert ego_msgs is not None  # decoded above when neither the columns nor the table were
            get = _getter(f(fld))
            vals = _floats([get(m) if isinstance(m, dict) else None for m in ego_msgs], scale)
        if not sorted_already:
            vals = vals[order]
        if fld in ("x", "v", "lane") and np.isnan(vals).all():
            raise Rejected(
                f"field {f(fld)!r} is absent from every {mapping.topic(TOPIC_EGO)} message: "
                f'map it with {fld} = "<your field>" under [mcap.fields."{TOPIC_EGO}"] {mapping.hint()}'
            )
        ego[key] = vals
    ego["ego_length_m"] = np.where(np.isnan(ego["ego_length_m"]), DEFAULT_LENGTH_M, ego["ego_length_m"])

    _controls(ego, messages(TOPIC_CONTROLS, False), ego_times, mapping)
    button = messages(TOPIC_BUTTON, False)
    _button(ego, button, ego_times, mapping, warnings)
    traffic = _traffic(traffic_raw, t0, mapping)

    topic_ego = mapping.topic(TOPIC_EGO)
    return RawLog(
        format="mcap",
        meta=meta,
        t_abs_s=t_abs,
        t_s=t_s,
        ego=ego,
        traffic=traffic,
        locate=lambda i: f"message {i} of {topic_ego} (log_time {int(ego_times[i])} ns)",
        time_name=f"{topic_ego} log_time",
        names={
            "ego_x_m": f"{topic_ego}.{f('x')}",
            "ego_v_mps": f"{topic_ego}.{f('v')}",
            "ego_lane": f"{topic_ego}.{f('lane')}",
        },
        has_button=button is not None,
        warnings=warnings,
    )


def _session_meta(metadata: dict[str, dict[str, str]], mapping: Mapping) -> tuple[dict[str, Any], list[str]]:
    """The session keys of the file's Metadata record, and warnings about them."""
    meta_rec = metadata.get(mapping.metadata_name, {})
    meta: dict[str, Any] = {
        k: meta_rec.get(mapping.meta_key(k)) or None
        for k in ("driver_id", "session_id", "simulator", "speed_limit_kph")
    }
    warnings: list[str] = []
    if meta["speed_limit_kph"] is not None:
        try:
            meta["speed_limit_kph"] = float(meta["speed_limit_kph"])
        except ValueError:
            warnings.append(f"speed_limit_kph {meta['speed_limit_kph']!r} in the metadata is not a number; ignored")
            meta["speed_limit_kph"] = None
    return meta, warnings


def _decoded_in_time_order(raw: tuple[list[int], list[bytes]], topic: str) -> tuple[np.ndarray, np.ndarray, list]:
    """(log times, the stable order that sorts them, decoded messages) of one topic."""
    times = np.asarray(raw[0], dtype=np.int64)
    return times, np.argsort(times, kind="stable"), _decode(topic, raw[1], raw[0])


def _controls(
    ego: dict[str, np.ndarray], raw: tuple[list[int], list[bytes]] | None, ego_times: np.ndarray, mapping: Mapping
) -> None:
    n = len(ego_times)
    for key in ("steer_rad", "throttle", "brake"):
        ego[key] = np.full(n, np.nan)
    if raw is None or not raw[0]:
        return
    fields = (("steer", "steer_rad"), ("throttle", "throttle"), ("brake", "brake"))
    names = [mapping.msg_field(TOPIC_CONTROLS, fld) for fld, _ in fields]
    columns = float_columns(raw[1], names)
    if columns is None:
        times, order, msgs = _decoded_in_time_order(raw, mapping.topic(TOPIC_CONTROLS))
        columns = {n: _floats([_getter(n)(m) if isinstance(m, dict) else None for m in msgs]) for n in names}
    else:
        times = np.asarray(raw[0], dtype=np.int64)
        order = np.argsort(times, kind="stable")
    idx = asof(ego_times, times[order])
    valid = idx >= 0
    for name, (_, key) in zip(names, fields):
        ego[key][valid] = columns[name][order][idx[valid]]


def _button(
    ego: dict[str, np.ndarray],
    raw: tuple[list[int], list[bytes]] | None,
    ego_times: np.ndarray,
    mapping: Mapping,
    warnings: list[str] | None = None,
) -> None:
    """Button state on the ego samples (state of the last message), each press on >= 1 sample."""
    if raw is None or not raw[0]:
        n = len(ego_times)
        ego["lc_button"], ego["lc_direction"] = np.zeros(n, dtype=bool), np.full(n, None, dtype=object)
        return
    times, order, msgs = _decoded_in_time_order(raw, mapping.topic(TOPIC_BUTTON))
    get_p = _getter(mapping.msg_field(TOPIC_BUTTON, "pressed"))
    get_d = _getter(mapping.msg_field(TOPIC_BUTTON, "direction"))
    states = np.array([bool(get_p(msgs[i])) if isinstance(msgs[i], dict) else False for i in order], dtype=bool)
    dirs = [get_d(msgs[i]) if isinstance(msgs[i], dict) else None for i in order]
    ego["lc_button"], ego["lc_direction"] = place_presses(ego_times, times[order], states, dirs, warnings)


def _traffic_arrow(datas: list[bytes], names: dict[str, str], mapping: Mapping) -> dict[str, Any] | None:
    """Traffic columns via Arrow's JSON reader; None when the fast path does not apply."""
    fields = ("id", "x", "y", "v", "lane", "length")
    if any("." in n for n in names.values()) or len({names[k] for k in fields}) != len(fields):
        return None
    vehicle = pa.struct([(names["id"], pa.string())] + [(names[k], pa.float64()) for k in fields[1:]])
    table = _arrow_table(datas, pa.schema([(names["vehicles"], pa.list_(vehicle))]))
    if table is None:
        return None
    # chunk by chunk: combining the chunks of the list<struct> column first costs more than the columns
    chunks = table.column(names["vehicles"]).chunks
    flats = [c.flatten() for c in chunks]
    starts = np.cumsum([0] + [len(c) for c in chunks[:-1]])

    def floats(key: str, scale: float = 1.0) -> np.ndarray:
        return np.concatenate([_column_floats(f.field(names[key]), scale) for f in flats])

    return {
        "rows": np.concatenate(
            [
                pc.list_parent_indices(c).to_numpy(zero_copy_only=False).astype(np.int64) + s
                for c, s in zip(chunks, starts)
            ]
        ),
        "vehicle_id": pa.concat_arrays([f.field(names["id"]) for f in flats]),
        "x_m": floats("x", mapping.position_scale),
        "y_m": floats("y", mapping.position_scale),
        "v_mps": floats("v", mapping.speed_scale),
        "lane": floats("lane"),
        "length_m": floats("length", mapping.position_scale),
    }


def _traffic_python(
    topic: str, datas: list[bytes], times: list[int], names: dict[str, str], mapping: Mapping
) -> dict[str, Any]:
    """Traffic columns by msgspec (`jsondecode`) and a loop (any message shape the mapping can name)."""
    msgs = _decode(topic, datas, times)
    rows: list[int] = []
    ids: list[Any] = []
    xs: list[Any] = []
    ys: list[Any] = []
    vs: list[Any] = []
    lanes: list[Any] = []
    lengths: list[Any] = []
    gv, gid, gx, gy, gvv, gl, glen = (_getter(names[k]) for k in ("vehicles", "id", "x", "y", "v", "lane", "length"))
    for i, m in enumerate(msgs):
        vehicles = gv(m) if isinstance(m, dict) else None
        if not isinstance(vehicles, list):
            continue
        for veh in vehicles:
            if not isinstance(veh, dict):
                veh = {}
            rows.append(i)
            ids.append(gid(veh))
            xs.append(gx(veh))
            ys.append(gy(veh))
            vs.append(gvv(veh))
            lanes.append(gl(veh))
            lengths.append(glen(veh))
    return {
        "rows": np.asarray(rows, dtype=np.int64),
        "vehicle_id": id_array(ids),
        "x_m": _floats(xs, mapping.position_scale),
        "y_m": _floats(ys, mapping.position_scale),
        "v_mps": _floats(vs, mapping.speed_scale),
        "lane": _floats(lanes),
        "length_m": _floats(lengths, mapping.position_scale),
    }


def _traffic(raw: tuple[list[int], list[bytes]], t0: int, mapping: Mapping) -> dict[str, Any]:
    topic = mapping.topic(TOPIC_TRAFFIC)
    times, datas = raw
    names = {k: mapping.msg_field(TOPIC_TRAFFIC, k) for k in ("vehicles", "id", "x", "y", "v", "lane", "length")}
    cols = _traffic_arrow(datas, names, mapping) if datas else None
    if cols is None:
        cols = _traffic_python(topic, datas, times, names, mapping)
    row_idx = cols.pop("rows")
    t_msg = (np.asarray(times, dtype=np.int64) - t0) / NS_PER_S
    out: dict[str, Any] = {"t_s": t_msg[row_idx] if len(row_idx) else np.zeros(0), **cols}
    out["length_m"] = np.where(np.isnan(out["length_m"]), DEFAULT_LENGTH_M, out["length_m"])
    for key, name in (("vehicle_id", "id"), ("x_m", "x"), ("v_mps", "v"), ("lane", "lane")):
        bad = out[key].is_null().to_numpy(zero_copy_only=False) if key == "vehicle_id" else np.isnan(out[key])
        if np.any(bad):
            k = int(np.argmax(bad))
            raise Rejected(
                f"{topic}: a vehicle without {names[name]!r} in message {row_idx[k]} "
                f'(log_time {times[row_idx[k]]} ns); map the field under [mcap.fields."{TOPIC_TRAFFIC}"] '
                f"{mapping.hint()}"
            )
    if len(row_idx) and np.any(np.diff(out["t_s"]) < 0):
        order = np.argsort(out["t_s"], kind="stable")
        out = {k: (v.take(pa.array(order)) if isinstance(v, pa.Array) else v[order]) for k, v in out.items()}
    return out
