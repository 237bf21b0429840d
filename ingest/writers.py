"""Write a recording (canonical EGO + long-form TRAFFIC frames) as a log of format v1.

`write_csv` writes the wide CSV (gzip-compressed when the path ends in `.csv.gz`),
`write_mcap` the MCAP file (JSON messages, jsonschema schemas, zstd chunks, index
and summary, a `session` Metadata record). Both take the frames of
`laneprint.schemas.EGO` / `TRAFFIC` and a metadata dict with `driver_id`,
`session_id`, `speed_limit_kph`, `simulator` (values may be None, then left out).

Floats are rounded to the millimetre (positions, lengths) and mm/s (speeds), times
to the microsecond in CSV and the nanosecond in MCAP; inputs (steer, throttle,
brake) to 1e-4. Files are written under a temporary name and renamed into place, so
an interrupted write never leaves half a log behind.

Size guide: a CSV row carries 5 cells per traffic vehicle *ever seen* in the
recording (empty while it is absent), so long recordings with many vehicles are
best written as `.csv.gz`.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pacsv
from mcap.writer import CompressionType, Writer

from ingest.logformat import (
    CSV_TIME,
    DEFAULT_LENGTH_M,
    METADATA_NAME,
    NS_PER_S,
    TOPIC_BUTTON,
    TOPIC_CONTROLS,
    TOPIC_EGO,
    TOPIC_TRAFFIC,
)

_POS_DECIMALS = 3  # mm, mm/s
_INPUT_DECIMALS = 4
_TIME_DECIMALS = 6  # us (CSV)
_META_KEYS = ("driver_id", "session_id", "speed_limit_kph", "simulator")
_UNSAFE_CSV_CHARS = (",", '"', "\n", "\r")


# --- shared helpers -----------------------------------------------------------


def _present(value: Any) -> bool:
    if value is None:
        return False
    try:
        return not bool(pd.isna(value))
    except (TypeError, ValueError):
        return True


def _meta_items(meta: dict[str, Any]) -> list[tuple[str, Any]]:
    return [(k, meta.get(k)) for k in _META_KEYS if _present(meta.get(k))]


def _has_values(df: pd.DataFrame, col: str) -> bool:
    return col in df.columns and bool(df[col].notna().any())


def _floats(df: pd.DataFrame, col: str, decimals: int) -> np.ndarray:
    return np.round(pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float, na_value=np.nan), decimals)


def _button(ego: pd.DataFrame) -> np.ndarray:
    if "lc_button" not in ego.columns:
        return np.zeros(len(ego), dtype=bool)
    return ego["lc_button"].fillna(False).to_numpy(dtype=bool)


def _directions(ego: pd.DataFrame) -> list[Any]:
    if "lc_direction" not in ego.columns:
        return [None] * len(ego)
    return [d if _present(d) else None for d in ego["lc_direction"].tolist()]


def _traffic_rows(t: np.ndarray, traffic: pd.DataFrame) -> np.ndarray:
    """Index of the ego sample each traffic row belongs to (same clock, nearest sample)."""
    tt = traffic["t_s"].to_numpy(dtype=float)
    if len(t) == 0:
        return np.zeros(len(tt), dtype=np.int64)
    idx = np.clip(np.searchsorted(t, tt), 0, len(t) - 1)
    prev = np.clip(idx - 1, 0, len(t) - 1)
    idx = np.where(np.abs(t[prev] - tt) < np.abs(t[idx] - tt), prev, idx)
    off = np.abs(t[idx] - tt)
    if len(off) and off.max() > 1e-6:
        bad = int(np.argmax(off))
        raise ValueError(f"traffic row at t_s={tt[bad]:.6f} has no ego sample at the same time")
    return idx


def _tmp_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def _replace_into(tmp: Path, path: Path) -> None:
    try:
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


# --- CSV -------------------------------------------------------------------------


def _wide_traffic(t: np.ndarray, traffic: pd.DataFrame) -> list[tuple[str, pa.Array]]:
    """Long-form traffic -> `<id>_x/_v/_lane/_y/_length` columns, empty where absent."""
    n = len(t)
    if traffic.empty:
        return []
    rows = _traffic_rows(t, traffic)
    codes, ids = pd.factorize(traffic["vehicle_id"].astype(str), sort=False)
    if len(np.unique(rows * len(ids) + codes)) != len(rows):
        raise ValueError("traffic has a vehicle twice at the same time")
    for vid in ids:
        if vid == "ego" or any(c in vid for c in _UNSAFE_CSV_CHARS):
            raise ValueError(f"vehicle id {vid!r} cannot be a CSV column prefix")
    k = len(ids)

    def grid(values: np.ndarray) -> np.ndarray:
        g = np.full((n, k), np.nan)
        g[rows, codes] = values
        return g

    x = grid(_floats(traffic, "x_m", _POS_DECIMALS))
    v = grid(_floats(traffic, "v_mps", _POS_DECIMALS))
    lane = grid(pd.to_numeric(traffic["lane"]).to_numpy(dtype=float))
    has_y = _has_values(traffic, "y_m")
    y = grid(_floats(traffic, "y_m", _POS_DECIMALS)) if has_y else None
    length = grid(_floats(traffic, "length_m", _POS_DECIMALS)) if "length_m" in traffic else None
    out: list[tuple[str, pa.Array]] = []
    for j, vid in enumerate(ids):
        absent = np.isnan(x[:, j])
        out.append((f"{vid}_x", pa.array(x[:, j], mask=absent)))
        out.append((f"{vid}_v", pa.array(v[:, j], mask=np.isnan(v[:, j]))))
        lane_j = np.nan_to_num(lane[:, j], nan=0).astype(np.int16)
        out.append((f"{vid}_lane", pa.array(lane_j, mask=np.isnan(lane[:, j]))))
        if y is not None and not np.isnan(y[:, j]).all():
            out.append((f"{vid}_y", pa.array(y[:, j], mask=np.isnan(y[:, j]))))
        if length is not None:
            out.append((f"{vid}_length", pa.array(length[:, j], mask=np.isnan(length[:, j]))))
    return out


def csv_table(meta: dict[str, Any], ego: pd.DataFrame, traffic: pd.DataFrame) -> pa.Table:
    """The wide CSV as an Arrow table (column names are the CSV header)."""
    n = len(ego)
    t = np.round(ego["t_s"].to_numpy(dtype=float), _TIME_DECIMALS)
    cols: list[tuple[str, pa.Array]] = [(CSV_TIME, pa.array(t))]
    for key, value in _meta_items(meta):
        if key == "speed_limit_kph":
            cols.append((key, pa.array(np.full(n, float(value)))))
        else:
            cols.append((key, pa.array(np.full(n, str(value), dtype=object), type=pa.string())))

    def num(name: str, col: str, decimals: int) -> None:
        a = _floats(ego, col, decimals)
        cols.append((name, pa.array(a, mask=np.isnan(a))))

    num("ego_x", "ego_x_m", _POS_DECIMALS)
    num("ego_v", "ego_v_mps", _POS_DECIMALS)
    cols.append(("ego_lane", pa.array(pd.to_numeric(ego["ego_lane"]).to_numpy(dtype=np.int16))))
    if _has_values(ego, "ego_y_m"):
        num("ego_y", "ego_y_m", _POS_DECIMALS)
    if _has_values(ego, "ego_length_m"):
        num("ego_length", "ego_length_m", _POS_DECIMALS)
    for name, col in (("steer", "steer_rad"), ("throttle", "throttle"), ("brake", "brake")):
        if _has_values(ego, col):
            num(name, col, _INPUT_DECIMALS)
    cols.append(("lc_button", pa.array(_button(ego).astype(np.int8))))
    dirs = _directions(ego)
    if any(d is not None for d in dirs):
        cols.append(("lc_direction", pa.array(dirs, type=pa.string())))
    cols.extend(_wide_traffic(t, traffic))
    return pa.table(dict(cols))


def _strings(table: pa.Table) -> Iterable[str]:
    for fld, col in zip(table.schema, table.columns):
        if pa.types.is_string(fld.type):
            yield from (s for s in col.unique().to_pylist() if s is not None)


def write_csv(path: Path, meta: dict[str, Any], ego: pd.DataFrame, traffic: pd.DataFrame) -> None:
    """Write one recording as a wide CSV log (gzip when `path` ends in `.csv.gz`)."""
    path = Path(path)
    table = csv_table(meta, ego, traffic)
    unsafe = any(c in s for s in _strings(table) for c in _UNSAFE_CSV_CHARS)
    opts = pacsv.WriteOptions(include_header=False, quoting_style="needed" if unsafe else "none")
    header = (",".join(table.column_names) + "\n").encode()
    tmp = _tmp_path(path)
    gz = path.name.endswith(".gz")
    try:
        with pa.CompressedOutputStream(str(tmp), "gzip") if gz else pa.OSFile(str(tmp), "wb") as out:
            out.write(header)
            pacsv.write_csv(table, out, opts)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _replace_into(tmp, path)


# --- MCAP ------------------------------------------------------------------------

_NUM = {"type": "number"}
_SCHEMAS = {
    TOPIC_EGO: (
        "laneprint.EgoState",
        {
            "type": "object",
            "properties": {"x": _NUM, "y": _NUM, "v": _NUM, "lane": {"type": "integer"}, "length": _NUM},
            "required": ["x", "v", "lane"],
        },
    ),
    TOPIC_TRAFFIC: (
        "laneprint.TrafficVehicles",
        {
            "type": "object",
            "properties": {
                "vehicles": {
                    "type": "array",
                    "items": {
                        "type": "object",
                        "properties": {
                            "id": {"type": "string"},
                            "x": _NUM,
                            "y": _NUM,
                            "v": _NUM,
                            "lane": {"type": "integer"},
                            "length": _NUM,
                        },
                        "required": ["id", "x", "v", "lane"],
                    },
                }
            },
            "required": ["vehicles"],
        },
    ),
    TOPIC_CONTROLS: (
        "laneprint.DriverControls",
        {
            "type": "object",
            "properties": {"steer": _NUM, "throttle": _NUM, "brake": _NUM},
        },
    ),
    TOPIC_BUTTON: (
        "laneprint.LaneChangeButton",
        {
            "type": "object",
            "properties": {"pressed": {"type": "boolean"}, "direction": {"enum": ["left", "right"]}},
            "required": ["pressed"],
        },
    ),
}


def _pylist(a: np.ndarray) -> list[Any]:
    """Floats as a Python list with NaN -> None."""
    out = a.tolist()
    if np.isnan(a).any():
        out = [None if v != v else v for v in out]
    return out


def _dumps(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":")).encode()


def _ego_messages(ego: pd.DataFrame) -> list[bytes]:
    x = _floats(ego, "ego_x_m", _POS_DECIMALS).tolist()
    v = _floats(ego, "ego_v_mps", _POS_DECIMALS).tolist()
    lane = pd.to_numeric(ego["ego_lane"]).to_numpy(dtype=np.int64).tolist()
    y = _pylist(_floats(ego, "ego_y_m", _POS_DECIMALS)) if "ego_y_m" in ego else [None] * len(ego)
    length = _pylist(_floats(ego, "ego_length_m", _POS_DECIMALS)) if "ego_length_m" in ego else [None] * len(ego)
    out = []
    for xi, yi, vi, li, ln in zip(x, y, v, lane, length):
        msg: dict[str, Any] = {"x": xi, "v": vi, "lane": li}
        if yi is not None:
            msg["y"] = yi
        if ln is not None:
            msg["length"] = ln
        out.append(_dumps(msg))
    return out


def _traffic_messages(t: np.ndarray, traffic: pd.DataFrame) -> list[bytes]:
    n = len(t)
    if traffic.empty:
        return [b'{"vehicles":[]}'] * n
    rows = _traffic_rows(t, traffic)
    order = np.argsort(rows, kind="stable")
    bounds = np.searchsorted(rows[order], np.arange(n + 1))
    tr = traffic.iloc[order]
    ids = tr["vehicle_id"].astype(str).tolist()
    x = _floats(tr, "x_m", _POS_DECIMALS).tolist()
    v = _floats(tr, "v_mps", _POS_DECIMALS).tolist()
    lane = pd.to_numeric(tr["lane"]).to_numpy(dtype=np.int64).tolist()
    y = _pylist(_floats(tr, "y_m", _POS_DECIMALS)) if "y_m" in tr else [None] * len(tr)
    length = _pylist(_floats(tr, "length_m", _POS_DECIMALS)) if "length_m" in tr else [None] * len(tr)
    vehicles = []
    for j in range(len(tr)):
        d: dict[str, Any] = {"id": ids[j], "x": x[j], "v": v[j], "lane": lane[j]}
        if y[j] is not None:
            d["y"] = y[j]
        if length[j] is not None:
            d["length"] = length[j]
        vehicles.append(d)
    return [_dumps({"vehicles": vehicles[bounds[i] : bounds[i + 1]]}) for i in range(n)]


def _control_messages(ego: pd.DataFrame) -> list[bytes] | None:
    fields = [
        (k, c) for k, c in (("steer", "steer_rad"), ("throttle", "throttle"), ("brake", "brake")) if _has_values(ego, c)
    ]
    if not fields:
        return None
    cols = [(k, _pylist(_floats(ego, c, _INPUT_DECIMALS))) for k, c in fields]
    out = []
    for i in range(len(ego)):
        out.append(_dumps({k: vals[i] for k, vals in cols if vals[i] is not None}))
    return out


def _button_messages(ego: pd.DataFrame) -> dict[int, bytes]:
    """Sample index -> button message, at the first sample and on every change of state."""
    pressed = _button(ego)
    if len(pressed) == 0:
        return {}
    dirs = _directions(ego)
    changes = np.flatnonzero(np.diff(pressed.astype(np.int8)) != 0) + 1
    starts = [0] + changes.tolist()
    ends = changes.tolist() + [len(pressed)]
    out = {}
    for s, e in zip(starts, ends):
        msg: dict[str, Any] = {"pressed": bool(pressed[s])}
        if pressed[s]:
            d = next((d for d in dirs[s:e] if d is not None), None)
            if d is not None:
                msg["direction"] = str(d)
        out[s] = _dumps(msg)
    return out


@dataclass(frozen=True)
class ExtraChannel:
    """A channel written beside the v1 topics (readers of the format ignore it): JSON messages
    with a jsonschema schema, each stamped with its log time [ns]."""

    topic: str
    schema_name: str
    schema: dict[str, Any]
    log_times_ns: list[int] = field(default_factory=list)
    messages: list[bytes] = field(default_factory=list)


class _ExtraQueue:
    """The extra channels' messages in log-time order, written as the samples' clock passes them."""

    def __init__(self, writer: Writer, items: list[tuple[int, int, int, bytes]]) -> None:
        self.writer, self.items, self.next = writer, items, 0

    def write_until(self, ts: int | None) -> None:
        """Write every message stamped before `ts` (all that remain when `ts` is None)."""
        while self.next < len(self.items) and (ts is None or self.items[self.next][0] < ts):
            t, cid, seq, data = self.items[self.next]
            self.writer.add_message(cid, log_time=t, data=data, publish_time=t, sequence=seq)
            self.next += 1


def _extra_queue(w: Writer, extra: Sequence[ExtraChannel]) -> _ExtraQueue:
    items = []
    for ch in extra:
        sid = w.register_schema(name=ch.schema_name, encoding="jsonschema", data=json.dumps(ch.schema).encode())
        cid = w.register_channel(topic=ch.topic, message_encoding="json", schema_id=sid)
        items += [(int(t), cid, seq, data) for seq, (t, data) in enumerate(zip(ch.log_times_ns, ch.messages))]
    items.sort(key=lambda it: it[0])
    return _ExtraQueue(w, items)


def write_mcap(
    path: Path,
    meta: dict[str, Any],
    ego: pd.DataFrame,
    traffic: pd.DataFrame,
    extra: Sequence[ExtraChannel] = (),
    extra_metadata: dict[str, dict[str, str]] | None = None,
) -> None:
    """Write one recording as an MCAP log (chunked, zstd, indexed, with summary).

    `extra` channels are interleaved with the samples in log-time order;
    `extra_metadata` adds Metadata records (name -> string map) beside `session`.
    """
    path = Path(path)
    for ch in extra:
        if ch.topic in _SCHEMAS or len(ch.log_times_ns) != len(ch.messages):
            raise ValueError(f"extra channel {ch.topic}: a v1 topic, or times and messages differ in number")
    t = ego["t_s"].to_numpy(dtype=float)
    stamps = np.round(t * NS_PER_S).astype(np.int64).tolist()
    ego_msgs = _ego_messages(ego)
    traffic_msgs = _traffic_messages(t, traffic)
    control_msgs = _control_messages(ego)
    button_msgs = _button_messages(ego)

    tmp = _tmp_path(path)
    try:
        with open(tmp, "wb") as fh:
            w = Writer(fh, compression=CompressionType.ZSTD)
            w.start(profile="", library="laneprint")
            channels = {}
            topics = [TOPIC_EGO, TOPIC_TRAFFIC] + ([TOPIC_CONTROLS] if control_msgs else []) + [TOPIC_BUTTON]
            for topic in topics:
                name, schema = _SCHEMAS[topic]
                sid = w.register_schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode())
                channels[topic] = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
            w.add_metadata(
                METADATA_NAME,
                {
                    k: (str(int(v)) if k == "speed_limit_kph" and float(v).is_integer() else str(v))
                    for k, v in _meta_items(meta)
                },
            )
            for name, values in (extra_metadata or {}).items():
                w.add_metadata(name, values)
            pending = _extra_queue(w, extra)
            ce, ct, cb = channels[TOPIC_EGO], channels[TOPIC_TRAFFIC], channels[TOPIC_BUTTON]
            cc = channels.get(TOPIC_CONTROLS)
            for i, ts in enumerate(stamps):
                pending.write_until(ts)
                w.add_message(ce, log_time=ts, data=ego_msgs[i], publish_time=ts, sequence=i)
                w.add_message(ct, log_time=ts, data=traffic_msgs[i], publish_time=ts, sequence=i)
                if control_msgs is not None and cc is not None:  # cc is registered whenever there are controls
                    w.add_message(cc, log_time=ts, data=control_msgs[i], publish_time=ts, sequence=i)
                if i in button_msgs:
                    w.add_message(cb, log_time=ts, data=button_msgs[i], publish_time=ts)
            pending.write_until(None)
            w.finish()
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _replace_into(tmp, path)


__all__ = ["write_csv", "write_mcap", "csv_table", "ExtraChannel", "DEFAULT_LENGTH_M"]
