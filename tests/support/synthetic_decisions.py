"""Small synthetic inputs for tests and benchmarks of the analysis stage.

`make_recording` builds EGO/TRAFFIC frames from constant-speed vehicles (exact
positions, so TTCs can be computed by hand); `make_decision_table` draws a whole
decisions table for many drivers directly (no traffic simulation), with the
styles' lines of Table 1, for timing `analyze_tables` at scale.
"""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np
import pandas as pd

from laneprint.reference import PAPER_TABLE1, STYLES


def make_recording(
    duration_s: float,
    hz: float,
    ego_v: float,
    lanes: Iterable[tuple[float, int]],
    presses: Iterable[tuple[float, float, str | None]] = (),
    vehicles: Iterable[tuple[str, float, float, int, float]] = (),
    ego_x0: float = 0.0,
    recording_id: str = "rec0",
    driver_id: str = "D01",
    speed_limit_kph: float | None = 70.0,
) -> tuple[dict[str, Any], pd.DataFrame, pd.DataFrame]:
    """(meta, ego, traffic) of a constant-speed scene.

    `lanes`: (from_t, lane) steps of the ego's lane, e.g. [(0, 0), (7.0, 1)].
    `presses`: (t, held_s, direction or None). `vehicles`: (id, x0, v, lane, length);
    position x0 + v t. Samples at t = i / hz.
    """
    t = np.round(np.arange(0, duration_s + 1e-9, 1.0 / hz), 9)
    lane = np.zeros(len(t), dtype=np.int64)
    for t_from, ln in sorted(lanes):
        lane[t >= t_from - 1e-9] = ln
    btn = np.zeros(len(t), dtype=bool)
    direction = np.full(len(t), None, dtype=object)
    for t_p, held, d in presses:
        on = (t >= t_p - 1e-9) & (t < t_p + held - 1e-9)
        btn[on] = True
        direction[np.argmax(on)] = d
    ego = pd.DataFrame(
        {
            "t_s": t,
            "ego_x_m": ego_x0 + ego_v * t,
            "ego_y_m": np.nan,
            "ego_v_mps": float(ego_v),
            "ego_lane": lane,
            "ego_length_m": 4.5,
            "steer_rad": np.nan,
            "throttle": np.nan,
            "brake": np.nan,
            "lc_button": btn,
            "lc_direction": direction,
        }
    )
    frames = [
        pd.DataFrame(
            {
                "t_s": t,
                "vehicle_id": vid,
                "x_m": x0 + v * t,
                "y_m": np.nan,
                "v_mps": float(v),
                "lane": np.int64(ln),
                "length_m": float(length),
            }
        )
        for vid, x0, v, ln, length in vehicles
    ]
    traffic = (
        pd.concat(frames, ignore_index=True)
        if frames
        else pd.DataFrame(
            {
                "t_s": pd.Series(dtype=float),
                "vehicle_id": pd.Series(dtype=object),
                "x_m": pd.Series(dtype=float),
                "y_m": pd.Series(dtype=float),
                "v_mps": pd.Series(dtype=float),
                "lane": pd.Series(dtype="int64"),
                "length_m": pd.Series(dtype=float),
            }
        )
    )
    meta = {
        "recording_id": recording_id,
        "driver_id": driver_id,
        "session_id": recording_id,
        "speed_limit_kph": speed_limit_kph,
    }
    return meta, ego, traffic


def make_decision_table(
    n_drivers: int,
    n_decisions: int,
    seed: int = 0,
    keep_per_press: int = 10,
    noise: float = 0.12,
    p_nf_absent: float = 0.2,
) -> tuple[pd.DataFrame, dict[str, str]]:
    """A decisions table for `n_drivers` x `n_decisions` presses (+ keep states), and the true styles.

    Drivers are spread evenly over the three styles of Table 1; each driver's lines
    are the style's lines with a small personal offset, and every decision scatters
    around them with relative noise `noise`. Speeds cover 60-95 km/h.
    """
    rng = np.random.default_rng(seed)
    rows = []
    truth: dict[str, str] = {}
    n = n_decisions
    for d in range(n_drivers):
        style = STYLES[d % len(STYLES)]
        did = f"D{d:04d}"
        truth[did] = style
        lines = PAPER_TABLE1[style]
        limit = rng.choice([60.0, 70.0, 80.0, 90.0], size=n)
        v = (limit + rng.uniform(-3, 5, size=n)) / 3.6
        scale = 1 + rng.normal(0, 0.03)
        vals = {}
        for ind in ("t_f", "t_nf", "dv_nb"):
            a, b = lines[ind]
            mean = (a * v + b) * (scale if ind != "dv_nb" else 1.0)
            sd = noise * np.abs(mean) if ind != "dv_nb" else 1.5
            vals[ind] = mean + rng.normal(0, 1, size=n) * sd
        vals["t_f"] = np.maximum(vals["t_f"], 0.3)
        vals["t_nf"] = np.maximum(vals["t_nf"], 0.3)
        nf_absent = rng.random(n) < p_nf_absent
        rid = f"r{d:04d}"
        for k in range(keep_per_press + 1):
            lab = "change" if k == 0 else "keep"
            grow = 1 + 0.15 * k
            rows.append(
                pd.DataFrame(
                    {
                        "driver_id": did,
                        "recording_id": rid,
                        "session_id": rid,
                        "decision_id": [f"{rid}:{i}" for i in range(n)],
                        "t_s": np.arange(n) * 60.0 - 0.5 * k,
                        "press_t_s": np.arange(n) * 60.0,
                        "label": lab,
                        "speed_limit_kph": limit,
                        "ego_v_mps": v,
                        "ego_x_m": 0.0,
                        "ego_lane": 0,
                        "target_lane": 1,
                        "cancelled": False,
                        "t_f_s": vals["t_f"] * grow,
                        "t_nf_s": np.where(nf_absent, np.nan, vals["t_nf"] / grow),
                        "dv_nb_mps": vals["dv_nb"],
                    }
                )
            )
    df = pd.concat(rows, ignore_index=True)
    df["f_present"] = True
    df["t_f_status"] = "ok"
    df["nf_present"] = df["t_nf_s"].notna()
    df["t_nf_status"] = np.where(df["nf_present"], "ok", "absent")
    df["nb_present"] = True
    df["dv_nb_status"] = "ok"
    for role in ("f", "nf", "nb"):
        for c in ("x_m", "v_mps", "gap_m"):
            df[f"{role}_{c}"] = np.nan
    return df, truth


def catalogue_row(meta: dict[str, Any], ego: pd.DataFrame, traffic: pd.DataFrame) -> dict[str, Any]:
    """A RECORDINGS row for frames built in memory (tests, benchmarks), so they can be
    stored with `Workspace.write_recording` without going through files and ingest."""
    import hashlib

    sid = str(meta.get("session_id") or meta.get("recording_id"))
    rid = meta.get("recording_id") or hashlib.sha256(f"{meta.get('driver_id')}/{sid}".encode()).hexdigest()[:16]
    btn = ego["lc_button"].to_numpy(dtype=bool)
    return {
        "recording_id": str(rid),
        "driver_id": str(meta["driver_id"]),
        "session_id": sid,
        "speed_limit_kph": meta.get("speed_limit_kph"),
        "simulator": meta.get("simulator", "in memory"),
        "source_name": f"{sid}.memory",
        "source_path": f"/memory/{sid}",
        "format": "csv",
        "n_samples": int(len(ego)),
        "duration_s": float(ego["t_s"].iloc[-1] - ego["t_s"].iloc[0]) if len(ego) else 0.0,
        "n_presses": int((btn & ~np.r_[False, btn[:-1]]).sum()),
        "n_vehicles": int(traffic["vehicle_id"].nunique()),
        "status": "ok",
        "warnings": "",
        "ingested_at": "2026-01-01T00:00:00Z",
    }
