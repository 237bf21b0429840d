"""Small pure helpers that shape tables for display (no Streamlit, no I/O)."""

from __future__ import annotations

from typing import Any, Iterable

import pandas as pd

from dashboard.uploads import SavedUpload

UPLOAD_COLUMNS = ["file", "status", "reason", "recording_id", "driver_id"]
RECORDING_COLUMNS = ["recording_id", "driver_id", "session_id", "speed_limit_kph", "format", "n_samples",
                     "duration_s", "n_presses", "n_vehicles", "status", "warnings", "source_name"]


def _file_entries(report: dict[str, Any]) -> list[dict[str, Any]]:
    """The per-file entries of an `IngestReport.to_dict()` (a list under 'files' or similar)."""
    for key in ("files", "results", "items"):
        if isinstance(report.get(key), list):
            return report[key]
    return []


def upload_rows(saved: Iterable[SavedUpload], report: dict[str, Any] | None) -> pd.DataFrame:
    """One row per uploaded file: its ingest status and reason, or why it was not even saved."""
    by_path: dict[str, dict[str, Any]] = {}
    for entry in _file_entries(report or {}):
        path = entry.get("source") or entry.get("path") or entry.get("source_path") or ""
        by_path[str(path)] = entry
        by_path.setdefault(str(entry.get("source_name", "")), entry)
    rows = []
    for s in saved:
        if s.path is None:
            rows.append({"file": s.name, "status": "refused", "reason": s.reason, "recording_id": "",
                         "driver_id": ""})
            continue
        e = by_path.get(str(s.path)) or by_path.get(s.path.name) or {}
        reason = "; ".join(([e["reason"]] if e.get("reason") else []) + list(e.get("warnings") or []))
        rows.append({"file": s.name, "status": e.get("status", "unknown"), "reason": reason,
                     "recording_id": e.get("recording_id") or "", "driver_id": e.get("driver_id") or ""})
    return pd.DataFrame(rows, columns=UPLOAD_COLUMNS)


_MD_SPECIAL = "\\`*_{}[]()#+-.!|<>~$"


def md_escape(text: str) -> str:
    """Text shown verbatim inside Streamlit markdown (file names come from the user's browser)."""
    return "".join("\\" + c if c in _MD_SPECIAL else c for c in str(text))


def reasons_markdown(results: pd.DataFrame) -> str:
    """A markdown list '- **file** (status): reason' of the uploads that were not ingested as they are."""
    todo = results[~results["status"].isin(["ingested", "duplicate"])]
    return "\n".join(f"- **{md_escape(r.file)}** ({r.status}): {md_escape(r.reason)}" for r in todo.itertuples())


def recordings_view(recs: pd.DataFrame) -> pd.DataFrame:
    """The catalogue columns worth showing, in a stable order."""
    return recs[[c for c in RECORDING_COLUMNS if c in recs.columns]]


def recording_label(row: pd.Series) -> str:
    """'D03 / session (ab12cd34...)' for a recording picker."""
    return f"{row['driver_id']} / {row['session_id']} ({str(row['recording_id'])[:8]})"


STATUS_COLUMNS = {"t_f": "t_f_status", "t_nf": "t_nf_status", "dv_nb": "dv_nb_status"}


def undefined_decisions(decisions: pd.DataFrame, driver_id: str) -> pd.DataFrame:
    """The driver's presses with at least one undefined indicator, and why each is undefined."""
    d = decisions[(decisions["driver_id"] == driver_id) & (decisions["label"] == "change")]
    status = d[list(STATUS_COLUMNS.values())]
    bad = d[(status != "ok").any(axis=1)]
    cols = ["session_id", "t_s", "ego_v_mps", *STATUS_COLUMNS.values(), "t_f_s", "t_nf_s", "dv_nb_mps"]
    return bad[[c for c in cols if c in bad.columns]].reset_index(drop=True)


def for_driver(df: pd.DataFrame | None, driver_id: str) -> pd.DataFrame:
    """Rows of `df` about one driver (all rows when it has no driver column; empty for None)."""
    if df is None:
        return pd.DataFrame()
    for col in ("driver_id", "driver", "name"):
        if col in df.columns:
            return df[df[col].astype(str) == driver_id].reset_index(drop=True)
    if "id" in df.columns:  # the analysis' skipped table: 'D01' or 'D01:t_nf'
        ids = df["id"].astype(str)
        return df[(ids == driver_id) | ids.str.startswith(driver_id + ":")].reset_index(drop=True)
    return df


def drivers_of(tables: dict[str, pd.DataFrame]) -> list[str]:
    """Driver ids known to the analysis, sorted."""
    ids: set[str] = set()
    for name in ("decisions", "styles", "fits"):
        df = tables.get(name)
        if df is not None and "driver_id" in df.columns:
            ids |= set(df["driver_id"].astype(str))
    return sorted(ids)


def style_summary(styles: pd.DataFrame) -> pd.DataFrame:
    """Per style: number of members, the typical driver and the members."""
    if styles is None or styles.empty or "style" not in styles:
        return pd.DataFrame(columns=["style", "drivers", "typical driver", "members"])
    rows = []
    for style, g in styles.groupby("style", sort=False):
        flag = next((c for c in ("is_typical", "typical") if c in g), None)
        typical = g.loc[g[flag].astype(bool), "driver_id"].tolist() if flag else []
        rows.append({"style": style, "drivers": len(g), "typical driver": ", ".join(map(str, typical)),
                     "members": ", ".join(sorted(map(str, g["driver_id"])))})
    return pd.DataFrame(rows)


#: evaluation summary column -> (shown name, scale); shares are shown in percent.
EVAL_COLUMNS = {
    "recall": ("recall at the presses [%]", 100.0),
    "balanced_accuracy": ("balanced accuracy [%]", 100.0),
    "specificity": ("keeps before the press [%]", 100.0),
    "timing_mae_s": ("timing MAE [s]", 1.0),
    "timing_bias_s": ("timing bias [s]", 1.0),
    "never_rate": ("never changes [%]", 100.0),
    "mae_t_f": ("MAE t_f [s]", 1.0),
    "mae_t_nf": ("MAE t_nf [s]", 1.0),
    "mae_dv_nb": ("MAE dv_nb [m/s]", 1.0),
}


def evaluation_table(summary: list[dict[str, Any]] | None) -> pd.DataFrame:
    """Agent vs greedy vs driver: one row per policy with the evaluation figures, units in the names."""
    df = pd.DataFrame(summary or [])
    if df.empty:
        return pd.DataFrame(columns=["policy", *[v[0] for v in EVAL_COLUMNS.values()]])
    out = pd.DataFrame({"policy": df["who"]})
    for col, (name, scale) in EVAL_COLUMNS.items():
        if col in df:
            out[name] = (pd.to_numeric(df[col], errors="coerce") * scale).round(2)
    return out


def compare_runs(tables: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """Several runs' evaluation tables stacked, with the run id in front."""
    parts = [t.assign(run_id=rid) for rid, t in tables.items() if len(t)]
    if not parts:
        return pd.DataFrame()
    out = pd.concat(parts, ignore_index=True)
    return out[["run_id", *[c for c in out.columns if c != "run_id"]]]


FIT_SUMMARY_COLUMNS = ["indicator", "status", "A", "A_lo", "A_hi", "b", "b_lo", "b_hi", "r2", "n", "v_min", "v_max",
                       "reason"]


def fit_summary(fits: pd.DataFrame) -> pd.DataFrame:
    """The fit columns a reader needs (speeds in m/s), numbers rounded."""
    out = fits[[c for c in FIT_SUMMARY_COLUMNS if c in fits.columns]].copy()
    out = out.rename(columns={"v_min": "v_min [m/s]", "v_max": "v_max [m/s]"})
    return out.round(3)


def analysis_settings(saved: dict[str, Any], **changes: Any):
    """`AnalysisSettings` from the dict stored in analysis/meta.json (lists back to tuples), with `changes`."""
    from indicators.settings import AnalysisSettings

    fields = AnalysisSettings.__dataclass_fields__
    base = {k: tuple(v) if isinstance(v, list) else v for k, v in saved.items() if k in fields}
    return AnalysisSettings(**base).with_(**changes)
