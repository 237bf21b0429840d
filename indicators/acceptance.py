"""Indicators of what a driver accepts: gaps, time headways and relative speeds at each state.

The study reads a decision through three times to collision, which are undefined
whenever a leader is not closing in (in real traffic, often). The lane-change
literature reads it as much through the gaps the driver accepts. Computed from the
scene columns of a decisions table (`f_*`, `nf_*`, `nb_*`, `ego_v_mps`), so any
decisions table gets them, old workspaces included.

Each indicator has a status column; undefined values are NaN, never a sentinel:

| indicator | column | unit | definition | undefined (status) |
|---|---|---|---|---|
| gap_f | f_gap_m | m | bumper-to-bumper gap to `C_f` | no `C_f` ('absent') |
| thw_f | thw_f_s | s | f_gap_m / v_e: time headway to `C_f` | no `C_f` ('absent'); v_e < `MIN_SPEED_MPS` ('stopped') |
| dv_f | dv_f_mps | m/s | v_e - v_f (> 0: closing in) | no `C_f` ('absent') |
| gap_nf | nf_gap_m | m | lead gap to `C_nf` in the target lane | no `C_nf` ('absent') |
| dv_nf | dv_nf_mps | m/s | v_e - v_nf | no `C_nf` ('absent') |
| gap_nb | nb_gap_m | m | lag gap to `C_nb` in the target lane | no `C_nb` ('absent'); kept, status 'far', beyond `far_follower_m` |
| thw_nb | thw_nb_s | s | nb_gap_m / v_nb: time headway of `C_nb` to the ego | no `C_nb` ('absent'); v_nb < `MIN_SPEED_MPS` ('stopped'); 'far' as gap_nb |

'far' values are kept in the table and left out of fits unless `fit_far_followers`,
as for the study's `dv_nb`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from indicators.settings import AnalysisSettings

MIN_SPEED_MPS = 0.5  # below this a time headway (gap / speed) says nothing

#: indicator -> (value column, status column, unit)
ACCEPTANCE_COLUMNS: dict[str, tuple[str, str, str]] = {
    "gap_f": ("f_gap_m", "gap_f_status", "m"),
    "thw_f": ("thw_f_s", "thw_f_status", "s"),
    "dv_f": ("dv_f_mps", "dv_f_status", "m/s"),
    "gap_nf": ("nf_gap_m", "gap_nf_status", "m"),
    "dv_nf": ("dv_nf_mps", "dv_nf_status", "m/s"),
    "gap_nb": ("nb_gap_m", "gap_nb_status", "m"),
    "thw_nb": ("thw_nb_s", "thw_nb_status", "s"),
}
DERIVED_COLUMNS: tuple[str, ...] = ("thw_f_s", "dv_f_mps", "dv_nf_mps", "thw_nb_s") + tuple(
    status for _, status, _ in ACCEPTANCE_COLUMNS.values()
)


def _status(present: np.ndarray, *rules: tuple[np.ndarray, str]) -> np.ndarray:
    """'absent' where not present, else the first rule's name whose mask holds, else 'ok'."""
    out = np.where(present, "ok", "absent").astype(object)
    for mask, name in reversed(rules):
        out[present & mask] = name
    return out


def add_acceptance(decisions: pd.DataFrame, settings: AnalysisSettings | None = None) -> pd.DataFrame:
    """`decisions` with the acceptance indicators and their statuses (a new frame; existing
    columns of those names are recomputed)."""
    settings = settings or AnalysisSettings()
    d = decisions.copy()
    v_e = d["ego_v_mps"].to_numpy(dtype=float)

    def col(name: str) -> np.ndarray:
        return d[name].to_numpy(dtype=float) if name in d else np.full(len(d), np.nan)

    f_gap, f_v = col("f_gap_m"), col("f_v_mps")
    nf_gap, nf_v = col("nf_gap_m"), col("nf_v_mps")
    nb_gap, nb_v = col("nb_gap_m"), col("nb_v_mps")
    d["f_gap_m"], d["nf_gap_m"], d["nb_gap_m"] = f_gap, nf_gap, nb_gap  # NaN where a table lacks them
    f_in, nf_in, nb_in = np.isfinite(f_gap), np.isfinite(nf_gap), np.isfinite(nb_gap)
    ego_slow = ~(v_e >= MIN_SPEED_MPS)
    with np.errstate(invalid="ignore", divide="ignore"):
        nb_slow = ~(nb_v >= MIN_SPEED_MPS)
        far = nb_gap > settings.far_follower_m
        d["thw_f_s"] = np.where(f_in & ~ego_slow, f_gap / v_e, np.nan)
        d["thw_nb_s"] = np.where(nb_in & ~nb_slow, nb_gap / nb_v, np.nan)
    d["dv_f_mps"] = np.where(f_in, v_e - f_v, np.nan)
    d["dv_nf_mps"] = np.where(nf_in, v_e - nf_v, np.nan)
    d["gap_f_status"] = _status(f_in)
    d["thw_f_status"] = _status(f_in, (ego_slow, "stopped"))
    d["dv_f_status"] = _status(f_in)
    d["gap_nf_status"] = _status(nf_in)
    d["dv_nf_status"] = _status(nf_in)
    d["gap_nb_status"] = _status(nb_in, (far, "far"))
    d["thw_nb_status"] = _status(nb_in, (nb_slow, "stopped"), (far, "far"))
    return d


def has_acceptance(decisions: pd.DataFrame) -> bool:
    """Whether the table already carries every acceptance column."""
    return all(c in decisions.columns for c in DERIVED_COLUMNS)
