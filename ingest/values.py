"""Value checks: every signal of a log against what it can physically be.

Shapes (columns present, times increasing, no gaps) are checked in `validate`; this
module checks values, with pandera schemas run lazily so that every failure is
collected before a reason is written. Bounds are in `BOUNDS`. What happens to a value
outside them depends on the signal:

- a **required** ego signal (x, v, lane) refuses the file, naming the signal, the
  line or message, and what to do;
- an **optional** ego signal (y, length, steer, throttle, brake) is emptied at those
  samples (length falls back to 4.5 m), with a warning saying how many;
- a **traffic** sample with an impossible value is dropped, with a warning saying
  how many samples of how many vehicles.

Also checked: the sample rate (1-1000 Hz) and jumps, a vehicle moving further
between two samples than its speed allows (refused for the ego, a warning for traffic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
import pandera.pandas as pdr
import pyarrow as pa
import pyarrow.compute as pc
from pandera.errors import SchemaErrors

from ingest.logformat import TOPIC_CONTROLS, TOPIC_EGO, TOPIC_TRAFFIC
from ingest.mapping import Mapping
from ingest.rawlog import RawLog, Rejected

MAX_LANE = 20  # lane indices above this are taken for a wrong column
MAX_SPEED_MPS = 100.0  # [m/s] 360 km/h: faster is not a car
MIN_SPEED_MPS = -10.0  # [m/s] reversing faster than this on a highway is not plausible
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 1000.0  # plausible sample rates of a driving simulator log
MAX_STEP_S = 3600.0  # [s] a longer pause between two samples of one recording is a broken time stamp
JUMP_FACTOR = 1.5  # a step may be this much longer than the faster of its two speeds allows ...
JUMP_SLACK_MPS = 5.0  # ... plus this speed [m/s] ...
JUMP_SLACK_M = 1.0  # ... plus this distance [m] (rounding, a logged speed lagging the position)


@dataclass(frozen=True)
class Bounds:
    """What a signal can physically be: lo..hi in its unit, optionally a whole number."""

    lo: float
    hi: float
    unit: str
    what: str  # a few words for messages ('a car's speed')
    integer: bool = False
    lo_open: bool = False  # lo itself is impossible (a length of 0)


BOUNDS: dict[str, Bounds] = {
    "ego_x_m": Bounds(-1e7, 1e7, "m", "a position on a road"),
    "ego_v_mps": Bounds(MIN_SPEED_MPS, MAX_SPEED_MPS, "m/s", "what a car does"),
    "ego_lane": Bounds(0, MAX_LANE, "", "a lane of the road", integer=True),
    "ego_y_m": Bounds(-100.0, 100.0, "m", "a lateral position on a road"),
    "ego_length_m": Bounds(0.0, 60.0, "m", "a vehicle length", lo_open=True),
    "steer_rad": Bounds(-4 * math.pi, 4 * math.pi, "rad", "two turns of a steering wheel"),
    "throttle": Bounds(0.0, 1.0, "", "a pedal position 0-1"),
    "brake": Bounds(0.0, 1.0, "", "a pedal position 0-1"),
}
TRAFFIC_BOUNDS: dict[str, Bounds] = {
    "x_m": BOUNDS["ego_x_m"],
    "v_mps": BOUNDS["ego_v_mps"],
    "lane": BOUNDS["ego_lane"],
    "y_m": BOUNDS["ego_y_m"],
    "length_m": BOUNDS["ego_length_m"],
}
EGO_REQUIRED = ("ego_x_m", "ego_v_mps", "ego_lane")
EGO_OPTIONAL = ("ego_y_m", "ego_length_m", "steer_rad", "throttle", "brake")
# EGO column -> (CSV canonical column, MCAP topic, MCAP field): how a signal is named in the file
_SOURCES = {
    "ego_x_m": ("ego_x", TOPIC_EGO, "x"),
    "ego_y_m": ("ego_y", TOPIC_EGO, "y"),
    "ego_v_mps": ("ego_v", TOPIC_EGO, "v"),
    "ego_lane": ("ego_lane", TOPIC_EGO, "lane"),
    "ego_length_m": ("ego_length", TOPIC_EGO, "length"),
    "steer_rad": ("steer", TOPIC_CONTROLS, "steer"),
    "throttle": ("throttle", TOPIC_CONTROLS, "throttle"),
    "brake": ("brake", TOPIC_CONTROLS, "brake"),
}
_TRAFFIC_FIELDS = {"x_m": "x", "v_mps": "v", "lane": "lane", "y_m": "y", "length_m": "length"}


def _checks(b: Bounds) -> list[pdr.Check]:
    # in_range is False for inf and -inf, so one check covers "finite" and "plausible"
    checks = [pdr.Check.in_range(b.lo, b.hi, include_min=not b.lo_open, name="range")]
    if b.integer:
        checks.append(pdr.Check(lambda s: s == np.round(s), name="integer"))
    return checks


_SCHEMA_BOUNDS: dict[str, dict[str, Bounds]] = {}  # schema name -> its columns' bounds (for `_all_pass`)


def _schema(name: str, bounds: dict[str, Bounds], columns: tuple[str, ...]) -> pdr.DataFrameSchema:
    _SCHEMA_BOUNDS[name] = {c: bounds[c] for c in columns}
    return pdr.DataFrameSchema(
        {c: pdr.Column(float, _checks(bounds[c]), nullable=True) for c in columns}, name=name, strict=False
    )


EGO_REQUIRED_SCHEMA = _schema("ego signals", BOUNDS, EGO_REQUIRED)
EGO_OPTIONAL_SCHEMA = _schema("optional ego signals", BOUNDS, EGO_OPTIONAL)
TRAFFIC_SCHEMA = _schema("traffic", TRAFFIC_BOUNDS, tuple(TRAFFIC_BOUNDS))


def _all_pass(df: pd.DataFrame, schema: pdr.DataFrameSchema) -> bool:
    """True when every column of `schema` is in `df` as float64 and each value is empty or within
    its bounds: what the schema's checks accept, tested in numpy (pandera costs ~10x more)."""
    bounds = _SCHEMA_BOUNDS.get(schema.name)
    if bounds is None or bounds.keys() != schema.columns.keys():
        return False
    for col, b in bounds.items():
        if col not in df.columns or df[col].dtype != np.float64:
            return False
        a = df[col].to_numpy()
        if not (_within(a, b) or _within_elementwise(a, b)):
            return False
    return True


def _within(a: np.ndarray, b: Bounds) -> bool:
    """True when `a` has no empty value and every value is within `b`: two reductions, no
    temporary array (a NaN makes min and max NaN, so such a column is left to the elementwise test)."""
    if not len(a) or b.integer:
        return False
    lo, hi = a.min(), a.max()
    return bool(((lo > b.lo) if b.lo_open else (lo >= b.lo)) and hi <= b.hi)


def _within_elementwise(a: np.ndarray, b: Bounds) -> bool:
    """True when each value of `a` is empty or within `b`."""
    with np.errstate(invalid="ignore"):
        inside = ((a > b.lo) if b.lo_open else (a >= b.lo)) & (a <= b.hi)
        if b.integer:
            inside &= a == np.round(a)
    return bool(np.all(inside | np.isnan(a)))


def failures(df: pd.DataFrame, schema: pdr.DataFrameSchema) -> dict[str, np.ndarray]:
    """Column -> sorted row positions that fail the schema's checks (empty when all pass).

    The usual case, every value inside its bounds, is found in numpy; pandera runs to
    collect the failing rows."""
    if _all_pass(df, schema):
        return {}
    try:
        schema.validate(df, lazy=True)
    except SchemaErrors as exc:
        fc = exc.failure_cases
        fc = fc[fc["index"].notna() & fc["column"].isin(df.columns)]
        return {str(col): np.unique(g["index"].to_numpy(dtype=np.int64)) for col, g in fc.groupby("column")}
    return {}


def signal_label(raw: RawLog, key: str, mapping: Mapping) -> str:
    """How an EGO signal is named in the file: "column 'ego_v'", "/ego/state.v" (as the reader names it)
    or "/driver/controls field 'steer'"."""
    column, topic, fld = _SOURCES[key]
    if key in raw.names:
        return raw.names[key] if raw.format == "mcap" else f"column {raw.names[key]!r}"
    if raw.format == "mcap":
        return f"{mapping.topic(topic)} field {mapping.msg_field(topic, fld)!r}"
    return f"column {mapping.column(column)!r}"


def describe(value: float, b: Bounds) -> str:
    """Why `value` is impossible for a signal with bounds `b` ('inf is not a finite number', ...)."""
    if not np.isfinite(value):
        return f"{value} is not a finite number"
    if b.integer and value != np.round(value):
        return f"{value:g} is not a lane index"
    unit = f" {b.unit}" if b.unit else ""
    limit = f"{b.lo:g}..{b.hi:g}{unit}"
    if b.integer:
        return f"{value:g} is outside the road (lanes {limit})"
    if value < b.lo or (b.lo_open and value == b.lo):
        return f"{value:g}{unit} is not {b.what} ({limit})"
    return f"{value:g}{unit} is beyond {b.what} ({limit})"


def check_ego_values(raw: RawLog, mapping: Mapping) -> list[str]:
    """Refuse impossible required ego values; empty impossible optional ones. Returns warnings."""
    ego = pd.DataFrame({k: raw.ego[k] for k in EGO_REQUIRED}, copy=False)
    bad = failures(ego, EGO_REQUIRED_SCHEMA)
    if bad:
        problems = []
        for key in EGO_REQUIRED:
            if key in bad:
                i = int(bad[key][0])
                problems.append((i, key, len(bad[key])))
        i, key, count = min(problems)
        label = signal_label(raw, key, mapping)
        value = float(raw.ego[key][i])
        more = f"; {count} such value(s) in {label}" if count > 1 else ""
        others = [f"{signal_label(raw, k, mapping)} ({c})" for _, k, c in problems if k != key]
        also = f"; also impossible values in {', '.join(others)}" if others else ""
        units = (
            f" (if the file is in km/h or mph, set speed under [units] {mapping.hint()})"
            if key == "ego_v_mps" and np.isfinite(value) and value > MAX_SPEED_MPS
            else ""
        )
        raise Rejected(
            f"{label} at {raw.locate(i)} (t={raw.t_s[i]:.3f} s): {describe(value, BOUNDS[key])}"
            f"{more}{also}; fix or cut those samples before ingesting{units}"
        )
    opt = pd.DataFrame({k: raw.ego[k] for k in EGO_OPTIONAL}, copy=False)
    warnings = []
    for key, rows in failures(opt, EGO_OPTIONAL_SCHEMA).items():
        i = int(rows[0])
        value = float(raw.ego[key][i])
        raw.ego[key] = raw.ego[key].copy()
        raw.ego[key][rows] = np.nan
        fallback = "4.5 m is used there" if key == "ego_length_m" else "left empty"
        warnings.append(
            f"{signal_label(raw, key, mapping)}: {len(rows)} of {len(opt)} value(s) impossible "
            f"(first {describe(value, BOUNDS[key])} at {raw.locate(i)}); {fallback}"
        )
    return warnings


def check_sample_rate(raw: RawLog, mapping: Mapping) -> None:
    """Refuse a log whose median sample rate is outside 1-1000 Hz (most often a time unit mix-up)
    or whose time jumps by more than an hour between two samples (a broken time stamp)."""
    steps = np.diff(raw.t_abs_s)
    big = np.flatnonzero(steps > MAX_STEP_S)
    if len(big):
        i = int(big[0])
        raise Rejected(
            f"time {raw.time_name!r} jumps {steps[i]:.4g} s at {raw.locate(i + 1)} (from "
            f"{raw.t_abs_s[i]:.6g} to {raw.t_abs_s[i + 1]:.6g} s), more than {MAX_STEP_S:g} s between two "
            f"samples; fix or cut the sample with the broken time before ingesting"
        )
    if len(raw.t_abs_s) < 3:
        return
    step = float(np.median(steps))
    rate = 1.0 / step if step > 0 else math.inf
    if MIN_RATE_HZ <= rate <= MAX_RATE_HZ:
        return
    hint = (
        f'set time = "ms" (or "us", "ns") under [units] {mapping.hint()}'
        if rate < MIN_RATE_HZ
        else f'set time = "s" or the right time_scale under [units] {mapping.hint()}'
    )
    raise Rejected(
        f"sample rate {rate:.3g} Hz (median step {step:.6g} s of {raw.time_name}) is outside "
        f"{MIN_RATE_HZ:g}-{MAX_RATE_HZ:g} Hz; if {raw.time_name} is not in seconds, {hint}"
    )


def _allowed_step(v0: np.ndarray, v1: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """How far a vehicle can move in `dt` between two samples with speeds v0 and v1 [m]."""
    # (JUMP_FACTOR * max(|v0|, |v1|) + JUMP_SLACK_MPS) * dt + JUMP_SLACK_M, in place: no temporary per step
    out = np.abs(np.asarray(v0, dtype=float))
    np.maximum(out, np.abs(v1), out=out)
    out *= JUMP_FACTOR
    out += JUMP_SLACK_MPS
    out *= dt
    out += JUMP_SLACK_M
    return out


def check_ego_jumps(raw: RawLog, mapping: Mapping) -> None:
    """Refuse an ego that moves further between two samples than its speed allows."""
    x, v, t = raw.ego["ego_x_m"], raw.ego["ego_v_mps"], raw.t_s
    if len(x) < 2:
        return
    dx = np.abs(np.diff(x))
    dt = np.diff(t)
    allowed = _allowed_step(v[:-1], v[1:], dt)
    jumps = np.flatnonzero(dx > allowed)
    if not len(jumps):
        return
    k = int(jumps[0])
    label = signal_label(raw, "ego_x_m", mapping)
    more = f"; {len(jumps)} such jumps" if len(jumps) > 1 else ""
    units = (
        f"; every other step is too long: check the position, speed and time units under [units] {mapping.hint()}"
        if len(jumps) > len(dx) / 2
        else "; fix or cut those samples before ingesting"
    )
    raise Rejected(
        f"{label} jumps {dx[k]:.4g} m in {dt[k]:.4g} s at {raw.locate(k + 1)} (t={t[k + 1]:.3f} s), "
        f"further than its speed ({max(abs(v[k]), abs(v[k + 1])):.3g} m/s) allows{more}{units}"
    )


def _traffic_label(raw: RawLog, mapping: Mapping, key: str) -> str:
    fld = _TRAFFIC_FIELDS[key]
    return f"field {mapping.msg_field(TOPIC_TRAFFIC, fld)!r}" if raw.format == "mcap" else fld


def check_traffic_values(raw: RawLog, mapping: Mapping) -> list[str]:
    """Drop traffic samples with impossible values (in place) and warn about jumps. Returns warnings."""
    tr = raw.traffic
    n = len(tr["t_s"])
    if n == 0:
        return []
    df = pd.DataFrame({k: tr[k] for k in TRAFFIC_BOUNDS}, copy=False)
    bad = failures(df, TRAFFIC_SCHEMA)
    warnings: list[str] = []
    ids = tr["vehicle_id"]
    if bad:
        drop = np.zeros(n, dtype=bool)
        for rows in bad.values():
            drop[rows] = True
        i = int(np.argmax(drop))
        key = next(k for k in TRAFFIC_BOUNDS if k in bad and i in bad[k])
        dropped_ids = pa.array(ids).filter(pa.array(drop)).unique()
        warnings.append(
            f"traffic: dropped {int(drop.sum())} of {n} vehicle sample(s) of {len(dropped_ids)} "
            f"vehicle(s) with impossible values (first: vehicle {_vid(ids, i)!r} "
            f"{_traffic_label(raw, mapping, key)} {describe(float(tr[key][i]), TRAFFIC_BOUNDS[key])} "
            f"at t={tr['t_s'][i]:.3f} s)"
        )
        keep = ~drop
        raw.traffic = tr = {
            k: (pa.array(a).filter(pa.array(keep)) if k == "vehicle_id" else a[keep]) for k, a in tr.items()
        }
        raw.n_vehicles = None
    known = raw.vehicle_grid if not bad else 0  # dropping rows may break the reader's grid
    k = known or _vehicle_grid(pa.array(tr["vehicle_id"]), len(tr["t_s"]))
    if k and raw.n_vehicles is None:
        raw.n_vehicles = k  # k vehicles in the same order at every sample: k distinct ids, nothing to count
    warnings += _traffic_jumps(tr, k)
    return warnings


def _vid(ids: Any, i: int) -> str:
    return str(ids[i].as_py() if isinstance(ids, pa.Array) else ids[i])


def _vehicle_grid(ids: pa.Array, n: int) -> int:
    """k when the rows are k vehicles in the same order at every sample (n = m * k rows, the
    usual simulator log): each vehicle's rows are then one column of an (m, k) grid. 0 otherwise."""
    if ids.null_count:
        return 0
    first = ids.slice(0, min(n, 4096)).to_pylist()
    seen: set[Any] = set()
    for k, vid in enumerate(first):  # noqa: B007 - k is read after the loop
        if vid in seen:
            break
        seen.add(vid)
    else:
        k = len(first)
    if k == 0 or n % k or k == n:
        return 0
    same = pc.all(pc.equal(ids.slice(k), ids.slice(0, n - k))).as_py()
    return k if same else 0


def _traffic_jumps(tr: dict[str, Any], k: int | None = None) -> list[str]:
    """A warning when traffic vehicles move further between their samples than their speed allows.

    `k`: the rows' `_vehicle_grid`, when the caller has it."""
    n = len(tr["t_s"])
    if n < 2:
        return []
    ids = pa.array(tr["vehicle_id"])
    k = _vehicle_grid(ids, n) if k is None else k
    if k:  # vehicle j's samples are column j of the (m, k) grids, in time order
        t, x, v = (tr[c].reshape(-1, k) for c in ("t_s", "x_m", "v_mps"))
        jump = (np.abs(np.diff(x, axis=0)) > _allowed_step(v[:-1], v[1:], np.diff(t, axis=0))).T
        if not jump.any():
            return []
        j, r = divmod(int(np.argmax(jump)), jump.shape[1])  # the first jump of the first vehicle
        count, vehicles = int(jump.sum()), int(jump.any(axis=1).sum())
        t0, t1, x0, x1, vid = t[r, j], t[r + 1, j], x[r, j], x[r + 1, j], _vid(tr["vehicle_id"], (r + 1) * k + j)
    else:
        codes = ids.dictionary_encode().indices
        # rows are in time order, and Arrow's sort is stable: each vehicle's rows stay sorted by time
        order = pc.sort_indices(codes).to_numpy()
        codes = codes.to_numpy(zero_copy_only=False)
        c, t, x, v = codes[order], tr["t_s"][order], tr["x_m"][order], tr["v_mps"][order]
        same = c[1:] == c[:-1]
        jumps = np.flatnonzero(same & (np.abs(np.diff(x)) > _allowed_step(v[:-1], v[1:], np.diff(t))))
        if not len(jumps):
            return []
        i = int(jumps[0])
        count, vehicles = len(jumps), len(np.unique(c[jumps]))
        t0, t1, x0, x1, vid = t[i], t[i + 1], x[i], x[i + 1], _vid(tr["vehicle_id"], int(order[i + 1]))
    return [
        f"traffic vehicle {vid!r} jumps {abs(x1 - x0):.4g} m in {t1 - t0:.4g} s at "
        f"t={t1:.3f} s, further than its speed allows ({count} such jump(s) in "
        f"{vehicles} vehicle(s)); kept"
    ]
