"""JSON messages decoded by msgspec (C, 3-10x the standard library), with `json.loads` behind it.

`loads` is msgspec's decoder; what strict JSON parsers refuse and Python's accepts
(`NaN` / `Infinity` literals, UTF-16 text, lone surrogates) is decoded by `json.loads`
as before, so every file reads exactly as it did. `float_columns` decodes flat
messages straight into typed structs and returns one float column per field: no dict
per message. Measurements in ingest/README.md (*Speed*).
"""

from __future__ import annotations

import json
import operator
from functools import lru_cache
from types import GenericAlias
from typing import Any, Optional

import msgspec
import numpy as np

_DECODER = msgspec.json.Decoder()


def loads(data: bytes) -> Any:
    """One JSON document as Python objects (dicts, lists, ...), exactly as `json.loads` gives it."""
    try:
        return _DECODER.decode(data)
    except msgspec.DecodeError:
        return json.loads(data)


def loads_many(datas: list[bytes]) -> list[Any]:
    """Several JSON documents in one call; `ValueError` / `UnicodeDecodeError` when one is not JSON."""
    return loads(b"[" + b",".join(datas) + b"]")


@lru_cache(maxsize=64)
def _rows_decoder(names: tuple[str, ...]) -> msgspec.json.Decoder:
    """A decoder of a list of objects whose fields `names` are numbers or null (other fields ignored)."""
    fields = [(f"f{i}", Optional[float], None) for i in range(len(names))]
    row = msgspec.defstruct("Row", fields, rename={f"f{i}": n for i, n in enumerate(names)}, gc=False)
    return msgspec.json.Decoder(GenericAlias(list, (row,)))  # list[row], spelled for a struct made at run time


def float_columns(datas: list[bytes], names: list[str]) -> dict[str, np.ndarray] | None:
    """Field `name` of every message as floats (NaN where absent or null), for each of `names`.

    None when a message does not fit (not an object, a field holding text, a bool or a
    nested value, invalid JSON): the caller then decodes the messages one by one.
    """
    unique = tuple(dict.fromkeys(names))
    if not datas or any("." in n for n in unique):
        return None
    try:
        rows = _rows_decoder(unique).decode(b"[" + b",".join(datas) + b"]")
    except msgspec.DecodeError:
        return None
    return {n: _floats(rows, f"f{i}") for i, n in enumerate(unique)}


def _floats(rows: list[Any], attr: str) -> np.ndarray:
    """Field `attr` of every row as floats; None -> NaN."""
    get = operator.attrgetter(attr)
    try:
        return np.fromiter(map(get, rows), dtype=float, count=len(rows))
    except TypeError:  # a null among them
        return np.array(list(map(get, rows)), dtype=float)
