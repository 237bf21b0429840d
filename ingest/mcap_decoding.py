"""Read MCAP messages through the schemas the file carries (ROS 2 CDR, protobuf, JSON).

The decoders are the mcap library's decoder factories (`mcap_ros2.decoder.DecoderFactory`,
`mcap_protobuf.decoder.DecoderFactory`, and one for JSON), applied to the channels and
schemas that `mcap_reader` collected with mcap's own readers. ROS 2 CDR goes first
through rosbags' generated deserialisers (about twice as fast), with mcap_ros2 behind
them for anything they read differently (`FastRos2DecoderFactory`). Signals are then taken
from the decoded messages by the field paths of the mapping (`ingest/mcap_signals.py`).

Before a topic is decoded its channel must be consistent: `cdr` messages need a
`ros2msg` schema, `protobuf` messages a `protobuf` schema, `json` messages a
`jsonschema` schema or none. A mismatch, an unreadable schema or a message that does not
decode is refused with a reason naming the topic and the encoding.
"""

from __future__ import annotations

import array
import gc
import operator
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from mcap.decoder import DecoderFactory
from mcap.records import Channel, Schema
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory

from ingest.alignment import asof, place_presses
from ingest.logformat import DEFAULT_LENGTH_M, NS_PER_S
from ingest.jsondecode import loads
from ingest.mapping import Mapping
from ingest.mcap_signals import LOG_TIME, McapSignals, Signal, signals_from_v1
from ingest.object_ids import id_array
from ingest.rawlog import RawLog, Rejected, first_line

# message encoding -> schema encodings it can be decoded with
#: The first two bytes of a CDR message: its encapsulation (plain or parameter-list CDR, big or little endian).
CDR_HEADERS = (b"\x00\x00", b"\x00\x01", b"\x00\x02", b"\x00\x03")
SCHEMA_ENCODINGS: dict[str, tuple[str, ...]] = {
    "json": ("jsonschema", ""),
    "cdr": ("ros2msg",),
    "protobuf": ("protobuf",),
}
_MISSING = object()  # a path that does not exist in a message


class _Fallback(Exception):
    """A value of a message decoded by rosbags that mcap_ros2 would give in another form (an array,
    a message): the file is read again through mcap_ros2 alone."""


def _plain(values: list[Any]) -> list[Any]:
    """`values` when each is a scalar that both CDR decoders give alike (or absent); else `_Fallback`."""
    if not all(v is _MISSING or v is None or type(v) in (str, int, float, bool) for v in values):
        raise _Fallback
    return values


class FastRos2DecoderFactory(DecoderFactory):
    """ROS 2 CDR through rosbags' generated deserialisers (about twice as fast as mcap_ros2's), with
    mcap_ros2 behind them: a schema must load in mcap_ros2 (its refusal is the reason, as before), and a
    message rosbags cannot decode is decoded by mcap_ros2. `used` says whether rosbags decoded anything."""

    def __init__(self) -> None:
        self.slow = Ros2DecoderFactory()
        self.used = False

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Callable[[bytes], Any] | None:
        slow = self.slow.decoder_for(message_encoding, schema)
        if slow is None or schema is None:
            return slow
        try:
            from rosbags.typesys import Stores, get_types_from_msg, get_typestore
            from rosbags.typesys.msg import normalize_msgtype

            store = get_typestore(Stores.EMPTY)
            store.register(get_types_from_msg(schema.data.decode(), schema.name))
            typename = normalize_msgtype(schema.name)
            store.get_msgdef(typename)
        except Exception:  # noqa: BLE001 - a schema rosbags does not read: mcap_ros2 alone, as before
            return slow
        self.used = True
        fast = store.deserialize_cdr

        def decode(data: bytes) -> Any:
            try:
                return fast(data, typename)
            except Exception:  # noqa: BLE001 - mcap_ros2 decodes it or names what is wrong, as before
                return slow(data)

        decode.fast = True  # type: ignore[attr-defined]
        return decode


class JsonDecoderFactory(DecoderFactory):
    """JSON messages as dicts, so that JSON files can be read by `[mcap.signals]` too."""

    def decoder_for(self, message_encoding: str, schema: Schema | None) -> Callable[[bytes], Any] | None:
        return loads if message_encoding == "json" else None


@dataclass
class Decoded:
    """The messages of one topic, decoded, in time order."""

    topic: str
    times: np.ndarray  # [ns] message times (log_time or the stamp), sorted
    msgs: list[Any]
    type_name: str  # schema name, for messages
    hint: str  # where the mapping is, for reasons ("in the --mapping file (x.toml)")
    fast: bool = False  # decoded by rosbags: ids, button and direction values must be `_plain`

    def plain(self, values: list[Any]) -> list[Any]:
        return _plain(values) if self.fast else values


def _decoder(
    topic: str, channel: Channel, schema: Schema | None, factories: list[DecoderFactory]
) -> Callable[[bytes], Any]:
    """The decoder of a channel; `Rejected` when its encodings disagree or its schema is unreadable."""
    enc = channel.message_encoding
    if enc not in SCHEMA_ENCODINGS:
        raise Rejected(
            f"unsupported message encoding {enc!r} on topic {topic}: laneprint decodes json, "
            f"cdr (ROS 2, ros2msg schemas) and protobuf messages"
        )
    schema_enc = schema.encoding if schema is not None else ""
    if schema_enc not in SCHEMA_ENCODINGS[enc]:
        want = " or ".join(repr(s) for s in SCHEMA_ENCODINGS[enc] if s)
        has = f"schema encoding {schema_enc!r} ({schema.name})" if schema is not None else "no schema"
        raise Rejected(
            f"topic {topic}: message encoding {enc!r} does not match its {has}; {enc} messages "
            f"need a {want} schema (the recorder wrote an inconsistent channel)"
        )
    try:
        for factory in factories:
            decode = factory.decoder_for(enc, schema)
            if decode is not None:
                return decode
    except Exception as exc:
        assert schema is not None
        raise Rejected(
            f"topic {topic}: cannot read its {schema_enc} schema {schema.name!r} for {enc} messages ({first_line(exc)})"
        ) from None
    raise Rejected(f"topic {topic}: no decoder for message encoding {enc!r}")  # pragma: no cover


def _get(obj: Any, name: str) -> Any:
    """Field `name` of a decoded message (dict, ROS 2 message, protobuf message) or `_MISSING`."""
    if isinstance(obj, dict):
        return obj.get(name, _MISSING)
    return getattr(obj, name, _MISSING)


def _resolve(obj: Any, parts: list[str]) -> Any:
    for p in parts:
        obj = _get(obj, p)
        if obj is _MISSING:
            return _MISSING
    return obj


def _values(objs: list[Any], path: str) -> list[Any]:
    """The value at `path` in each object (`_MISSING` where there is none)."""
    if objs and not isinstance(objs[0], dict):  # typed messages: one C-level attribute walk per object
        try:
            return list(map(operator.attrgetter(path), objs))
        except AttributeError:
            pass
    parts = path.split(".")
    return [_resolve(o, parts) for o in objs]


def _field_names(obj: Any) -> list[str]:
    if isinstance(obj, dict):
        return [str(k) for k in obj]
    descriptor = getattr(obj, "DESCRIPTOR", None)
    if descriptor is not None and hasattr(descriptor, "fields"):
        return [f.name for f in descriptor.fields]
    return list(getattr(obj, "__slots__", []))


def _type_name(value: Any) -> str:
    descriptor = getattr(value, "DESCRIPTOR", None)
    if descriptor is not None and hasattr(descriptor, "full_name"):
        return f"a {descriptor.full_name} message"
    if hasattr(value, "_type"):
        return f"a {value._type} message"
    if isinstance(value, (Sequence, array.array)) and not isinstance(value, (str, bytes)):
        return "a list"
    return f"a {type(value).__name__}"


def _no_field(
    dec: Decoded, path: str, sample: Any, prefix: str = "", fix: str = "fix the path under [mcap.signals]"
) -> Rejected:
    """The reason for a path absent from every message: where it stops and what is there."""
    at = sample
    done: list[str] = []
    for p in path.split("."):
        nxt = _get(at, p)
        if nxt is _MISSING:
            break
        done.append(p)
        at = nxt
    where = ".".join(done)
    names = _field_names(at)
    if names:
        place = f"at {prefix}{where}" if where else f"of {prefix.rstrip('.') or 'the message'}"
        there = f"fields {place}: {', '.join(names)}"
    else:
        there = f"{prefix + where or 'the message'} is {_type_name(at)}"
    return Rejected(
        f"topic {dec.topic}: no field {prefix + path!r} in its {dec.type_name} messages ({there}); {fix} {dec.hint}"
    )


def _numbers(dec: Decoded, path: str, values: list[Any], scale: float = 1.0) -> np.ndarray:
    """Floats (NaN where absent); `Rejected` when the path holds something that is not a number."""
    try:
        out = np.array(values, dtype=float)
        if out.ndim != 1:  # a path to equal-length lists
            raise TypeError
    except (TypeError, ValueError):
        out = np.full(len(values), np.nan)
        for i, v in enumerate(values):
            if v is _MISSING or v is None:
                continue
            if not isinstance(v, (int, float, np.number)):
                raise Rejected(
                    f"topic {dec.topic}: field {path!r} holds {_type_name(v)}, not a number "
                    f"(message {i}); name a numeric field under [mcap.signals] {dec.hint}"
                ) from None
            out[i] = v
    return out * scale if scale != 1.0 else out


def _stamp_ns(value: Any) -> int | None:
    """A stamp in ns: builtin_interfaces/Time (sec, nanosec), google.protobuf.Timestamp
    (seconds, nanos), an integer (ns) or a float (s)."""
    if isinstance(value, (bool, np.bool_)):
        return None
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return round(float(value) * NS_PER_S)
    for s, n in (("sec", "nanosec"), ("seconds", "nanos")):
        sec, nsec = _get(value, s), _get(value, n)
        if isinstance(sec, int) and isinstance(nsec, int):
            return sec * NS_PER_S + nsec
    return None


def decode_topic(got: Any, topic: str, time_path: str, factories: list[DecoderFactory], hint: str) -> Decoded | None:
    """All messages of `topic` decoded and sorted by time; None when the file has no such topic."""
    cids = [cid for cid, ch in got.channels.items() if ch.topic == topic]
    if not cids:
        return None
    times: list[int] = []
    msgs: list[Any] = []
    type_name = ""
    fast = False
    for cid in cids:
        ch = got.channels[cid]
        schema = got.schemas.get(ch.schema_id) if ch.schema_id else None
        decode = _decoder(topic, ch, schema, factories)
        fast = fast or getattr(decode, "fast", False)
        type_name = type_name or (schema.name if schema is not None else ch.message_encoding)
        for i, (t, data) in enumerate(zip(got.times.get(cid, []), got.datas.get(cid, []))):
            if ch.message_encoding == "cdr" and data[:2] not in CDR_HEADERS:
                looks = " (it looks like JSON)" if data.lstrip()[:1] in (b"{", b"[") else ""
                raise Rejected(
                    f"message {i} on {topic} (log_time {t} ns) is declared cdr but does not start with a "
                    f"CDR header{looks}: declare the channel's message_encoding as what it holds"
                )
            try:
                msgs.append(decode(data))
            except Exception as exc:
                raise Rejected(
                    f"message {i} on {topic} (log_time {t} ns) does not decode as "
                    f"{ch.message_encoding} {type_name}: {first_line(exc)}"
                ) from None
            times.append(t)
    dec = Decoded(topic, np.asarray(times, dtype=np.int64), msgs, type_name, hint, fast)
    if time_path != LOG_TIME and msgs:
        parts = time_path.split(".")
        stamps = [_stamp_ns(v) for v in _values(msgs, time_path)]
        if None in stamps:
            i = stamps.index(None)
            if _resolve(msgs[i], parts) is _MISSING:
                raise _no_field(
                    dec,
                    time_path,
                    msgs[i],
                    fix="every topic read needs the stamp of time = "
                    f'{time_path!r}; else use time = "log_time" under [mcap.signals]',
                )
            raise Rejected(
                f"topic {topic}: time = {time_path!r} is not a stamp in message {i} (expected sec/nanosec, "
                f'seconds/nanos or a number); use time = "log_time" under [mcap.signals]'
            )
        dec.times = np.asarray(stamps, dtype=np.int64)
    order = np.argsort(dec.times, kind="stable")
    if np.any(order[1:] < order[:-1]):
        dec.times = dec.times[order]
        dec.msgs = [dec.msgs[i] for i in order]
    return dec


class _SignalReader:
    """Values of signals on the ego samples, from the decoded topics."""

    def __init__(self, decoded: dict[str, Decoded | None], base: Decoded) -> None:
        self.decoded = decoded
        self.base = base

    def raw(self, sig: Signal) -> tuple[Decoded, list[Any]] | None:
        """(topic, values per message in time order); None when the topic is not in the file."""
        dec = self.decoded[sig.topic]
        if dec is None:
            return None
        values = _values(dec.msgs, sig.path)
        if sig.explicit and values and all(v is _MISSING for v in values):
            raise _no_field(dec, sig.path, dec.msgs[0])
        return dec, values

    def on_samples(self, dec: Decoded, values: np.ndarray) -> np.ndarray:
        """Per-message values put on the ego samples (last value at or before each sample)."""
        if dec is self.base:
            return values
        idx = asof(self.base.times, dec.times)
        out = np.full(len(idx), np.nan)
        out[idx >= 0] = values[idx[idx >= 0]]
        return out

    def numbers(self, sig: Signal | None, scale: float = 1.0) -> np.ndarray:
        got = self.raw(sig) if sig is not None else None
        if sig is None or got is None:
            return np.full(len(self.base.times), np.nan)
        dec, values = got
        return self.on_samples(dec, _numbers(dec, sig.path, values, scale))


def _directions(values: list[Any], sig: Signal) -> np.ndarray:
    """Raw direction values as 'left'/'right' (through the mapping's `left`/`right` values)."""
    by_value = {v: k for k, v in sig.values.items()}
    out = np.full(len(values), None, dtype=object)
    for i, v in enumerate(values):
        if v is _MISSING or v is None:
            continue
        if by_value:
            out[i] = by_value.get(v)
        else:
            out[i] = v if isinstance(v, str) else str(v)
    return out


def _button(
    reader: _SignalReader, signals: McapSignals, warnings: list[str] | None = None
) -> tuple[np.ndarray, np.ndarray, bool]:
    """(lc_button, lc_direction) on the ego samples, and whether the file logs the button."""
    n = len(reader.base.times)
    btn = signals.ego.get("lc_button")
    got = reader.raw(btn) if btn is not None else None
    if got is None:
        return np.zeros(n, dtype=bool), np.full(n, None, dtype=object), False
    dec, values = got
    states = np.array([bool(v) if v is not _MISSING else False for v in dec.plain(values)], dtype=bool)
    dirs = np.full(len(values), None, dtype=object)
    dsig = signals.ego.get("lc_direction")
    dgot = reader.raw(dsig) if dsig is not None else None
    if dsig is not None and dgot is not None:
        ddec, dvalues = dgot
        raw_dirs = _directions(ddec.plain(dvalues), dsig)
        if ddec is dec:
            dirs = raw_dirs
        else:  # the direction at each button message: the last one published at or before it
            idx = asof(dec.times, ddec.times)
            dirs[idx >= 0] = raw_dirs[idx[idx >= 0]]
    pressed, direction = place_presses(reader.base.times, dec.times, states, list(dirs), warnings)
    return pressed, direction, True


def _ids(values: list[Any]) -> pa.Array:
    """Object ids as canonical text (`ingest.object_ids`: numbers, strings, bytes and UUIDs as hex)."""
    return id_array([None if v is _MISSING else v for v in values])


def _traffic(
    decoded: dict[str, Decoded | None], signals: McapSignals, t0: int, mapping: Mapping, known: str
) -> dict[str, Any]:
    ts = signals.traffic
    dec = decoded[ts.topic]
    if dec is None:
        raise Rejected(
            f"missing required topic {ts.topic} (traffic); topics in the file: {known}; "
            f'name it with topic = "<your topic>" under [mcap.signals.traffic] {mapping.hint()}'
        )
    lists = _values(dec.msgs, ts.list)
    if ts.explicit and lists and all(v is _MISSING for v in lists):
        raise _no_field(dec, ts.list, dec.msgs[0], fix="fix list under [mcap.signals.traffic]")
    rows: list[int] = []
    objs: list[Any] = []
    for i, objects in enumerate(lists):
        if objects is _MISSING or objects is None:
            continue
        if isinstance(objects, (str, bytes, dict)) or not isinstance(objects, (Sequence, array.array)):
            raise Rejected(
                f"topic {ts.topic}: list = {ts.list!r} holds {_type_name(objects)}, not a list of "
                f"objects (message {i}); fix it under [mcap.signals.traffic] {mapping.hint()}"
            )
        rows.extend([i] * len(objects))
        objs.extend(objects)
    values: dict[str, list[Any]] = {}
    for key in ("id", "x", "y", "v", "lane", "length"):
        path = ts.fields.get(key)
        values[key] = [_MISSING] * len(objs) if path is None else _values(objs, path)
        if path is not None and objs and ts.explicit and all(v is _MISSING for v in values[key]):
            raise _no_field(dec, path, objs[0], prefix=f"{ts.list}[].", fix="fix the path under [mcap.signals.traffic]")
    row_idx = np.asarray(rows, dtype=np.int64)
    num = lambda key, scale=1.0: _numbers(dec, f"{ts.list}[].{ts.fields.get(key, key)}", values[key], scale)  # noqa: E731
    out: dict[str, Any] = {
        "t_s": (dec.times[row_idx] - t0) / NS_PER_S if len(row_idx) else np.zeros(0),
        "vehicle_id": _ids(dec.plain(values["id"])),
        "x_m": num("x", mapping.position_scale),
        "y_m": num("y", mapping.position_scale),
        "v_mps": num("v", mapping.speed_scale),
        "lane": num("lane"),
        "length_m": num("length", mapping.position_scale),
    }
    out["length_m"] = np.where(np.isnan(out["length_m"]), DEFAULT_LENGTH_M, out["length_m"])
    if "lane" not in ts.fields:
        tracks = pc.dictionary_encode(out["vehicle_id"]).indices.to_numpy(zero_copy_only=False)
        assert signals.lane_from_y is not None  # mcap_signals requires it when the lane is not mapped
        out["lane"] = signals.lane_from_y.lanes(out["y_m"], tracks)
    for key, name in (("vehicle_id", "id"), ("x_m", "x"), ("v_mps", "v"), ("lane", "lane")):
        bad = out[key].is_null().to_numpy(zero_copy_only=False) if key == "vehicle_id" else np.isnan(out[key])
        if np.any(bad):
            k = int(np.argmax(bad))
            field = ts.fields.get(name) or ts.fields.get("y", name)  # lanes from y: y is missing
            raise Rejected(
                f"topic {ts.topic}: an object without {field!r} in message {row_idx[k]} "
                f"(time {dec.times[row_idx[k]]} ns); fix {name} under [mcap.signals.traffic] "
                f"{mapping.hint()}"
            )
    return out


def read_decoded_mcap(got: Any, mapping: Mapping, meta: dict[str, Any], warnings: list[str]) -> RawLog:
    """A `RawLog` from the collected records of an MCAP file, decoding through its schemas.

    `got` holds `channels`, `schemas`, `times` and `datas` by channel id (see
    `mcap_records.Collected`); `meta` and `warnings` come from its session metadata.
    ROS 2 messages are decoded by rosbags; when that read ends in a refusal or meets a
    value that mcap_ros2 gives in another form, the file is read again through mcap_ros2
    alone, so samples, ids and reasons are those of mcap_ros2's decoder.
    """
    fast = FastRos2DecoderFactory()
    with gc_paused():
        try:
            return _read_decoded(got, mapping, meta, list(warnings), fast)
        except (Rejected, _Fallback):
            if not fast.used:
                raise
        return _read_decoded(got, mapping, meta, warnings, Ros2DecoderFactory())


@contextmanager
def gc_paused() -> Iterator[None]:
    """Python's cyclic garbage collector paused while the block runs (as it was before, after).

    Decoding builds millions of small message objects, none of them in a cycle; each
    700 new objects the collector would walk the young ones, and ever more often the
    old: on the benchmark's ROS 2 bag that walking was two thirds of the read (8 -> 2.5
    CPU-s without it). Nothing the block creates needs it: the objects are freed by
    their reference counts when the block's result no longer holds them.
    """
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _read_decoded(
    got: Any, mapping: Mapping, meta: dict[str, Any], warnings: list[str], ros2: DecoderFactory
) -> RawLog:
    signals = mapping.mcap_signals or signals_from_v1(mapping.topic, mapping.msg_field)
    factories: list[DecoderFactory] = [ros2, ProtobufDecoderFactory(), JsonDecoderFactory()]
    decoded = {t: decode_topic(got, t, signals.time, factories, mapping.hint()) for t in signals.topics()}
    known = ", ".join(sorted({ch.topic for ch in got.channels.values()})) or "none"
    for name in ("ego_x", "ego_v", "ego_lane"):
        sig = signals.ego.get(name, signals.ego.get("ego_y"))  # ego_lane may come from ego_y (lane_from_y)
        assert sig is not None  # mcap_signals requires ego_x, ego_v and ego_lane or ego_y
        if decoded[sig.topic] is None:
            raise Rejected(
                f"missing required topic {sig.topic} ({name}); topics in the file: {known}; name it with "
                f'{name} = {{ topic = "<your topic>", path = "..." }} under [mcap.signals] {mapping.hint()}'
            )
    base = decoded[signals.ego["ego_x"].topic]
    assert base is not None
    if not len(base.times):
        raise Rejected(f"no messages on {base.topic}: the log has no ego samples")
    for name, sig in signals.ego.items():
        if sig.explicit and decoded[sig.topic] is None and name != "lc_button":
            warnings.append(f"topic {sig.topic} ({name}) is not in the file; {name} not logged")
    reader = _SignalReader(decoded, base)
    p, v = mapping.position_scale, mapping.speed_scale
    ego = {
        key: reader.numbers(signals.ego.get(name), scale)
        for key, name, scale in (
            ("ego_x_m", "ego_x", p),
            ("ego_y_m", "ego_y", p),
            ("ego_v_mps", "ego_v", v),
            ("ego_lane", "ego_lane", 1.0),
            ("ego_length_m", "ego_length", p),
            ("steer_rad", "steer", 1.0),
            ("throttle", "throttle", 1.0),
            ("brake", "brake", 1.0),
        )
    }
    ego["ego_length_m"] = np.where(np.isnan(ego["ego_length_m"]), DEFAULT_LENGTH_M, ego["ego_length_m"])
    if "ego_lane" not in signals.ego:
        assert signals.lane_from_y is not None  # mcap_signals requires it when ego_lane is not mapped
        ego["ego_lane"] = signals.lane_from_y.lanes(ego["ego_y_m"])
    ego["lc_button"], ego["lc_direction"], has_button = _button(reader, signals, warnings)
    t0 = int(base.times[0])
    clock = "log_time" if signals.time == LOG_TIME else signals.time
    where = {
        k: f"{signals.ego[n].topic}.{signals.ego[n].path}"
        for k, n in (("ego_x_m", "ego_x"), ("ego_v_mps", "ego_v"), ("ego_lane", "ego_lane"))
        if n in signals.ego
    }
    if "ego_lane" not in signals.ego:
        where["ego_lane"] = f"lane_from_y of {signals.ego['ego_y'].topic}.{signals.ego['ego_y'].path}"
    return RawLog(
        format="mcap",
        meta=meta,
        t_abs_s=base.times / NS_PER_S,
        t_s=(base.times - t0) / NS_PER_S,
        ego=ego,
        traffic=_traffic(decoded, signals, t0, mapping, known),
        locate=lambda i: f"message {i} of {base.topic} ({clock} {int(base.times[i])} ns)",
        time_name=f"{base.topic} {clock}",
        names=where,
        has_button=has_button,
        warnings=warnings,
    )
