"""`[mcap.signals]` in a mapping file: per canonical signal, the topic and the field path.

For MCAP files whose messages are not the v1 JSON shape (ROS 2 CDR, protobuf, or
JSON of another layout), each signal is named where it lives:

    [mcap.signals]
    time = "log_time"            # or a stamp path present in every message read, e.g. "header.stamp"
    ego_x = { topic = "/odom", path = "pose.pose.position.x" }
    ego_v = { topic = "/odom", path = "twist.twist.linear.x" }
    ego_lane = { topic = "/ego/lane", path = "data" }
    lc_button = { topic = "/hmi/lane_change", path = "data" }
    lc_direction = { topic = "/hmi/lane_change_dir", path = "data", left = 1, right = -1 }

    [mcap.signals.traffic]       # one message holds a list of objects
    topic = "/perception/objects"
    list = "objects"             # the list inside each message
    id = "id"                    # paths inside one object
    x = "position.x"
    v = "speed"
    lane = "lane"

Paths are field names joined by dots. The ego samples are the messages of the
`ego_x` topic; signals on other topics take their last value at or before each sample.
A stack that logs no lanes can give `lane_from_y = { width_m = 3.5, lane0_y_m = 0.0 }`
instead of `ego_lane` / the traffic `lane` (then `ego_y` / the traffic `y` are needed);
a sample exactly on a lane border keeps the lane it was in (`LaneFromY`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ingest.logformat import TOPIC_BUTTON, TOPIC_CONTROLS, TOPIC_EGO, TOPIC_TRAFFIC
from laneprint.errors import UserError

LOG_TIME = "log_time"
EGO_REQUIRED = ("ego_x", "ego_v", "ego_lane")
EGO_OPTIONAL = ("ego_y", "ego_length", "steer", "throttle", "brake", "lc_button", "lc_direction")
TRAFFIC_REQUIRED = ("topic", "list", "id", "x", "v", "lane")
TRAFFIC_OPTIONAL = ("y", "length")


@dataclass(frozen=True)
class Signal:
    """One signal: the topic it is on and the field path inside each message."""

    topic: str
    path: str
    values: dict[str, Any] = field(default_factory=dict)  # lc_direction only: "left"/"right" -> raw value
    explicit: bool = True  # named by the user (a path absent from every message is then an error)


@dataclass(frozen=True)
class TrafficSignals:
    """Traffic from one topic whose messages hold a list of objects."""

    topic: str
    list: str  # path of the list inside a message
    fields: dict[str, str]  # id, x, v, lane (+ y, length) -> path inside one object
    explicit: bool = True


BORDER_TOL = 1e-9  # [lane widths] a sample this close to the middle between two lane centres is on the border


@dataclass(frozen=True)
class LaneFromY:
    """Lane indices from the lateral position, for stacks that log no lane.

    Each sample is in the lane whose centre is nearest, (y - lane0_y_m) / width_m rounded.
    A sample exactly on the border between two lanes keeps the lane of the track's
    previous sample (hysteresis: a vehicle changes lane once it has crossed the border),
    or, at the start of a track, takes the lane of its next sample off the border; a
    track that never leaves the border is in the lower (right) lane of the two.
    """

    width_m: float  # [m] lane width
    lane0_y_m: float = 0.0  # [m] y of the centre of lane 0 (the rightmost)

    def lanes(self, y_m: np.ndarray, tracks: np.ndarray | None = None) -> np.ndarray:
        """Lane of each sample (NaN where y is); `tracks` (one code per sample, samples in time
        order within a track) says which samples follow each other: one track when None."""
        r = (np.asarray(y_m, dtype=float) - self.lane0_y_m) / self.width_m
        lanes = np.round(r)
        low = np.floor(r)
        border = np.abs(r - low - 0.5) <= BORDER_TOL
        if not border.any():
            return lanes
        order = np.arange(len(r)) if tracks is None else np.argsort(tracks, kind="stable")
        codes = np.zeros(len(r), dtype=np.int64) if tracks is None else np.asarray(tracks)[order]
        ref = _neighbour_lanes(lanes[order], border[order], codes)
        lanes[order[border[order]]] = np.clip(ref, low[order], low[order] + 1)[border[order]]
        return lanes


def _neighbour_lanes(lanes: np.ndarray, border: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """For each sample, the lane of the last sample off the border before it on its track, else
    of the first one after it, else -inf (clipped to the lower lane by the caller)."""
    n = len(lanes)
    known = ~border & ~np.isnan(lanes)
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(known, idx, -1))
    nxt = np.minimum.accumulate(np.where(known, idx, n)[::-1])[::-1]
    ok_prev = (prev >= 0) & (codes[np.clip(prev, 0, n - 1)] == codes)
    ok_next = (nxt < n) & (codes[np.clip(nxt, 0, n - 1)] == codes)
    return np.where(ok_prev, lanes[np.clip(prev, 0, n - 1)], np.where(ok_next, lanes[np.clip(nxt, 0, n - 1)], -np.inf))


@dataclass(frozen=True)
class McapSignals:
    """Where every canonical signal is in a schema-decoded MCAP file."""

    ego: dict[str, Signal]  # canonical ego signal (ego_x, ego_v, ...) -> where it is
    traffic: TrafficSignals
    time: str = LOG_TIME  # "log_time" or the path of a stamp in every message read
    lane_from_y: LaneFromY | None = None  # derive ego / traffic lanes that are not mapped from y

    def topics(self) -> list[str]:
        """Every topic read, each once, ego sample topic first."""
        seen = [self.ego["ego_x"].topic] + [s.topic for s in self.ego.values()] + [self.traffic.topic]
        return list(dict.fromkeys(seen))


def _check_keys(section: str, got: dict[str, Any], allowed: tuple[str, ...]) -> None:
    unknown = sorted(set(got) - set(allowed))
    if unknown:
        raise UserError(f"mapping: unknown key(s) {', '.join(unknown)} in [{section}] (known: {', '.join(allowed)})")


def _path(section: str, key: str, value: Any) -> str:
    if not isinstance(value, str) or not value or any(not p for p in value.split(".")):
        raise UserError(f'mapping: [{section}] {key} must be a field path like "twist.twist.linear.x", got {value!r}')
    return value


def _signal(name: str, value: Any) -> Signal:
    section = "mcap.signals"
    if not isinstance(value, dict):
        raise UserError(
            f'mapping: [mcap.signals] {name} must be a table, e.g. {name} = {{ topic = "/odom", '
            f'path = "pose.pose.position.x" }}'
        )
    allowed = ("topic", "path", "left", "right") if name == "lc_direction" else ("topic", "path")
    _check_keys(f"mcap.signals.{name}", value, allowed)
    if not isinstance(value.get("topic"), str) or not value["topic"]:
        raise UserError(f'mapping: [{section}] {name} needs topic = "<topic in your file>"')
    values = {k: value[k] for k in ("left", "right") if k in value}
    if any(not isinstance(v, (str, int, float)) for v in values.values()):
        raise UserError(
            f"mapping: [{section}] {name}: left / right must be the value the field holds "
            f"for that direction (a number or a string)"
        )
    return Signal(topic=value["topic"], path=_path(f"{section}.{name}", "path", value.get("path")), values=values)


def signals_from_dict(doc: dict[str, Any]) -> McapSignals:
    """Parse the `[mcap.signals]` table; `UserError` naming the key on any mistake."""
    allowed = ("time", "lane_from_y", *EGO_REQUIRED, *EGO_OPTIONAL, "traffic")
    _check_keys("mcap.signals", doc, allowed)
    time = doc.get("time", LOG_TIME)
    if time != LOG_TIME:
        time = _path("mcap.signals", "time", time)
    ego = {name: _signal(name, doc[name]) for name in (*EGO_REQUIRED, *EGO_OPTIONAL) if name in doc}
    lane_from_y = _lane_from_y(doc["lane_from_y"]) if "lane_from_y" in doc else None
    derivable = {"ego_lane"} if lane_from_y is not None and "ego_y" in doc else set()
    missing = [k for k in (*EGO_REQUIRED, "traffic") if k not in doc and k not in derivable]
    if missing:
        hint = " (ego_lane: or ego_y with lane_from_y)" if "ego_lane" in missing else ""
        raise UserError(f"mapping: [mcap.signals] needs {', '.join(missing)} (the required signals){hint}")
    tr = doc["traffic"]
    if not isinstance(tr, dict):
        raise UserError("mapping: [mcap.signals.traffic] must be a table with topic, list, id, x, v, lane")
    _check_keys("mcap.signals.traffic", tr, (*TRAFFIC_REQUIRED, *TRAFFIC_OPTIONAL))
    derivable = {"lane"} if lane_from_y is not None and "y" in tr else set()
    missing = [k for k in TRAFFIC_REQUIRED if k not in tr and k not in derivable]
    if missing:
        hint = " (lane: or y with lane_from_y under [mcap.signals])" if "lane" in missing else ""
        raise UserError(f"mapping: [mcap.signals.traffic] needs {', '.join(missing)}{hint}")
    if not isinstance(tr["topic"], str) or not tr["topic"]:
        raise UserError("mapping: [mcap.signals.traffic] topic must be a topic name")
    fields = {k: _path("mcap.signals.traffic", k, tr[k]) for k in (*TRAFFIC_REQUIRED[2:], *TRAFFIC_OPTIONAL) if k in tr}
    traffic = TrafficSignals(topic=tr["topic"], list=_path("mcap.signals.traffic", "list", tr["list"]), fields=fields)
    return McapSignals(ego=ego, traffic=traffic, time=time, lane_from_y=lane_from_y)


def _lane_from_y(value: Any) -> LaneFromY:
    ok = (
        isinstance(value, dict)
        and set(value) <= {"width_m", "lane0_y_m"}
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value.values())
    )
    if not ok or not value.get("width_m", 0) > 0:
        raise UserError(
            "mapping: [mcap.signals] lane_from_y must be { width_m = <lane width, m, > 0>, "
            "lane0_y_m = <y of the centre of lane 0, m; default 0> }"
        )
    return LaneFromY(width_m=float(value["width_m"]), lane0_y_m=float(value.get("lane0_y_m", 0.0)))


def signals_from_v1(topic: Any, msg_field: Any) -> McapSignals:
    """The v1 layout (`[mcap.topics]` / `[mcap.fields]` applied) as signals, for non-JSON files.

    `topic(canonical)` and `msg_field(canonical_topic, field)` are the mapping's own
    look-ups. Optional signals absent from the messages are simply not logged.
    """

    def sig(canonical_topic: str, fld: str, required: bool) -> Signal:
        return Signal(topic(canonical_topic), msg_field(canonical_topic, fld), explicit=required)

    ego = {
        "ego_x": sig(TOPIC_EGO, "x", True),
        "ego_v": sig(TOPIC_EGO, "v", True),
        "ego_lane": sig(TOPIC_EGO, "lane", True),
        "ego_y": sig(TOPIC_EGO, "y", False),
        "ego_length": sig(TOPIC_EGO, "length", False),
        "steer": sig(TOPIC_CONTROLS, "steer", False),
        "throttle": sig(TOPIC_CONTROLS, "throttle", False),
        "brake": sig(TOPIC_CONTROLS, "brake", False),
        "lc_button": sig(TOPIC_BUTTON, "pressed", False),
        "lc_direction": sig(TOPIC_BUTTON, "direction", False),
    }
    fields = {k: msg_field(TOPIC_TRAFFIC, k) for k in ("id", "x", "v", "lane", "y", "length")}
    traffic = TrafficSignals(topic(TOPIC_TRAFFIC), msg_field(TOPIC_TRAFFIC, "vehicles"), fields, explicit=False)
    return McapSignals(ego=ego, traffic=traffic)
