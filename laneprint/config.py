"""Settings from a TOML file: `--config FILE.toml` of the commands whose settings are a dataclass.

The file's keys are the dataclass's field names (for `analyze`, those of
`indicators.settings.AnalysisSettings`), its values of the field's type; lists stand for tuples.
Unknown keys and values of the wrong type are refused with one line before any work.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path
from typing import Any, TypeVar

from laneprint.errors import UserError

T = TypeVar("T")
#: A config file larger than this is no settings file.
MAX_CONFIG_BYTES = 64 * 1024


def read_config(path: Path, cls: type[T], base: T | None = None) -> T:
    """`base` (default: `cls()`) with the fields `path` sets."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise UserError(f"--config {path}: larger than {MAX_CONFIG_BYTES // 1024} KB, not a settings file")
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UserError(f"--config {path}: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"--config {path}: not valid TOML ({exc})") from None
    base = base if base is not None else cls()
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise UserError(f"--config {path}: unknown setting(s) {', '.join(unknown)}; known: {', '.join(fields)}")
    changes: dict[str, Any] = {}
    for key, value in data.items():
        current = getattr(base, key)
        if isinstance(value, list):
            value = tuple(value)
        ok = (current is None or value is None or isinstance(value, type(current))
              or (isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool)))
        if not ok or (isinstance(current, bool) != isinstance(value, bool) and current is not None):
            raise UserError(f"--config {path}: {key} must be {type(current).__name__}, not {value!r}")
        changes[key] = float(value) if isinstance(current, float) and isinstance(value, int) else value
    return dataclasses.replace(base, **changes)  # type: ignore[type-var]
