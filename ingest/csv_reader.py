"""Read a wide CSV log (plain or gzip) into a `RawLog`, with pyarrow and vectorised reshaping."""

from __future__ import annotations

import csv
import re
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv

from ingest.limits import IngestLimits, check_csv_shape, gunzip, long_line
from ingest.logformat import CSV_EGO_REQUIRED, CSV_TIME, DEFAULT_LENGTH_M
from ingest.mapping import Mapping, traffic_regex
from ingest.rawlog import RawLog, Rejected, first_line

_STRING_COLUMNS = ("driver_id", "session_id", "simulator", "lc_direction")
_EGO_FLOATS = {  # CSV canonical column -> EGO column (positions scaled with position_scale)
    "ego_x": "ego_x_m",
    "ego_y": "ego_y_m",
    "ego_length": "ego_length_m",
    "ego_v": "ego_v_mps",
    "ego_lane": "ego_lane",
    "steer": "steer_rad",
    "throttle": "throttle",
    "brake": "brake",
}
_POSITIONS = ("ego_x", "ego_y", "ego_length")
_OPTIONAL_FLOATS = ("ego_y", "ego_length", "steer", "throttle", "brake", "speed_limit_kph")
#: The traffic pattern's time on one file's header, all columns together [s].
HEADER_MATCH_S = 2.0
_CONVERSION = re.compile(
    r"In CSV column #(\d+): Row #(\d+): CSV conversion error to (\w+)(?:: invalid value '(.*)')?", re.DOTALL
)
PART_MIN_BYTES = 4 << 20  # [bytes] a CSV is parsed in parts side by side from 2 x this size


def _header(text: bytes, delimiter: str = ",") -> list[str]:
    nul = text.find(b"\x00", 0, 65536)
    if nul >= 0:
        raise Rejected(f"not a text CSV file (binary byte at offset {nul})")
    end = text.find(b"\n")
    line = text[: end if end >= 0 else len(text)]
    try:
        decoded = line.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise Rejected(f"malformed CSV: the header row is not UTF-8 text (byte {exc.start})") from None
    names = next(csv.reader([decoded.rstrip("\r")], delimiter=delimiter), [])
    if not any(n.strip() for n in names):
        raise Rejected("malformed CSV: the first row (header) is empty")
    seen: set[str] = set()
    for n in names:
        if n in seen:
            raise Rejected(f"malformed CSV: column {n!r} appears twice in the header")
        seen.add(n)
    return names


def _ragged_line(data: bytes, n_fields: int, delimiter: str) -> str | None:
    """'line N has M fields, the header has K' for the first ragged row (error path only)."""
    text = data.decode("utf-8", errors="replace").splitlines()
    for lineno, row in enumerate(csv.reader(text, delimiter=delimiter), start=1):
        if row and len(row) != n_fields:
            return f"line {lineno} has {len(row)} fields, the header has {n_fields}"
    return None


def _missing_reason(missing: list[str], mapping: Mapping, names: list[str]) -> str:
    if len(names) == 1:
        for sep, label in ((";", ";"), ("\t", "\\t"), ("|", "|")):
            if sep in names[0] and sep != mapping.csv_delimiter:
                return (
                    f"the header has one column only ({names[0][:40]!r}...): the file looks {label}-separated; "
                    f'set delimiter = "{label}" under [csv] {mapping.hint()}'
                )
    parts = [f"{c}" + (f" (looked for {mapping.column(c)!r})" if mapping.column(c) != c else "") for c in missing]
    example = missing[0]
    return (
        f"missing required column(s) {', '.join(parts)}: name your column with "
        f'{example} = "<your column>" under [csv.columns] {mapping.hint()}'
    )


def _vehicle_columns(names: list[str], known: set[str], mapping: Mapping) -> dict[str, dict[str, str]]:
    """Vehicle id -> canonical field -> file column, in the order the vehicles first appear."""
    rx = traffic_regex(mapping.traffic_pattern)
    tokens = mapping.vehicle_field_by_token
    out: dict[str, dict[str, str]] = {}
    deadline = time.monotonic() + HEADER_MATCH_S
    for name in names:
        if name in known or name.startswith("ego_"):
            continue
        try:
            m = rx.match(name, timeout=max(deadline - time.monotonic(), 1e-3))
        except TimeoutError:
            raise Rejected(
                f"the traffic pattern took over {HEADER_MATCH_S:g} s on this file's column names "
                f"(at {name[:24]!r}): simplify [csv.traffic] pattern in the mapping"
            ) from None
        if not m or m.group("field") not in tokens:
            continue
        out.setdefault(m.group("id"), {})[tokens[m.group("field")]] = name
    for vid, cols in out.items():
        lacking = [f for f in ("x", "v", "lane") if f not in cols]
        if lacking:
            have = ", ".join(sorted(cols.values()))
            raise Rejected(
                f"traffic vehicle {vid!r} has {have} but no {'/'.join(lacking)} column(s): "
                f"every vehicle needs x, v and lane ([csv.traffic] in a --mapping file sets the pattern)"
            )
    return out


def _const(table: pa.Table, column: str, label: str) -> str | float | None:
    values = [v for v in table.column(column).unique().to_pylist() if v is not None and v == v]
    if not values:
        return None
    if len(values) > 1:
        shown = ", ".join(map(str, values[:3])) + (", ..." if len(values) > 3 else "")
        raise Rejected(f"{label} column has several values ({shown}): write one file per recording")
    return values[0]


def _parse(
    data: bytes,
    names: list[str],
    parse_options: pacsv.ParseOptions,
    convert_options: pacsv.ConvertOptions,
    block_size: int = 1 << 20,
) -> pa.Table:
    """pyarrow's CSV reader over `data`; a large file is cut into parts parsed side by side.

    On these wide logs pyarrow's own multi-threaded reader costs ~15 % more CPU than its
    single-threaded one (a task per 1 MB block and column), so a file is cut at line ends
    into one part per core, each part parsed by a single-threaded reader in its own thread
    (the parts after the first one told the header's column `names`). Rows keep their order.
    Cutting at a line end is what pyarrow does itself: it does not allow newlines inside
    values by default. Any error is reported from a parse of the whole file, so that the
    row numbers in pyarrow's message count from the file's start.
    """
    parts = max(1, min(pa.cpu_count(), len(data) // PART_MIN_BYTES))
    end_header = data.find(b"\n") + 1
    cuts = [end_header]
    for i in range(1, parts):
        cut = data.find(b"\n", max(cuts[-1], len(data) * i // parts)) + 1
        if 0 < cut < len(data):
            cuts.append(cut)
    cuts.append(len(data))
    with_header = pacsv.ReadOptions(use_threads=False, block_size=block_size)  # a line longer than a block fails
    headless = pacsv.ReadOptions(use_threads=False, column_names=names, block_size=block_size)

    def read(i: int | None) -> pa.Table:
        piece = data if i is None else memoryview(data)[0 if i == 0 else cuts[i] : cuts[i + 1]]
        return pacsv.read_csv(
            pa.BufferReader(piece),
            read_options=with_header if not i else headless,
            parse_options=parse_options,
            convert_options=convert_options,
        )

    if len(cuts) == 2:  # a small file, or nothing to cut at
        return read(None)
    try:
        with ThreadPoolExecutor(len(cuts) - 2) as pool:  # pyarrow releases the GIL while it parses
            rest = [pool.submit(read, i) for i in range(1, len(cuts) - 1)]
            first = read(0)
            return pa.concat_tables([first, *(f.result() for f in rest)])
    except (pa.ArrowInvalid, pa.ArrowTypeError, UnicodeDecodeError):
        # a part numbers its rows from its own start: parse the whole file for the error message
        return read(None)


def _parse_typed(
    data: bytes,
    names: list[str],
    types: dict[str, pa.DataType],
    optional: set[str],
    vehicle_columns: set[str],
    mapping: Mapping,
    limits: IngestLimits,
) -> tuple[pa.Table, dict[str, pa.ChunkedArray], list[str]]:
    """Parse with the given column types; a text cell in an optional column empties that cell
    (with a warning), in a required one refuses the file naming the column and the line.
    Returns the table, the mask of emptied cells per column, and the warnings."""
    as_text: list[str] = []
    while True:
        convert = pacsv.ConvertOptions(
            column_types={k: (pa.string() if k in as_text else v) for k, v in types.items()},
            include_columns=list(types),
            strings_can_be_null=True,
        )
        try:
            table = _parse(
                data,
                names,
                pacsv.ParseOptions(delimiter=mapping.csv_delimiter),
                convert,
                block_size=limits.max_line_bytes,
            )
            break
        except (pa.ArrowInvalid, pa.ArrowTypeError, UnicodeDecodeError) as exc:
            m = _CONVERSION.match(str(exc))
            column = names[int(m.group(1))] if m and int(m.group(1)) < len(names) else None
            if m is None or column is None:  # column is None whenever m is
                raise Rejected(f"malformed CSV: {_parse_failure(data, names, exc, mapping, limits)}") from None
            if column in optional and column not in as_text:
                as_text.append(column)
                continue
            if m.group(4) is None:
                raise Rejected(
                    f"column {column!r} line {m.group(2)}: the value is not UTF-8 text; save the file as UTF-8"
                ) from None
            what = "0/1 or true/false" if types[column] == pa.bool_() else "a number"
            raise Rejected(
                f"column {column!r} line {m.group(2)}: {first_line(m.group(4), 40)!r} is not {what}; "
                f"correct that value or remove the line"
            ) from None
    warnings: list[str] = []
    coerced: dict[str, pa.ChunkedArray] = {}
    for column in as_text:
        text = table.column(column)
        numbers = _to_floats(text)
        bad = pc.and_(pc.is_valid(text), pc.is_null(numbers))
        coerced[column] = bad
        first = int(pc.index(bad, True).as_py())
        warnings.append(
            f"column {column!r}: {pc.sum(bad).as_py()} value(s) are not numbers (first "
            f"{first_line(text[first].as_py(), 40)!r} at line {first + 2}); "
            + ("the vehicle is left out of those samples" if column in vehicle_columns else "left empty")
        )
        table = table.set_column(table.schema.get_field_index(column), column, numbers)
    return table, coerced, warnings


def _to_floats(text: pa.ChunkedArray) -> pa.ChunkedArray:
    """Text -> float64, null where a cell is not a number."""
    return pa.chunked_array([pa.array(pd.to_numeric(text.to_pandas(), errors="coerce"), pa.float64())])


def _parse_failure(data: bytes, names: list[str], exc: Exception, mapping: Mapping, limits: IngestLimits) -> str:
    """The reason a CSV could not be parsed: a line too long, a ragged line, or pyarrow's first line."""
    if "straddling" in str(exc):
        return long_line(data, limits) or first_line(exc)
    return _ragged_line(data, len(names), mapping.csv_delimiter) or first_line(exc)


def _blank_absent_vehicles(
    table: pa.Table, vehicles: dict[str, dict[str, str]], coerced: dict[str, pa.ChunkedArray]
) -> pa.Table:
    """A traffic vehicle whose v or lane cell was not a number is absent at that sample: its x is emptied too."""
    for cols in vehicles.values():
        gone = [coerced[cols[f]] for f in ("v", "lane") if cols[f] in coerced]
        if gone:
            mask = gone[0] if len(gone) == 1 else pc.or_(*gone)
            x = table.column(cols["x"])
            table = table.set_column(table.schema.get_field_index(cols["x"]), cols["x"], pc.if_else(mask, None, x))
    return table


def read_csv_log(data: bytes, fmt: str, mapping: Mapping, limits: IngestLimits | None = None) -> RawLog:
    """Parse CSV bytes (gzip when `fmt` is 'csv.gz') into a `RawLog`; `Rejected` on bad input."""
    limits = limits or IngestLimits()
    if fmt == "csv.gz":
        data = gunzip(data, limits)
        if not data.strip():
            raise Rejected("empty CSV inside the gzip file")
    check_csv_shape(data, mapping.csv_delimiter, limits)
    names = _header(data, mapping.csv_delimiter)
    col = mapping.column
    required = [CSV_TIME, *CSV_EGO_REQUIRED]
    missing = [c for c in required if col(c) not in names]
    if missing:
        raise Rejected(_missing_reason(missing, mapping, names))

    canonical_present = {
        c: col(c) for c in (*_STRING_COLUMNS, "speed_limit_kph", "lc_button", *_EGO_FLOATS, CSV_TIME) if col(c) in names
    }
    known = set(canonical_present.values())
    vehicles = _vehicle_columns(names, known, mapping)

    types: dict[str, pa.DataType] = {}
    for c, name in canonical_present.items():
        types[name] = pa.string() if c in _STRING_COLUMNS else pa.bool_() if c == "lc_button" else pa.float64()
    for cols in vehicles.values():
        for name in cols.values():
            types[name] = pa.float64()
    vehicle_columns = {name for cols in vehicles.values() for name in cols.values()}
    optional = vehicle_columns | {name for c, name in canonical_present.items() if c in _OPTIONAL_FLOATS}
    table, coerced, warnings = _parse_typed(data, names, types, optional, vehicle_columns, mapping, limits)
    if coerced:
        table = _blank_absent_vehicles(table, vehicles, coerced)
    n = table.num_rows
    meta = {}
    for c in ("driver_id", "session_id", "simulator"):
        meta[c] = _const(table, canonical_present[c], canonical_present[c]) if c in canonical_present else None
    if "speed_limit_kph" in canonical_present:
        try:
            meta["speed_limit_kph"] = _const(table, canonical_present["speed_limit_kph"], "speed_limit_kph")
        except Rejected:
            meta["speed_limit_kph"] = None
            warnings.append("speed_limit_kph changes within the file; the catalogue leaves it empty")
    else:
        meta["speed_limit_kph"] = None

    def floats(name: str) -> np.ndarray:
        return table.column(name).to_numpy().astype(float, copy=False)

    t_abs = floats(col(CSV_TIME)) * mapping.time_scale
    ego: dict[str, np.ndarray] = {}
    for c, target in _EGO_FLOATS.items():
        if c in canonical_present:
            a = floats(canonical_present[c])
            if c in _POSITIONS and mapping.position_scale != 1.0:
                a = a * mapping.position_scale
            if c == "ego_v" and mapping.speed_scale != 1.0:
                a = a * mapping.speed_scale
            ego[target] = a
        else:
            ego[target] = np.full(n, DEFAULT_LENGTH_M if c == "ego_length" else np.nan)
    has_button = "lc_button" in canonical_present
    if has_button:
        ego["lc_button"] = table.column(canonical_present["lc_button"]).fill_null(False).to_numpy(zero_copy_only=False)
    else:
        ego["lc_button"] = np.zeros(n, dtype=bool)
    if "lc_direction" in canonical_present:
        ego["lc_direction"] = np.asarray(table.column(canonical_present["lc_direction"]).to_pylist(), dtype=object)
    else:
        ego["lc_direction"] = np.full(n, None, dtype=object)

    t0 = t_abs[0] if n else 0.0
    traffic, n_vehicles, grid = _long_traffic(table, vehicles, t_abs - t0, mapping)
    return RawLog(
        format=fmt,
        meta=meta,
        t_abs_s=t_abs,
        t_s=t_abs - t0,
        ego=ego,
        traffic=traffic,
        locate=lambda i: f"line {i + 2}",
        time_name=col(CSV_TIME),
        names={"ego_x_m": col("ego_x"), "ego_v_mps": col("ego_v"), "ego_lane": col("ego_lane")},
        has_button=has_button,
        warnings=warnings,
        n_vehicles=n_vehicles,
        vehicle_grid=grid,
    )


def _grid(table: pa.Table, names: list[str | None], n: int) -> np.ndarray:
    """(samples, vehicles) float values of one field, NaN where a column is missing or empty."""
    out = np.empty((len(names), n))  # filled row by row (contiguous), then transposed once
    for j, name in enumerate(names):
        if name is None:
            out[j] = np.nan
            continue
        i = 0
        for chunk in table.column(name).chunks:
            out[j, i : i + len(chunk)] = chunk.to_numpy(zero_copy_only=False)
            i += len(chunk)
    return np.ascontiguousarray(out.T)


def _tiled(ids: list[str], n: int) -> pa.Array:
    """The strings `ids` repeated `n` times as one Arrow string array, built from its buffers (a
    quarter of the time of `take` on a 10-minute, 20-vehicle log)."""
    enc = [i.encode() for i in ids]
    block = b"".join(enc)
    if len(block) * n >= 2**31:  # beyond 32-bit offsets
        return pa.array(ids, pa.string()).take(pa.array(np.tile(np.arange(len(ids), dtype=np.int32), n)))
    ends = np.cumsum([len(e) for e in enc])
    offsets = np.zeros(n * len(ids) + 1, dtype=np.int32)
    offsets[1:] = (np.arange(n, dtype=np.int64)[:, None] * len(block) + ends[None, :]).ravel()
    return pa.StringArray.from_buffers(n * len(ids), pa.py_buffer(offsets), pa.py_buffer(block * n))


def _long_traffic(
    table: pa.Table, vehicles: dict[str, dict[str, str]], t: np.ndarray, mapping: Mapping
) -> tuple[dict[str, np.ndarray], int, int]:
    """Wide `<id>_<field>` columns -> long-form arrays, one row per vehicle present per sample,
    the number of vehicles present at least once, and k when the rows are the k vehicles in the
    same order at every sample (`RawLog.vehicle_grid`; 0 otherwise).

    Rows are time-major (by sample, then by vehicle in header order). Each field is laid
    out as a (samples, vehicles) grid; when every vehicle is present in every sample
    (the usual simulator log) the long column is that grid flattened, without a copy.
    """
    n = table.num_rows
    ids = list(vehicles)
    k = len(ids)
    if not ids or n == 0:
        empty = np.zeros(0)
        return (
            {
                "t_s": empty,
                "vehicle_id": pa.array([], pa.string()),
                "x_m": empty,
                "y_m": empty,
                "v_mps": empty,
                "lane": empty,
                "length_m": empty,
            },
            0,
            0,
        )

    x = _grid(table, [vehicles[vid]["x"] for vid in ids], n)
    present = ~np.isnan(x)
    everywhere = bool(present.all())
    if everywhere:
        t_long = np.repeat(t, k)
        codes = np.tile(np.arange(k, dtype=np.int32), n)
        n_vehicles = k
    else:
        t_long = np.repeat(t, present.sum(axis=1))
        codes = np.nonzero(present)[1].astype(np.int32)
        n_vehicles = int(present.any(axis=0).sum())

    def pick(grid: np.ndarray) -> np.ndarray:
        return grid.reshape(-1) if everywhere else grid[present]

    def field(fld: str, scale: float) -> np.ndarray:
        names = [vehicles[vid].get(fld) for vid in ids]
        if not any(names):
            return np.full(len(codes), DEFAULT_LENGTH_M if fld == "length" else np.nan)
        vals = pick(x if fld == "x" else _grid(table, names, n))
        if scale != 1.0:
            vals *= scale  # vals is a fresh array of ours
        return vals

    out = {"t_s": t_long}
    fields = {
        "x_m": ("x", mapping.position_scale),
        "v_mps": ("v", mapping.speed_scale),
        "lane": ("lane", 1.0),
        "y_m": ("y", mapping.position_scale),
        "length_m": ("length", mapping.position_scale),
    }
    # the grids are numpy copies and transposes, which release the GIL: two at a time
    with ThreadPoolExecutor(1) as pool:
        later = {key: pool.submit(field, *fields[key]) for key in ("v_mps", "y_m")}
        out["vehicle_id"] = _tiled(ids, n) if everywhere else pa.array(ids, pa.string()).take(pa.array(codes))
        out.update({key: field(*fields[key]) for key in ("x_m", "lane", "length_m")})
        out.update({key: f.result() for key, f in later.items()})
    for key, fld in (("v_mps", "v"), ("lane", "lane")):
        bad = np.isnan(out[key])
        if bad.any():
            i = int(np.argmax(bad))
            vid = ids[codes[i]]
            row = int(np.nonzero(present)[0][i])
            raise Rejected(
                f"traffic vehicle {vid!r}: {vehicles[vid][fld]} is empty at line {row + 2} "
                f"while {vehicles[vid]['x']} is given (a present vehicle needs x, v and lane)"
            )
    gaps = np.isnan(out["length_m"])
    if gaps.any():
        out["length_m"][gaps] = DEFAULT_LENGTH_M
    return out, n_vehicles, k if everywhere else 0
