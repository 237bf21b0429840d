"""Named tables and their columns: the contract between the stages.

Every table a stage writes to the workspace is described here, with units in the
column names (`_s` seconds, `_m` metres, `_mps` metres per second, `_kph` km/h).
`validate(df, SCHEMA)` checks a frame at a boundary (before it is stored, after it
is read from outside) and raises `SchemaError` with a one-line reason.

A stage may add columns of its own; the ones listed here are the contract.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd


class SchemaError(ValueError):
    """A table does not match its schema."""


@dataclass(frozen=True)
class Column:
    name: str
    kind: str  # "float", "int", "bool", "str"
    doc: str
    nullable: bool = False


@dataclass(frozen=True)
class Schema:
    name: str
    doc: str
    columns: tuple[Column, ...]

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.columns]


_KIND_CHECKS = {
    "float": pd.api.types.is_numeric_dtype,
    "int": pd.api.types.is_integer_dtype,
    "bool": pd.api.types.is_bool_dtype,
    "str": lambda s: pd.api.types.is_string_dtype(s) or pd.api.types.is_object_dtype(s),
}


def validate(df: pd.DataFrame, schema: Schema) -> pd.DataFrame:
    """Check that `df` has the schema's columns, kinds and no nulls where not allowed.

    Returns `df` unchanged so it can be used inline. Raises `SchemaError`.
    """
    missing = [c.name for c in schema.columns if c.name not in df.columns]
    if missing:
        raise SchemaError(f"{schema.name}: missing column(s) {', '.join(missing)}")
    for col in schema.columns:
        series = df[col.name]
        if not col.nullable and _has_empty(series):
            raise SchemaError(f"{schema.name}: column {col.name} has empty values")
        if series.dtype == object:  # judged by the kind of its values
            series = series[series.notna()].infer_objects()
        if len(series) and not _KIND_CHECKS[col.kind](series):
            raise SchemaError(f"{schema.name}: column {col.name} should be {col.kind}, got {df[col.name].dtype}")
    return df


def _has_empty(series: pd.Series) -> bool:
    """True when `series` holds an empty value (None, NaN, NA); numpy columns tested without a mask
    (a NaN makes the minimum NaN), a third of the time of `isna().any()` on a recording's traffic."""
    dtype = series.dtype
    if isinstance(dtype, np.dtype) and dtype.kind in "iub":
        return False
    if isinstance(dtype, np.dtype) and dtype.kind == "f":
        values = series.to_numpy()
        return bool(len(values)) and bool(np.isnan(values.min()))
    return bool(series.isna().any())


# --- ingest ---------------------------------------------------------------

EGO = Schema(
    "ego",
    "Ego samples of one recording, one row per sample, sorted by strictly increasing t_s.",
    (
        Column("t_s", "float", "time since the recording's first sample [s]"),
        Column("ego_x_m", "float", "longitudinal position of the ego's centre [m]"),
        Column("ego_y_m", "float", "lateral position, left positive [m]", nullable=True),
        Column("ego_v_mps", "float", "ego speed [m/s]"),
        Column("ego_lane", "int", "lane index, 0 = rightmost"),
        Column("ego_length_m", "float", "ego length [m] (4.5 when not logged)"),
        Column("steer_rad", "float", "steering input [rad]", nullable=True),
        Column("throttle", "float", "throttle 0-1", nullable=True),
        Column("brake", "float", "brake 0-1", nullable=True),
        Column("lc_button", "bool", "lane-change button held"),
        Column("lc_direction", "str", "'left'/'right' where recorded on a press", nullable=True),
    ),
)

TRAFFIC = Schema(
    "traffic",
    "Traffic vehicles of one recording in long form: one row per vehicle per sample it is in the scene.",
    (
        Column("t_s", "float", "time since the recording's first sample [s] (same clock as ego)"),
        Column("vehicle_id", "str", "stable id of the vehicle"),
        Column("x_m", "float", "longitudinal position of the vehicle's centre [m]"),
        Column("y_m", "float", "lateral position [m]", nullable=True),
        Column("v_mps", "float", "speed [m/s]"),
        Column("lane", "int", "lane index, 0 = rightmost"),
        Column("length_m", "float", "length [m] (4.5 when not logged)"),
    ),
)

RECORDINGS = Schema(
    "recordings",
    "Catalogue of ingested recordings, one row each (rejected files are in REJECTED).",
    (
        Column("recording_id", "str", "first 16 hex digits of the XXH3-128 of the bytes (SHA-256 before 2026-12-03)"),
        Column("driver_id", "str", "who drove"),
        Column("session_id", "str", "this recording (file name stem when not given)"),
        Column("speed_limit_kph", "float", "posted limit [km/h]", nullable=True),
        Column("simulator", "str", "free text", nullable=True),
        Column("source_name", "str", "file name as given"),
        Column("source_path", "str", "absolute path at ingest time"),
        Column("format", "str", "'csv', 'csv.gz' or 'mcap'"),
        Column("n_samples", "int", "ego samples"),
        Column("duration_s", "float", "last minus first sample time [s]"),
        Column("n_presses", "int", "rising edges of the lane-change button"),
        Column("n_vehicles", "int", "distinct traffic vehicles"),
        Column("status", "str", "'ok' or 'warning'"),
        Column("warnings", "str", "'; '-joined warnings, empty when none"),
        Column("ingested_at", "str", "ISO 8601 UTC time of ingest"),
    ),
)

REJECTED = Schema(
    "rejected",
    "Files an ingest refused, with the reason; the latest attempt per file content.",
    (
        Column("content_hash", "str", "first 16 hex digits of the XXH3-128 of the bytes ('' if unreadable)"),
        Column("source_name", "str", "file name as given"),
        Column("source_path", "str", "absolute path at ingest time"),
        Column("format", "str", "detected or guessed format"),
        Column("reason", "str", "one line the user can act on"),
        Column("rejected_at", "str", "ISO 8601 UTC time"),
    ),
)

# --- indicators -------------------------------------------------------------

DECISIONS = Schema(
    "decisions",
    "Decision points: every button press (label 'change') and the 'not yet' states "
    "before it (label 'keep'), with the scene around the ego and the indicators. "
    "Undefined indicators are NaN with a status saying why, never a sentinel.",
    (
        Column("driver_id", "str", ""),
        Column("recording_id", "str", ""),
        Column("session_id", "str", ""),
        Column("decision_id", "str", "'<recording_id>:<press index>' shared by a press and its not-yet states"),
        Column("t_s", "float", "time of this state [s]"),
        Column("press_t_s", "float", "time of the press this state belongs to [s]"),
        Column("label", "str", "'change' at the press, 'keep' before it"),
        Column("speed_limit_kph", "float", "", nullable=True),
        Column("ego_v_mps", "float", ""),
        Column("ego_x_m", "float", ""),
        Column("ego_lane", "int", ""),
        Column("target_lane", "int", ""),
        Column("cancelled", "bool", "press not followed by a lane change"),
        Column("f_present", "bool", "a leader in the ego lane"),
        Column("f_x_m", "float", "", nullable=True),
        Column("f_v_mps", "float", "", nullable=True),
        Column("f_gap_m", "float", "bumper-to-bumper gap [m]", nullable=True),
        Column("t_f_s", "float", "TTC to the ego-lane leader [s]", nullable=True),
        Column("t_f_status", "str", "'ok', 'absent' or 'not_closing'"),
        Column("nf_present", "bool", "a leader in the target lane"),
        Column("nf_x_m", "float", "", nullable=True),
        Column("nf_v_mps", "float", "", nullable=True),
        Column("nf_gap_m", "float", "", nullable=True),
        Column("t_nf_s", "float", "TTC to the target-lane leader [s]", nullable=True),
        Column("t_nf_status", "str", "'ok', 'absent' or 'not_closing'"),
        Column("nb_present", "bool", "a follower in the target lane"),
        Column("nb_x_m", "float", "", nullable=True),
        Column("nb_v_mps", "float", "", nullable=True),
        Column("nb_gap_m", "float", "", nullable=True),
        Column("dv_nb_mps", "float", "v_ego - v_nb [m/s]", nullable=True),
        Column("dv_nb_status", "str", "'ok', 'absent' or 'far' (follower beyond the no-influence distance)"),
    ),
)

REFERENCE_LINES = Schema(
    "reference_lines",
    "Lines I = A * v_e[m/s] + b per style or driver and indicator; what the RL stage reads.",
    (
        Column("scope", "str", "'style' or 'driver'"),
        Column("name", "str", "style name (Defensive/Normal/Aggressive) or driver id"),
        Column("kind", "str", "'typical' (the style's typical driver), 'pooled' (all members), 'driver', or 'paper'"),
        Column(
            "indicator",
            "str",
            "'t_f', 't_nf', 'dv_nb' (the study's, which the agents read) or an "
            "indicator of what drivers accept (gap_f, thw_f, dv_f, gap_nf, dv_nf, gap_nb, thw_nb)",
        ),
        Column("A", "float", "slope [indicator unit per m/s]; 0 for a level (column 'fit' = 'level')"),
        Column("b", "float", "intercept [s] for times, [m] for gaps, [m/s] for relative speeds"),
        Column("A_lo", "float", "95 % CI", nullable=True),
        Column("A_hi", "float", "95 % CI", nullable=True),
        Column("b_lo", "float", "95 % CI", nullable=True),
        Column("b_hi", "float", "95 % CI", nullable=True),
        Column("r2", "float", "", nullable=True),
        Column("n", "int", "points in the fit"),
        Column("source", "str", "provenance, e.g. 'typical driver D03', 'pooled over 4 drivers', 'Table 1'"),
    ),
)
