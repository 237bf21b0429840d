"""Mapping files: adapt logs whose columns, topics, fields or units differ from format v1.

A mapping is a TOML file (YAML also accepted when PyYAML is installed) with any of
these sections; everything is optional and unnamed things keep their v1 names.
See `ingest/README.md` for a full example.

    [csv] delimiter = ";"  (default ",")
    [csv.columns]       canonical column = column in your file   (t, driver_id, ego_x, ...)
    [csv.traffic]       pattern = regex with named groups `id` and `field`
    [csv.traffic.fields] canonical vehicle field = field token in your columns (x, v, lane, y, length)
    [mcap.topics]       canonical topic = topic in your file
    [mcap.fields."<canonical topic>"] canonical field = field in your messages (dotted paths allowed)
    [mcap] metadata_name = "session"
    [mcap.metadata_keys] canonical key = key in your Metadata record
    [mcap.signals]      per canonical signal: { topic, path } inside schema-decoded messages
                        (ROS 2 CDR, protobuf, any JSON); see `ingest/mcap_signals.py`
    [units]             speed = "m/s" | "km/h" | "mph"; position = "m" | "cm" | "mm" | "ft";
                        time = "s" | "ms" | "us" | "ns" (CSV time column); or *_scale = factor
    [metadata]          defaults when a file has none: driver_id, session_id, speed_limit_kph, simulator
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import regex

from ingest.logformat import (
    CSV_EGO_OPTIONAL,
    CSV_EGO_REQUIRED,
    CSV_META,
    CSV_TIME,
    CSV_VEHICLE_FIELDS,
    METADATA_NAME,
    TOPIC_BUTTON,
    TOPIC_CONTROLS,
    TOPIC_EGO,
    TOPIC_TRAFFIC,
)
from ingest.mcap_signals import McapSignals, signals_from_dict
from laneprint.errors import UserError

DEFAULT_TRAFFIC_PATTERN = r"^(?P<id>.+)_(?P<field>x|v|lane|y|length)$"
#: A traffic pattern that takes longer than this on one probe name is refused before any log is read.
PATTERN_PROBE_S = 0.25
#: Column names on which a pattern with nested repetition backtracks for ever (`slow_probe`).
_PROBES = tuple(c * 48 + end for c in "a1_." for end in ("!", "_x!", "_"))


def traffic_regex(pattern: object) -> regex.Pattern:
    """A mapping's traffic pattern compiled by `regex` (the `re` syntax, plus a time limit on a match)."""
    if not isinstance(pattern, str):
        raise UserError("mapping: [csv.traffic] pattern must be text (a regular expression)")
    try:
        return regex.compile(pattern)
    except regex.error as exc:
        raise UserError(f"mapping: [csv.traffic] pattern is not a valid regex: {exc}") from None


def slow_probe(rx: regex.Pattern) -> str | None:
    """The first probe column name the pattern cannot match or refuse within `PATTERN_PROBE_S` (None: all fast)."""
    for name in _PROBES:
        try:
            rx.match(name, timeout=PATTERN_PROBE_S)
        except TimeoutError:
            return name
    return None


CSV_COLUMNS = (CSV_TIME, *CSV_META, *CSV_EGO_REQUIRED, *CSV_EGO_OPTIONAL)
MCAP_FIELDS: dict[str, tuple[str, ...]] = {
    TOPIC_EGO: ("x", "y", "v", "lane", "length"),
    TOPIC_TRAFFIC: ("vehicles", "id", "x", "y", "v", "lane", "length"),
    TOPIC_CONTROLS: ("steer", "throttle", "brake"),
    TOPIC_BUTTON: ("pressed", "direction"),
}
META_KEYS = ("driver_id", "session_id", "speed_limit_kph", "simulator")

_SPEED_UNITS = {"m/s": 1.0, "mps": 1.0, "km/h": 1 / 3.6, "kph": 1 / 3.6, "mph": 0.44704}
_POSITION_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "ft": 0.3048}
_TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


@dataclass(frozen=True)
class Mapping:
    """How names and units in a user's logs map onto log format v1 (identity by default)."""

    csv_columns: dict[str, str] = field(default_factory=dict)  # canonical -> file column
    csv_delimiter: str = ","  # field separator of the CSV files
    traffic_pattern: str = DEFAULT_TRAFFIC_PATTERN  # regex with groups `id`, `field`
    traffic_fields: dict[str, str] = field(default_factory=dict)  # canonical field -> token
    mcap_topics: dict[str, str] = field(default_factory=dict)  # canonical -> file topic
    mcap_fields: dict[str, dict[str, str]] = field(default_factory=dict)  # topic -> canonical -> field
    metadata_name: str = METADATA_NAME  # name of the MCAP Metadata record
    metadata_keys: dict[str, str] = field(default_factory=dict)  # canonical -> key in the record
    mcap_signals: McapSignals | None = None  # per-signal topic + field path ([mcap.signals])
    speed_scale: float = 1.0  # multiply speeds by this to get m/s
    position_scale: float = 1.0  # multiply positions/lengths by this to get m
    time_scale: float = 1.0  # multiply the CSV time column by this to get s
    defaults: dict[str, Any] = field(default_factory=dict)  # metadata when a file has none
    source: str = ""  # the file it came from ('' for the identity mapping)

    def column(self, canonical: str) -> str:
        return self.csv_columns.get(canonical, canonical)

    def topic(self, canonical: str) -> str:
        return self.mcap_topics.get(canonical, canonical)

    def msg_field(self, topic: str, canonical: str) -> str:
        return self.mcap_fields.get(topic, {}).get(canonical, canonical)

    def meta_key(self, canonical: str) -> str:
        return self.metadata_keys.get(canonical, canonical)

    @property
    def vehicle_field_by_token(self) -> dict[str, str]:
        """Token in the file's column names -> canonical vehicle field."""
        tokens = {f: f for f in CSV_VEHICLE_FIELDS}
        for canonical, token in self.traffic_fields.items():
            tokens.pop(canonical, None)
            tokens[token] = canonical
        return tokens

    def hint(self) -> str:
        """How to name the mapping in a reason ('--mapping FILE' or 'your --mapping file')."""
        return f"in the --mapping file ({self.source})" if self.source else "in a --mapping file"


IDENTITY = Mapping()


def _check_keys(section: str, got: dict[str, Any], allowed: tuple[str, ...] | set[str]) -> None:
    if not isinstance(got, dict):
        raise UserError(f"mapping: [{section}] must be a table of names, not {type(got).__name__} {str(got)[:40]!r}")
    unknown = sorted(set(map(str, got)) - set(allowed))
    if unknown:
        raise UserError(
            f"mapping: unknown key(s) {', '.join(unknown)} in [{section}] (known: {', '.join(sorted(allowed))})"
        )


def _str_dict(section: str, value: Any) -> dict[str, str]:
    if not isinstance(value, dict) or not all(isinstance(v, str) for v in value.values()):
        raise UserError(f"mapping: [{section}] must map names to strings")
    return dict(value)


def _scale(units: dict[str, Any], name: str, table: dict[str, float]) -> float:
    if f"{name}_scale" in units:
        value = units[f"{name}_scale"]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value < float("inf"):
            raise UserError(f"mapping: [units] {name}_scale must be a positive finite number")
        return float(value)
    unit = units.get(name)
    if unit is None:
        return 1.0
    if unit not in table:
        raise UserError(f"mapping: [units] {name} = {unit!r} is not one of {', '.join(table)}")
    return table[unit]


def mapping_from_dict(doc: dict[str, Any], source: str = "") -> Mapping:
    """Build a `Mapping` from a parsed TOML/YAML document; `UserError` on unknown keys."""
    _check_keys("top level", doc, {"csv", "mcap", "units", "metadata"})
    csv = doc.get("csv", {}) or {}
    _check_keys("csv", csv, {"columns", "traffic", "delimiter"})
    delimiter = csv.get("delimiter", ",")
    if not isinstance(delimiter, str) or len(delimiter) != 1 or delimiter in '"\r\n':
        raise UserError('mapping: [csv] delimiter must be one character, e.g. ";" or "\\t"')
    columns = _str_dict("csv.columns", csv.get("columns", {}) or {})
    _check_keys("csv.columns", columns, CSV_COLUMNS)
    traffic = csv.get("traffic", {}) or {}
    _check_keys("csv.traffic", traffic, {"pattern", "fields"})
    pattern = traffic.get("pattern", DEFAULT_TRAFFIC_PATTERN)
    rx = traffic_regex(pattern)
    if not {"id", "field"} <= set(rx.groupindex):
        raise UserError("mapping: [csv.traffic] pattern needs named groups (?P<id>...) and (?P<field>...)")
    slow = slow_probe(rx)
    if slow is not None:
        raise UserError(
            f"mapping: [csv.traffic] pattern takes over {PATTERN_PROBE_S} s on a column name like "
            f"{slow[:12]!r}...: write it without nested repetition, e.g. {DEFAULT_TRAFFIC_PATTERN!r}"
        )
    tfields = _str_dict("csv.traffic.fields", traffic.get("fields", {}) or {})
    _check_keys("csv.traffic.fields", tfields, CSV_VEHICLE_FIELDS)

    mcap = doc.get("mcap", {}) or {}
    _check_keys("mcap", mcap, {"topics", "fields", "metadata_name", "metadata_keys", "signals"})
    signals = signals_from_dict(mcap["signals"]) if "signals" in mcap else None
    if signals is not None and ("topics" in mcap or "fields" in mcap):
        raise UserError(
            "mapping: [mcap.signals] names every topic and field itself; "
            "drop [mcap.topics] / [mcap.fields] (they are for v1-shaped JSON messages)"
        )
    topics = _str_dict("mcap.topics", mcap.get("topics", {}) or {})
    _check_keys("mcap.topics", topics, tuple(MCAP_FIELDS))
    fields: dict[str, dict[str, str]] = {}
    for topic, fmap in (mcap.get("fields", {}) or {}).items():
        _check_keys("mcap.fields", {topic: 1}, tuple(MCAP_FIELDS))
        fields[topic] = _str_dict(f'mcap.fields."{topic}"', fmap)
        _check_keys(f'mcap.fields."{topic}"', fields[topic], MCAP_FIELDS[topic])
    meta_keys = _str_dict("mcap.metadata_keys", mcap.get("metadata_keys", {}) or {})
    _check_keys("mcap.metadata_keys", meta_keys, META_KEYS)

    units = doc.get("units", {}) or {}
    _check_keys("units", units, {"speed", "position", "time", "speed_scale", "position_scale", "time_scale"})
    defaults = dict(doc.get("metadata", {}) or {})
    _check_keys("metadata", defaults, META_KEYS)
    from ingest.plausible import speed_limit_problem

    problem = speed_limit_problem(defaults.get("speed_limit_kph"))
    if problem:
        raise UserError(f"mapping: [metadata] {problem}")
    return Mapping(
        csv_columns=columns,
        csv_delimiter=delimiter,
        traffic_pattern=pattern,
        traffic_fields=tfields,
        mcap_topics=topics,
        mcap_fields=fields,
        mcap_signals=signals,
        metadata_name=str(mcap.get("metadata_name", METADATA_NAME)),
        metadata_keys=meta_keys,
        speed_scale=_scale(units, "speed", _SPEED_UNITS),
        position_scale=_scale(units, "position", _POSITION_UNITS),
        time_scale=_scale(units, "time", _TIME_UNITS),
        defaults=defaults,
        source=source,
    )


def load_mapping(path: Path | None) -> Mapping:
    """Read a mapping file (.toml, or .yaml/.yml); the identity mapping when `path` is None."""
    if path is None:
        return IDENTITY
    path = Path(path)
    if not path.is_file():
        raise UserError(f"mapping file {path} does not exist")
    if path.stat().st_size > 1024 * 1024:
        raise UserError(f"mapping {path.name}: larger than 1024 KB, not a mapping file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise UserError(f"mapping {path.name}: not UTF-8 text") from None
    if path.suffix.lower() in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError:  # pragma: no cover - PyYAML is optional
            raise UserError("YAML mapping files need PyYAML (pip install pyyaml); or write it as TOML") from None
        try:
            from ingest.small_yaml import load as load_yaml

            doc = load_yaml(text) or {}
        except yaml.YAMLError as exc:
            raise UserError(f"mapping {path.name}: invalid YAML: {str(exc).splitlines()[0]}") from None
    else:
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise UserError(f"mapping {path.name}: invalid TOML: {exc}") from None
    if not isinstance(doc, dict):
        raise UserError(f"mapping {path.name}: expected a table of sections")
    return mapping_from_dict(doc, source=path.name)
