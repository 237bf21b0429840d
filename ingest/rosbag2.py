"""Split rosbag2 folders: `metadata.yaml` plus several `<name>_N.mcap` files, read as one recording.

`ros2 bag record` cuts long recordings into files (`--max-bag-size`, `--max-bag-duration`)
and describes them in `metadata.yaml` (`rosbag2_bagfile_information`): the storage, the
files in recording order (`relative_file_paths`), the time span (`starting_time`,
`duration`) and the message count. A folder holding such a file is one log: its parts
are read in that order, each with its own channel and schema ids (they restart in every
file), and merged by topic. Parts listed but absent are refused; a message count or
time span that disagrees with what the files hold is a warning.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ingest.limits import IngestLimits
from ingest.mapping import Mapping
from ingest.mcap_reader import read_collected, read_mcap_file
from ingest.mcap_records import Collected
from ingest.rawlog import RawLog, Rejected, first_line

METADATA = "metadata.yaml"
_KEY = "rosbag2_bagfile_information"
_PART = re.compile(r"_(\d+)\.mcap$")
_ID_BITS = 16  # channel and schema ids are uint16: part k's ids become k << 16 | id


@dataclass(frozen=True)
class BagInfo:
    """What `metadata.yaml` says about a split bag."""

    files: tuple[str, ...]  # part file names, in recording order
    start_ns: int | None  # [ns] starting_time
    duration_ns: int | None  # [ns] duration
    message_count: int | None
    sizes: tuple[int, ...] = ()  # [bytes] each part's size, once read


def is_bag_folder(path: Path) -> bool:
    """True for a folder whose `metadata.yaml` describes a rosbag2 bag."""
    meta = path / METADATA
    try:
        return meta.is_file() and _KEY in meta.read_text(errors="replace")[:4096]
    except OSError:
        return False


def _nested(doc: dict[str, Any], *keys: str) -> Any:
    node: Any = doc
    for k in keys:
        node = node.get(k) if isinstance(node, dict) else None
    return node


def _int(value: Any) -> int | None:
    return int(value) if isinstance(value, int) and not isinstance(value, bool) else None


def read_bag_info(folder: Path) -> BagInfo:
    """The parts and time span of a bag folder; `Rejected` for what laneprint cannot read."""
    import yaml

    from ingest.small_yaml import load as load_yaml

    try:
        doc = load_yaml((folder / METADATA).read_text())
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise Rejected(f"{METADATA} of the rosbag2 folder is not readable YAML ({first_line(exc)})") from None
    info = _nested(doc, _KEY)
    if not isinstance(info, dict):
        raise Rejected(f"{METADATA} has no {_KEY} section")
    storage = info.get("storage_identifier", "mcap")
    if storage != "mcap":
        raise Rejected(
            f"rosbag2 storage {storage!r}: laneprint reads MCAP storage; convert the bag with "
            f"`ros2 bag convert` to storage_id mcap"
        )
    if info.get("compression_mode") in ("file", "FILE", "message", "MESSAGE"):
        raise Rejected(
            f"rosbag2 compression_mode {info['compression_mode']!r} ({info.get('compression_format')}): "
            f"decompress the bag first (`ros2 bag convert` without compression)"
        )
    files = info.get("relative_file_paths")
    if not isinstance(files, list) or not files or not all(isinstance(f, str) for f in files):
        found = [p.name for p in folder.glob("*.mcap")]
        files = sorted(found, key=lambda n: (int(m.group(1)) if (m := _PART.search(n)) else -1, n))
    if not files:
        raise Rejected(f"rosbag2 folder with no .mcap file ({METADATA} lists none)")
    twice = next((f for i, f in enumerate(files) if Path(f).name in {Path(g).name for g in files[:i]}), None)
    if twice is not None:
        raise Rejected(f"{METADATA} lists the part {Path(twice).name} more than once; list each part once")
    return BagInfo(
        tuple(Path(f).name for f in files),
        _int(_nested(info, "starting_time", "nanoseconds_since_epoch")),
        _int(_nested(info, "duration", "nanoseconds")),
        _int(info.get("message_count")),
    )


def bag_parts(folder: Path) -> tuple[BagInfo, list[Path]]:
    """The bag's info and its part files in order; `Rejected` naming a listed part that is absent."""
    info = read_bag_info(folder)
    paths = [folder / name for name in info.files]
    missing = [p.name for p in paths if not p.is_file()]
    if missing:
        raise Rejected(
            f"split rosbag2: {', '.join(missing)} listed in {METADATA} is missing from the folder "
            f"({len(paths) - len(missing)} of {len(paths)} parts present); fetch or copy every part"
        )
    return info, paths


def merge_parts(parts: list[Collected]) -> Collected:
    """One `Collected` from the parts of a bag: ids made unique per part, metadata records merged."""
    out = Collected()
    for k, got in enumerate(parts):
        base = k << _ID_BITS
        for sid, schema in got.schemas.items():
            out.schemas[base | sid] = replace(schema, id=base | sid)
        for cid, ch in got.channels.items():
            out.channels[base | cid] = replace(
                ch, id=base | cid, schema_id=(base | ch.schema_id) if ch.schema_id else 0
            )
        for cid in got.times:
            out.times[base | cid] = got.times[cid]
            out.datas[base | cid] = got.datas[cid]
        for name, values in got.metadata.items():
            out.metadata.setdefault(name, {}).update(values)
    return out


def bag_warnings(info: BagInfo, got: Collected, n_files: int) -> list[str]:
    """Where the files disagree with metadata.yaml: message count, messages outside its time span."""
    warnings: list[str] = []
    n = sum(len(t) for t in got.times.values())
    if info.message_count is not None and info.message_count != n:
        warnings.append(
            f"{METADATA} counts {info.message_count} messages, the {n_files} part(s) hold {n}: a part may be cut short"
        )
    if info.start_ns is not None and info.duration_ns is not None:
        lo, hi = info.start_ns, info.start_ns + info.duration_ns
        outside = sum(sum(1 for t in times if t < lo or t > hi) for times in got.times.values())
        if outside:
            warnings.append(f"{outside} message(s) lie outside the time span of {METADATA} ({lo}-{hi} ns)")
    return warnings


def _read_part(name: str, data: bytes, limits: IngestLimits) -> Collected:
    """One part's records; `Rejected` naming the part."""
    try:
        return read_mcap_file(data, limits)
    except Rejected as exc:
        raise Rejected(f"split rosbag2 part {name}: {exc}") from None


def read_split_bag(data: bytes, info: BagInfo, mapping: Mapping, limits: IngestLimits) -> RawLog:
    """A `RawLog` from a split bag's parts (`data`: the parts one after the other, `info.sizes` long)."""
    parts: list[Collected] = []
    at = 0
    for name, size in zip(info.files, info.sizes):
        parts.append(_read_part(name, data[at : at + size], limits))
        at += size
    got = merge_parts(parts)
    return read_collected(got, mapping, bag_warnings(info, got, len(parts)))
