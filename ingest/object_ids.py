"""Traffic object ids as text: one canonical form for every way a log can carry an id.

Strings stay as they are; whole numbers are written without a decimal part (`7`, `7.0`
-> `"7"`); byte strings and arrays of bytes (ROS 2 `uint8[]`, protobuf `bytes`, a JSON
list of 0-255 integers) are lowercase hex, two digits per byte, no separators; a message
whose only field holds such bytes (ROS 2 `unique_identifier_msgs/msg/UUID`, `uuid`)
is the hex of that field. So a ROS 2 UUID `b'V001' + 12 zero bytes` is
`"56303031000000000000000000000000"`, as Autoware's `toHexString` prints it.
"""

from __future__ import annotations

import array
from typing import Any

import numpy as np
import pyarrow as pa


def _bytes_of(value: Any) -> bytes | None:
    """The bytes an id value holds, or None when it is not a byte string / byte array."""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value)
    if isinstance(value, array.array) and value.typecode in "bB":
        return value.tobytes()
    if isinstance(value, np.ndarray) and value.dtype in (np.uint8, np.int8):
        return value.tobytes()
    if (
        isinstance(value, (list, tuple))
        and value
        and all(isinstance(b, int) and not isinstance(b, bool) and 0 <= b <= 255 for b in value)
    ):
        return bytes(value)
    return None


def _wrapped(value: Any) -> Any:
    """The one field of a single-field message (a UUID message's `uuid`), else the value itself."""
    slots = getattr(value, "__slots__", None)
    if isinstance(slots, (list, tuple)) and len(slots) == 1:
        inner = getattr(value, slots[0], None)
        if inner is None:  # a SimpleNamespace-based message keeps its fields in __dict__
            inner = getattr(value, "__dict__", {}).get(slots[0])
        return value if inner is None else inner
    descriptor = getattr(value, "DESCRIPTOR", None)
    fields = getattr(descriptor, "fields", None)
    if fields is not None and len(fields) == 1:
        return getattr(value, fields[0].name)
    return value


def id_text(value: Any) -> str | None:
    """The canonical text of one object id (None for a missing one)."""
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return str(int(value)) if float(value).is_integer() else str(value)
    inner = next(iter(value.values())) if isinstance(value, dict) and len(value) == 1 else _wrapped(value)
    if inner is not value:  # a single-field message or object ({"uuid": [...]}, std_msgs/String): its field
        return id_text(inner)
    raw = _bytes_of(value)
    return raw.hex() if raw is not None else str(value)


def id_array(values: list[Any]) -> pa.Array:
    """Object ids as an Arrow string array, in canonical text."""
    kinds = set(map(type, values))
    if kinds <= {str}:
        return pa.array(values, pa.string())
    if kinds <= {int}:
        return pa.array(list(map(str, values)), pa.string())
    return pa.array([id_text(v) for v in values], pa.string())
