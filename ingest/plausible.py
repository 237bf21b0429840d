"""Physical plausibility of a well-formed recording: what no real drive can look like.

Each value may be in its bounds (`ingest.values`) and the recording still not be a
drive: the ego listed among its own traffic, an ego that stands still while its
speed says it drives, a button that toggles faster than a hand can press, a single
sample, a speed limit no road has. Such a recording would otherwise pass as a driver
(often as its style's most typical one), so each case is refused with one line
(`Rejected`) or kept with a warning that says what was changed:

- fewer than `MIN_SAMPLES` samples: refused (no time to measure anything in);
- a speed limit that is not a finite number in (0, `MAX_SPEED_LIMIT_KPH`] km/h: refused;
- an ego that moves less than `STATIC_FRACTION` of the distance its speed adds up to
  (and that distance is at least `STATIC_MIN_M`): refused (a frozen position signal);
- a button pressed again less than `MIN_PRESS_INTERVAL_S` after a press, for most of
  the presses, or more than `MAX_MEAN_PRESS_RATE_HZ` presses a second over the whole
  recording: refused (a toggling or noisy signal, not decisions); a few such presses:
  a warning;
- a traffic vehicle overlapping the ego (same lane, gap <= 0 m) at `EGO_COPY_FRACTION`
  of its samples: the ego listed among its own traffic; its samples are dropped with a
  warning. Shorter overlaps (a collision, or positions off) are kept with a warning.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pyarrow as pa

from ingest.rawlog import RawLog, Rejected

MIN_SAMPLES = 2  # a recording of one sample has no duration: nothing in it can be measured
MAX_SPEED_LIMIT_KPH = 300.0  # no road's limit is higher; an unlimited road is an empty limit, not inf
STATIC_MIN_M = 20.0  # [m] the speed must add up to at least this before a still position is judged
STATIC_FRACTION = 0.05  # an ego moving less than this share of what its speed adds up to is frozen
# The fastest voluntary finger tapping is 5-7 taps a second; a lane-change press is a decision that a
# manoeuvre follows, so two presses 0.2 s apart are a bouncing contact or a toggling signal, not two
# decisions. Over a whole recording a person presses every few seconds at the very most.
MIN_PRESS_INTERVAL_S = 0.2
MAX_MEAN_PRESS_RATE_HZ = 1.0
MIN_PRESSES_FOR_RATE = 10  # the mean rate is judged on at least this many presses
EGO_COPY_FRACTION = 0.9  # a vehicle overlapping the ego at this share of its samples is the ego itself
DEFAULT_LENGTH_M = 4.5


def speed_limit_problem(value: Any) -> str | None:
    """Why `value` [km/h] cannot be a road's speed limit, or None when it can (None/empty: unknown, fine)."""
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    if isinstance(value, bool):
        return f"speed limit {value!r} is not a number"
    try:
        kph = float(value)
    except (TypeError, ValueError):
        return f"speed limit {str(value)[:40]!r} is not a number"
    if math.isnan(kph):
        return None  # an empty limit as the tables store it
    if not math.isfinite(kph):
        return f"speed limit {kph} km/h is not a finite number (for a road without a limit leave it empty)"
    if kph <= 0 or kph > MAX_SPEED_LIMIT_KPH:
        return f"speed limit {kph:g} km/h is not a road's (0-{MAX_SPEED_LIMIT_KPH:g} km/h, or empty when unknown)"
    return None


def check_samples(raw: RawLog) -> None:
    """`Rejected` for a recording with fewer than `MIN_SAMPLES` samples."""
    n = len(raw.t_s)
    if 0 < n < MIN_SAMPLES:
        raise Rejected(
            f"one sample only (at {raw.locate(0)}): a recording needs at least {MIN_SAMPLES} "
            f"samples to measure anything"
        )


def check_static_ego(raw: RawLog, label: str) -> None:
    """`Rejected` when the ego's position stands (nearly) still while its speed says it drives."""
    t, x, v = raw.t_s, raw.ego["ego_x_m"], raw.ego["ego_v_mps"]
    if len(t) < 2:
        return
    dt = np.diff(t)
    by_speed = float(np.sum(np.abs(v[:-1]) * dt))
    if not np.isfinite(by_speed) or by_speed < STATIC_MIN_M:
        return
    moved = float(np.sum(np.abs(np.diff(x))))
    if moved >= STATIC_FRACTION * by_speed:
        return
    raise Rejected(
        f"{label} moves {moved:.3g} m in {t[-1] - t[0]:.4g} s while the ego speed adds up to "
        f"{by_speed:.4g} m (median {float(np.median(np.abs(v))):.3g} m/s): a position that does not "
        f"follow the speed (a frozen or wrong position signal); fix it before ingesting"
    )


def check_press_rate(raw: RawLog, pressed: np.ndarray, warnings: list[str]) -> None:
    """`Rejected` when the button toggles faster than a person presses; a warning for a few fast presses."""
    if pressed.sum() == 0:
        return
    edges = np.diff(np.concatenate([[0], pressed.astype(np.int8)]))
    starts = np.flatnonzero(edges == 1)
    if len(starts) < 2:
        return
    t = raw.t_s
    gaps = np.diff(t[starts])
    fast = int(np.sum(gaps < MIN_PRESS_INTERVAL_S))
    duration = float(t[-1] - t[0])
    rate = len(starts) / duration if duration > 0 else math.inf
    label = raw.names.get("lc_button", "the lane-change button")
    if (fast >= 3 and fast > len(starts) / 2) or (
        len(starts) >= MIN_PRESSES_FOR_RATE and rate > MAX_MEAN_PRESS_RATE_HZ
    ):
        raise Rejected(
            f"{label} is pressed {len(starts)} times in {duration:.4g} s ({rate:.3g} a second; "
            f"{fast} presses less than {MIN_PRESS_INTERVAL_S:g} s after the one before): faster than a "
            f"person presses, a toggling or noisy signal; check which signal is the button"
        )
    if fast:
        k = int(np.flatnonzero(gaps < MIN_PRESS_INTERVAL_S)[0]) + 1
        warnings.append(
            f"{fast} lane-change press(es) less than {MIN_PRESS_INTERVAL_S:g} s after the one before "
            f"(first at t={t[starts[k]]:.3f} s): a bouncing button? kept as presses"
        )


def ego_overlaps(raw: RawLog, warnings: list[str]) -> None:
    """Drop a traffic vehicle that overlaps the ego at nearly every sample (the ego itself listed as
    traffic), with a warning; warn about shorter overlaps. In place on `raw.traffic`."""
    tr = raw.traffic
    n = len(tr["t_s"])
    if n == 0 or len(raw.t_s) == 0:
        return
    t = raw.t_s
    i = np.clip(np.searchsorted(t, tr["t_s"]), 1, max(len(t) - 1, 1)) if len(t) > 1 else np.zeros(n, dtype=np.int64)
    if len(t) > 1:  # the nearer of the ego samples either side
        i = np.where(np.abs(t[i - 1] - tr["t_s"]) <= np.abs(t[i] - tr["t_s"]), i - 1, i)
    half_step = float(np.median(np.diff(t))) / 2 if len(t) > 1 else 0.0
    at_sample = np.abs(t[i] - tr["t_s"]) <= half_step + 1e-6
    ego_len = raw.ego["ego_length_m"][i]
    length = np.where(np.isnan(tr["length_m"]), DEFAULT_LENGTH_M, tr["length_m"])
    ego_len = np.where(np.isnan(ego_len), DEFAULT_LENGTH_M, ego_len)
    with np.errstate(invalid="ignore"):
        gap = np.abs(tr["x_m"] - raw.ego["ego_x_m"][i]) - (length + ego_len) / 2
        overlap = at_sample & (tr["lane"] == raw.ego["ego_lane"][i]) & (gap <= 0)
    if not overlap.any():
        return
    codes = pa.array(tr["vehicle_id"]).dictionary_encode()
    idx = codes.indices.to_numpy(zero_copy_only=False)
    names = codes.dictionary
    total = np.bincount(idx, minlength=len(names))
    over = np.bincount(idx, weights=overlap, minlength=len(names))
    copies = np.flatnonzero((over >= 2) & (over >= EGO_COPY_FRACTION * total))
    if len(copies):
        drop = np.isin(idx, copies)
        ids = ", ".join(repr(str(names[int(c)].as_py())) for c in copies[:3]) + (" ..." if len(copies) > 3 else "")
        warnings.append(
            f"traffic vehicle(s) {ids} overlap the ego (same lane, gap <= 0 m) at "
            f"{int(over[copies].sum())} of {int(total[copies].sum())} samples: the ego listed among its "
            f"own traffic; dropped"
        )
        keep = ~drop
        raw.traffic = {k: (pa.array(a).filter(pa.array(keep)) if k == "vehicle_id" else a[keep]) for k, a in tr.items()}
        raw.n_vehicles = None
        raw.vehicle_grid = 0
        overlap = overlap[keep]
        idx = idx[keep]
        tr = raw.traffic
    if overlap.any():
        first = int(np.argmax(overlap))
        vehicles = len(np.unique(idx[overlap]))
        warnings.append(
            f"traffic vehicle {str(names[int(idx[first])].as_py())!r} overlaps the ego (same lane, gap "
            f"<= 0 m) at t={tr['t_s'][first]:.3f} s ({int(overlap.sum())} sample(s) of {vehicles} "
            f"vehicle(s)): a collision or wrong positions; kept"
        )
