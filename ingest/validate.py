"""Checks on a `RawLog` and its conversion into the canonical EGO / TRAFFIC tables.

Every check either passes, adds a warning (the recording is kept), or raises
`Rejected` with one line saying what is wrong, where, and what fixes it.
"""

from __future__ import annotations

import unicodedata

from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from ingest.mapping import Mapping
from ingest.plausible import check_press_rate, check_samples, check_static_ego, ego_overlaps, speed_limit_problem
from ingest.rawlog import RawLog, Rejected
from ingest.values import check_ego_jumps, check_ego_values, check_sample_rate, check_traffic_values, signal_label
from laneprint.schemas import EGO, TRAFFIC, SchemaError

KMH_MEDIAN_MPS = 45.0  # [m/s] a median ego speed above this (162 km/h) is taken for km/h


@dataclass
class Canonical:
    """A validated recording: catalogue fields, tables and warnings."""

    meta: dict[str, Any]  # driver_id, session_id, speed_limit_kph, simulator
    ego: pd.DataFrame
    traffic: pd.DataFrame
    n_presses: int
    warnings: list[str]
    n_vehicles: int = 0  # distinct traffic vehicles
    traffic_parquet: Future[bytes] | bytes | None = None  # `traffic` encoded for the store, or being encoded

    def encoded_traffic(self) -> bytes | None:
        """`traffic` as the store writes it, when it was encoded beside the checks (None: not, or it
        does not fit the TRAFFIC schema; the store then encodes it and refuses it with the reason)."""
        if isinstance(self.traffic_parquet, Future):
            try:
                self.traffic_parquet = self.traffic_parquet.result()
            except SchemaError:
                self.traffic_parquet = None
        return self.traffic_parquet

    def __getstate__(self) -> dict[str, Any]:
        self.encoded_traffic()  # sent to another process (a Ray worker's result): the bytes, not the future
        return self.__dict__


def _check_time(raw: RawLog) -> None:
    t = raw.t_abs_s
    if np.isnan(t).any():
        i = int(np.argmax(np.isnan(t)))
        raise Rejected(f"time {raw.time_name!r} is empty at {raw.locate(i)}")
    if np.isinf(t).any() or np.isinf(raw.t_s).any():
        i = int(np.argmax(np.isinf(t) | np.isinf(raw.t_s)))
        raise Rejected(
            f"time {raw.time_name!r} at {raw.locate(i)}: {t[i]} is not a finite number; "
            f"fix or cut that sample before ingesting"
        )
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if len(bad):
        i = int(bad[0])
        more = f" ({len(bad) - 1} more)" if len(bad) > 1 else ""
        if dt[i] == 0:
            raise Rejected(
                f"duplicated time {raw.time_name}={t[i]:.6g} s at {raw.locate(i)} and {raw.locate(i + 1)}"
                f"{more}: each sample needs its own time"
            )
        raise Rejected(
            f"time not strictly increasing at {raw.locate(i + 1)}: {raw.time_name}={t[i + 1]:.6g} s "
            f"after {t[i]:.6g} s{more}; sort the samples by time"
        )


def _check_gaps(raw: RawLog) -> None:
    for key in ("ego_x_m", "ego_v_mps", "ego_lane"):
        nan = np.isnan(raw.ego[key])
        if not nan.any():
            continue
        edges = np.diff(np.concatenate([[0], nan.astype(np.int8), [0]]))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
        s, e = int(starts[0]), int(stops[0])
        name = raw.names.get(key, key)
        more = f" (and {len(starts) - 1} more gap(s), {int(nan.sum())} empty values in all)" if len(starts) > 1 else ""
        span = (
            f"at {raw.locate(s)} (t={raw.t_s[s]:.3f} s)"
            if s == e
            else f"from {raw.locate(s)} to {raw.locate(e)} (t={raw.t_s[s]:.3f}-{raw.t_s[e]:.3f} s)"
        )
        empty = "empty value(s)" if raw.format != "mcap" else "empty or non-numeric value(s)"
        raise Rejected(
            f"gap in required signal {name}: {e - s + 1} {empty} {span}{more}; fill or cut the gap before ingesting"
        )


def _check_kmh(raw: RawLog, mapping: Mapping) -> None:
    v = raw.ego["ego_v_mps"]
    med = float(np.median(v))
    if med > KMH_MEDIAN_MPS:
        raise Rejected(
            f"ego speed looks like km/h, not m/s (median {med:.1f}, i.e. {med * 3.6:.0f} km/h if it "
            f'were m/s): set speed = "km/h" under [units] {mapping.hint()}'
        )


def _unit_warnings(raw: RawLog) -> list[str]:
    """A warning when the ego speed disagrees with how fast ego_x changes (a unit mix-up)."""
    t, x, v = raw.t_abs_s, raw.ego["ego_x_m"], raw.ego["ego_v_mps"]
    if len(t) < 3:
        return []
    rate = np.abs(np.diff(x) / np.diff(t))
    moving = np.abs(v[1:]) > 1.0
    if moving.sum() < 2:
        return []
    observed = float(np.median(rate[moving]))
    logged = float(np.median(np.abs(v[1:][moving])))
    if observed <= 0 or not np.isfinite(observed):
        return []
    ratio = logged / observed
    if 0.5 <= ratio <= 2.0:
        return []
    return [
        f"ego speed (median {logged:.3g}) is {ratio:.3g}x the rate at which {raw.names.get('ego_x_m', 'ego_x')} "
        f"changes ({observed:.3g} per {raw.time_name} unit): check the units ([units] speed/position/time "
        f"in a --mapping file)"
    ]


def _directions(pressed: np.ndarray, raw_dirs: np.ndarray, warnings: list[str]) -> tuple[np.ndarray, int]:
    """Directions kept on the press samples only (first one given during the hold)."""
    n = len(pressed)
    out = np.full(n, None, dtype=object)
    edges = np.diff(np.concatenate([[0], pressed.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    odd: set[str] = set()
    for s, e in zip(starts, stops):
        for d in raw_dirs[s:e]:
            if d is None or d != d:
                continue
            d = str(d).strip().lower()
            if d in ("left", "right"):
                out[s] = d
                break
            odd.add(d)
    if odd:
        warnings.append(f"lc_direction values {', '.join(sorted(odd))} are not left/right; ignored")
    return out, len(starts)


#: A driver id longer than this is no id (it names files and figures) [characters].
MAX_ID_CHARS = 64


def clean_id(value: Any, what: str = "driver id") -> str:
    """`value` as an id: one Unicode form (NFC, so a composed and a decomposed name are one driver), at
    most `MAX_ID_CHARS`, no control characters; `Rejected` otherwise."""
    text = unicodedata.normalize("NFC", str(value)).strip()
    if len(text) > MAX_ID_CHARS:
        raise Rejected(f"{what} of {len(text)} characters: at most {MAX_ID_CHARS}")
    if any(unicodedata.category(c) == "Cc" for c in text):
        raise Rejected(f"{what} {text.encode('unicode_escape').decode()[:80]!r} holds control characters")
    return text


def resolve_driver(file_id: Any, default: Any, override: str | None, warnings: list[str]) -> str:
    """The file's own driver id wins; `--driver` fills in when it has none (a conflict warns). Each is
    checked and normalised by `clean_id`."""
    override = clean_id(override) if override else override
    default = clean_id(default) if default not in (None, "") else default
    own = clean_id(file_id) if file_id not in (None, "") else ""
    if own:
        if override and override != own:
            warnings.append(f"file says driver {own!r}; --driver {override!r} ignored for it")
        return own
    if override:
        return override
    if default not in (None, ""):
        return str(default)
    raise Rejected(
        "no driver id: the file has no driver_id (CSV column or MCAP session metadata); "
        "give one with --driver ID or a driver_id default under [metadata] in a --mapping file"
    )


def _strings(values: Any) -> pd.Series:
    """An Arrow-backed string column (cheap to validate and to write as Parquet)."""
    arr = values if isinstance(values, pa.Array) else pa.array(values, pa.string())
    return pd.Series(pd.arrays.ArrowStringArray(arr))


def traffic_frame(raw: RawLog) -> pd.DataFrame:
    """The TRAFFIC table of `raw` (columns in the schema's order; lanes as whole numbers)."""
    tr = raw.traffic
    with np.errstate(invalid="ignore"):  # lanes out of 0..MAX_LANE (NaN too) are dropped by the checks
        lanes = tr["lane"].astype(np.int64)
    return pd.DataFrame(
        {
            "t_s": tr["t_s"],
            "vehicle_id": _strings(tr["vehicle_id"]),
            "x_m": tr["x_m"],
            "y_m": tr["y_m"],
            "v_mps": tr["v_mps"],
            "lane": lanes,
            "length_m": tr["length_m"],
        },
        copy=False,
    )[TRAFFIC.names]  # no consolidation copy: each column stays its own block


def canonicalise(
    raw: RawLog, mapping: Mapping, session_default: str, driver: str | None, traffic: pd.DataFrame | None = None
) -> Canonical:
    """Check `raw` and build the EGO / TRAFFIC tables; `Rejected` on the first problem.
    `traffic`: `traffic_frame(raw)` when the caller has built it already (the checks build it anew
    when they drop samples: then the result's `traffic` is not that frame)."""
    traffic_read = raw.traffic
    if len(raw.t_s) == 0:
        raise Rejected("no samples: the log has a header but no data rows")
    check_samples(raw)
    _check_time(raw)
    check_sample_rate(raw, mapping)
    _check_gaps(raw)
    _check_kmh(raw, mapping)
    warnings = list(raw.warnings) + check_ego_values(raw, mapping)
    check_ego_jumps(raw, mapping)
    check_static_ego(raw, signal_label(raw, "ego_x_m", mapping))
    warnings += check_traffic_values(raw, mapping) + _unit_warnings(raw)
    ego_overlaps(raw, warnings)
    meta = dict(raw.meta)
    meta["driver_id"] = resolve_driver(meta.get("driver_id"), mapping.defaults.get("driver_id"), driver, warnings)
    meta["session_id"] = str(meta.get("session_id") or mapping.defaults.get("session_id") or session_default)
    for key in ("speed_limit_kph", "simulator"):
        if meta.get(key) is None and mapping.defaults.get(key) is not None:
            meta[key] = mapping.defaults[key]
    sl = meta.get("speed_limit_kph")
    problem = speed_limit_problem(sl)
    if problem:
        raise Rejected(f"{problem}; fix the file's speed_limit_kph")
    meta["speed_limit_kph"] = float(sl) if sl is not None and str(sl).strip() else float("nan")
    meta["simulator"] = None if meta.get("simulator") is None else str(meta["simulator"])

    e = raw.ego
    pressed = e["lc_button"].astype(bool)
    check_press_rate(raw, pressed, warnings)
    directions, n_presses = _directions(pressed, e["lc_direction"], warnings)
    if n_presses == 0:
        warnings.append(
            "no lane-change button presses: the recording holds no decisions"
            + ("" if raw.has_button else " (no lc_button signal in the file)")
        )
    length = np.where(np.isnan(e["ego_length_m"]), 4.5, e["ego_length_m"])
    ego = pd.DataFrame(
        {
            "t_s": raw.t_s,
            "ego_x_m": e["ego_x_m"],
            "ego_y_m": e["ego_y_m"],
            "ego_v_mps": e["ego_v_mps"],
            "ego_lane": e["ego_lane"].astype(np.int64),
            "ego_length_m": length,
            "steer_rad": e["steer_rad"],
            "throttle": e["throttle"],
            "brake": e["brake"],
            "lc_button": pressed,
            "lc_direction": pd.Series(directions, dtype=object),
        },
        copy=False,
    )
    if traffic is None or raw.traffic is not traffic_read:  # the checks dropped samples
        traffic = traffic_frame(raw)
    n_vehicles = raw.n_vehicles if raw.n_vehicles is not None else int(traffic["vehicle_id"].nunique())
    return Canonical(
        meta=meta, ego=ego[EGO.names], traffic=traffic, n_presses=n_presses, warnings=warnings, n_vehicles=n_vehicles
    )
