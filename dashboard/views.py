"""Small pure helpers that shape tables for display (no Streamlit, no I/O)."""

from __future__ import annotations

from typing import Any, Iterable

import numpy as np
import pandas as pd

from dashboard.uploads import SavedUpload

UPLOAD_COLUMNS = ["file", "status", "reason", "recording_id", "driver_id"]
RECORDING_COLUMNS = [
    "recording_id",
    "driver_id",
    "session_id",
    "speed_limit_kph",
    "format",
    "n_samples",
    "duration_s",
    "n_presses",
    "n_vehicles",
    "status",
    "warnings",
    "source_name",
]


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
            rows.append({"file": s.name, "status": "refused", "reason": s.reason, "recording_id": "", "driver_id": ""})
            continue
        e = by_path.get(str(s.path)) or by_path.get(s.path.name) or {}
        reason = "; ".join(([e["reason"]] if e.get("reason") else []) + list(e.get("warnings") or []))
        rows.append(
            {
                "file": s.name,
                "status": e.get("status", "unknown"),
                "reason": reason,
                "recording_id": e.get("recording_id") or "",
                "driver_id": e.get("driver_id") or "",
            }
        )
    return pd.DataFrame(rows, columns=UPLOAD_COLUMNS)


_MD_SPECIAL = "\\`*_{}[]()#+-.!|<>~$"


def md_escape(text: object) -> str:
    """Text shown verbatim inside Streamlit markdown (file names come from the user's browser)."""
    return "".join("\\" + c if c in _MD_SPECIAL else c for c in str(text))


def reasons_markdown(results: pd.DataFrame) -> str:
    """A markdown list '- **file** (status): reason' of the uploads that were not ingested as they are."""
    todo = results[~results["status"].isin(["ingested", "duplicate"])]
    return "\n".join(f"- **{md_escape(r.file)}** ({r.status}): {md_escape(r.reason)}" for r in todo.itertuples())


#: Catalogue columns renamed for display: units in brackets, as on the plots.
RECORDING_LABELS = {
    "speed_limit_kph": "speed limit [km/h]",
    "duration_s": "duration [s]",
    "n_samples": "samples",
    "n_presses": "presses",
    "n_vehicles": "traffic vehicles",
}


def recordings_view(recs: pd.DataFrame) -> pd.DataFrame:
    """The catalogue columns worth showing, in a stable order, units in the column names."""
    return recs[[c for c in RECORDING_COLUMNS if c in recs.columns]].rename(columns=RECORDING_LABELS)


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
            ids |= set(map(str, df["driver_id"].unique()))  # unique first: the decisions table has many rows
    return sorted(ids)


def style_summary(styles: pd.DataFrame, meta: dict[str, Any] | None = None) -> pd.DataFrame:
    """Per style: number of members, the typical driver, the members and, from the analysis's
    summary, what sets the style apart in words (empty for an analysis made before)."""
    if styles is None or styles.empty or "style" not in styles:
        return pd.DataFrame(columns=["style", "drivers", "typical driver", "members", "what sets it apart"])
    words = ((meta or {}).get("summary") or {}).get("style_descriptions") or {}
    rows = []
    for style, g in styles.groupby("style", sort=False):
        flag = next((c for c in ("is_typical", "typical") if c in g), None)
        typical = g.loc[g[flag].astype(bool), "driver_id"].tolist() if flag else []
        rows.append(
            {
                "style": style,
                "drivers": len(g),
                "typical driver": ", ".join(map(str, typical)),
                "members": ", ".join(sorted(map(str, g["driver_id"]))),
                "what sets it apart": str(words.get(str(style), "")),
            }
        )
    return pd.DataFrame(rows)


def unsure_drivers(styles: pd.DataFrame) -> pd.DataFrame:
    """The drivers whose style is not sure, with their confidence and why (empty when none is, or
    for an analysis made before the reasons were kept)."""
    cols = ["driver", "style", "confidence [-]", "why unsure"]
    if styles is None or "unsure" not in styles:
        return pd.DataFrame(columns=cols)
    g = styles[styles["unsure"].fillna("").astype(str) != ""]
    return pd.DataFrame(
        {
            "driver": g["driver_id"].astype(str),
            "style": g["style"].astype(str),
            "confidence [-]": g["confidence"].astype(float).round(2),
            "why unsure": g["unsure"].astype(str),
        },
        columns=cols,
    ).reset_index(drop=True)


#: evaluation summary column -> (shown name, scale); shares are shown in percent.
EVAL_COLUMNS = {
    "recall": ("recall at the presses [%]", 100.0),
    "balanced_accuracy": ("balanced accuracy [%]", 100.0),
    "specificity": ("keeps before the press [%]", 100.0),
    "timing_mae_s": ("timing MAE [s]", 1.0),
    "timing_bias_s": ("timing bias [s]", 1.0),
    "never_rate": ("never changes [%]", 100.0),
    "medae_t_f": ("median |err| t_f [s]", 1.0),
    "medae_t_nf": ("median |err| t_nf [s]", 1.0),
    "medae_dv_nb": ("median |err| dv_nb [m/s]", 1.0),
}

#: Shown beside every evaluation table: what its robust indicator errors are.
EVAL_DEFINITION = (
    "median |err| <indicator>: the median, over the policy's changes, of |the indicator at its change "
    "- the reference line at that speed|. A median, because the TTCs t_f and t_nf of slowly closing "
    "leaders run to minutes and a few of them would set a mean (the means are `mae_*` in the JSON "
    "download). Timing MAE: mean |time of its first change - time of the driver's press|."
)


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


FIT_SUMMARY_COLUMNS = [
    "indicator",
    "unit",
    "flag",
    "status",
    "A",
    "A_lo",
    "A_hi",
    "b",
    "b_lo",
    "b_hi",
    "r2",
    "n",
    "v_min",
    "v_max",
    "reason",
]


def fit_summary(fits: pd.DataFrame) -> pd.DataFrame:
    """The fit columns a reader needs (speeds in m/s, each indicator's unit, the analysis' flag), numbers rounded."""
    from indicators.plots import unit_of

    out = fits.copy()
    out["unit"] = [unit_of(i) for i in out["indicator"]]
    if "flag" in out:
        out["flag"] = out["flag"].fillna("").astype(str)
    out = out[[c for c in FIT_SUMMARY_COLUMNS if c in out.columns]]
    out = out.rename(columns={"v_min": "v_min [m/s]", "v_max": "v_max [m/s]"})
    return out.round(3)


def flagged_fits(fits: pd.DataFrame | None) -> pd.DataFrame:
    """The fitted lines the analysis flagged (R² too low, slope interval spanning 0, ...): indicator, flag.
    Empty for an analysis made before flags existed."""
    if fits is None or fits.empty or "flag" not in fits:
        return pd.DataFrame(columns=["driver_id", "indicator", "flag"])
    ok = fits[(fits["status"] == "ok") & (fits["flag"].fillna("").astype(str) != "")]
    return ok[[c for c in ("driver_id", "indicator", "flag") if c in ok]].reset_index(drop=True)


def indicator_groups_of(decisions: pd.DataFrame, fits: pd.DataFrame | None = None) -> dict[str, tuple[str, ...]]:
    """The indicator groups the Drivers page offers: only indicators this analysis has (their value
    column in the decisions table; an older analysis has the paper's three only)."""
    from indicators.plots import PAPER_INDICATORS, indicator_columns, indicator_groups

    cols = indicator_columns()
    have = [i for i, (value, status, _) in cols.items() if value in decisions and status in decisions]
    return indicator_groups(have or [i for i in PAPER_INDICATORS if i in cols])


def chosen_indicators(meta: dict[str, Any]) -> list[str]:
    """The indicators the styles were read by (analysis/meta.json's summary.features, else its settings)."""
    summary = (meta or {}).get("summary") or {}
    feats = summary.get("features") or {}
    if feats.get("indicators"):
        return [str(i) for i in feats["indicators"]]
    return [str(i) for i in ((meta or {}).get("settings") or {}).get("feature_indicators") or ("t_f", "t_nf")]


def feature_candidates(meta: dict[str, Any]) -> pd.DataFrame:
    """The feature sets the analysis measured, the chosen one first: set, indicators, k, silhouette,
    stability, score, presses read per driver (the median driver's defined values of the set's sparsest
    press indicator), chosen. Empty for an analysis made before the choice existed."""
    feats = ((meta or {}).get("summary") or {}).get("features") or {}
    rows = []
    for c in feats.get("candidates") or []:
        inds = c.get("indicators")
        rows.append(
            {
                "feature set": c.get("name"),
                "indicators": ", ".join(inds) if isinstance(inds, list) else inds,
                "k": c.get("k"),
                "silhouette [-]": c.get("silhouette"),
                "stability [-]": c.get("stability"),
                "score [-]": c.get("score"),
                "presses read per driver": c.get("presses_read"),
                "held-out log-likelihood [-]": c.get("heldout_ll"),
                "reliability [-]": c.get("reliability"),
                "chosen": c.get("name") == feats.get("chosen"),
            }
        )
    out = pd.DataFrame(
        rows,
        columns=[
            "feature set",
            "indicators",
            "k",
            "silhouette [-]",
            "stability [-]",
            "score [-]",
            "presses read per driver",
            "held-out log-likelihood [-]",
            "reliability [-]",
            "chosen",
        ],
    )
    out["held-out log-likelihood [-]"] = pd.to_numeric(out["held-out log-likelihood [-]"], errors="coerce").round(1)
    out["presses read per driver"] = pd.to_numeric(out["presses read per driver"], errors="coerce")
    for c in ("silhouette [-]", "stability [-]", "score [-]", "reliability [-]"):
        out[c] = pd.to_numeric(out[c], errors="coerce").round(3)
    return out.sort_values("chosen", ascending=False, kind="stable").reset_index(drop=True)


def analysis_warnings(meta: dict[str, Any]) -> list[str]:
    """The analysis' warnings (a style with one driver, k >= drivers, flagged fits, ...): meta summary.warnings."""
    return [str(w) for w in (((meta or {}).get("summary") or {}).get("warnings") or [])]


def plural(n: int, word: str, words: str | None = None) -> str:
    """'1 driver', '3 drivers' (`words` for an irregular plural)."""
    return f"{n:,} {word if n == 1 else (words or word + 's')}"


def cli_hint(command: str, root, *args: str) -> str:
    """'laneprint ingest sample_logs/ --workspace /w': a command for the workspace the page shows."""
    import shlex

    return shlex.join(["laneprint", command, *args, "--workspace", str(root)])


def analysis_settings(saved: dict[str, Any], **changes: Any):
    """`AnalysisSettings` from the dict stored in analysis/meta.json (lists back to tuples), with `changes`."""
    from indicators.settings import AnalysisSettings

    return AnalysisSettings.from_dict(saved).with_(**changes)


# --- cross-validation (held-out figures) -------------------------------------------------

#: The policies a cross-validation scores, in the order they are shown.
CROSSVAL_POLICIES = ("agent", "greedy", "imitation")

#: summary column -> (shown name, scale, interval column or None).
CROSSVAL_COLUMNS = {
    "balanced_accuracy": ("balanced accuracy", "%", 100.0, "balanced_accuracy_ci"),
    "timing_mae_s": ("timing MAE", "s", 1.0, "timing_mae_ci"),
    "recall": ("recall at the presses", "%", 100.0, None),
    "specificity": ("keeps before the press", "%", 100.0, None),
    "never_rate": ("never changes", "%", 100.0, None),
}


def _number(row: dict | None, key: str, scale: float) -> float | None:
    v: Any = (row or {}).get(key)
    try:
        v = float(v) * scale
    except (TypeError, ValueError):
        return None
    return None if v != v else round(v, 2)  # NaN -> None


def _interval(row: dict | None, key: str, scale: float, digits: int) -> str:
    ci = (row or {}).get(key)
    if not ci or len(ci) != 2 or None in ci:
        return ""
    return f"{float(ci[0]) * scale:.{digits}f} – {float(ci[1]) * scale:.{digits}f}"


def crossval_table(
    held_out: list[dict[str, Any]] | None, in_sample: list[dict[str, Any]] | None = None
) -> pd.DataFrame:
    """Agent, greedy and imitation side by side: each figure in-sample (a run's evaluation, when
    given), then held out with its 95 % interval, then the held-out decisions scored.

    `held_out`: a cross-validation's `summary`; `in_sample`: a run evaluation's
    `summary_members` (the same drivers' decisions, scored by policies fitted on
    them). A policy the in-sample evaluation lacks (older runs have no
    imitation) shows empty in-sample cells.
    """
    held = {str(r.get("who")): r for r in held_out or []}
    ins = {str(r.get("who")): r for r in in_sample or []}
    rows = []
    for who in [p for p in CROSSVAL_POLICIES if p in held or p in ins]:
        row: dict[str, Any] = {"policy": who}
        for key, (name, unit, scale, ci_key) in CROSSVAL_COLUMNS.items():
            if in_sample is not None:
                row[f"{name} in-sample [{unit}]"] = _number(ins.get(who), key, scale)
            row[f"{name} held out [{unit}]"] = _number(held.get(who), key, scale)
            if ci_key:
                row[f"{name} held out 95 % interval [{unit}]"] = _interval(
                    held.get(who), ci_key, scale, 1 if unit == "%" else 2
                )
        row["decisions held out"] = (held.get(who) or {}).get("n_decisions")
        rows.append(row)
    return pd.DataFrame(rows)


def unscored_table(result: dict[str, Any]) -> pd.DataFrame:
    """The decisions a cross-validation could not score: reason, what it means, how many."""
    try:
        from rl.problem.env import SKIP_REASONS
    except ImportError:  # pragma: no cover - the RL stage is part of the package
        SKIP_REASONS = {}
    items = sorted(((str(k), int(v)) for k, v in (result.get("unscored") or {}).items() if v), key=lambda kv: -kv[1])
    return pd.DataFrame(
        [{"reason": k, "meaning": SKIP_REASONS.get(k, ""), "decisions": v} for k, v in items],
        columns=["reason", "meaning", "decisions"],
    )


def scored_line(result: dict[str, Any]) -> str:
    """'200 of 200 decisions scored (100 %), 4 folds by session, ...' for a caption."""
    total, scored = result.get("n_decisions_total"), result.get("n_decisions_scored")
    settings = result.get("settings") or {}
    share = f" ({scored / total:.0%})" if total and scored is not None else ""
    return (
        f"{scored if scored is not None else '?'} of {total if total is not None else '?'} decisions scored"
        f"{share}, {result.get('folds', '?')} folds by {settings.get('split', '?')}, "
        f"seed {settings.get('seed', '?')}, {settings.get('n_bootstrap', '?')} bootstrap resamples"
    )


def crossvals_view(table: pd.DataFrame) -> pd.DataFrame:
    """`rl.evaluation.crossval_store.list_crossvals` newest first, balanced accuracies in percent."""
    if table is None or table.empty:
        return pd.DataFrame(columns=["crossval_id", "target_kind", "target", "run_id", "reward", "folds"])
    out = table.copy()
    order = out["created_at"] if "created_at" in out else out["crossval_id"]
    out = out.assign(_order=order.astype(str)).sort_values(["_order", "crossval_id"], ascending=False)
    out = out.drop(columns="_order").reset_index(drop=True)
    for who in CROSSVAL_POLICIES:
        col = f"{who}_balanced_accuracy"
        if col in out:
            out = out.rename(columns={col: f"{who} balanced accuracy [%]"})
            out[f"{who} balanced accuracy [%]"] = (
                pd.to_numeric(out[f"{who} balanced accuracy [%]"], errors="coerce") * 100
            ).round(1)
    return out


def crossval_label(row: pd.Series | dict) -> str:
    """'2026-11-30 14:10 · style Normal · run n1 · reward decisions · 4 folds' for a picker."""
    when = str(row.get("created_at") or "")[:16].replace("T", " ")
    parts = [
        when,
        f"{row.get('target_kind')} {row.get('target')}",
        f"run {row['run_id']}" if row.get("run_id") else "no run",
        f"reward {row.get('reward')}",
        f"{row.get('folds')} folds",
    ]
    analysis = str(row.get("analysis") or "")
    if analysis and "current" not in analysis:  # made with an earlier analysis, or one not recorded
        parts.append(analysis)
    return " · ".join(p for p in parts if p)


def default_crossval(table: pd.DataFrame, run_id: str, target: dict[str, Any], own_id: str | None = None) -> str | None:
    """The cross-validation to show beside a run: its own (`runs/<id>/crossval.json`), else the
    newest of this run, else the newest of the same target; None when there is none."""
    view = crossvals_view(table)
    if own_id and own_id in set(view["crossval_id"]):
        return own_id
    if view.empty:
        return None
    mine = view[view["run_id"].astype(str) == str(run_id)]
    if len(mine):
        return str(mine["crossval_id"].iloc[0])
    same = view[
        (view["target_kind"].astype(str) == str(target.get("kind")))
        & (view["target"].astype(str) == str(target.get("name")))
    ]
    return str(same["crossval_id"].iloc[0]) if len(same) else None


def crossval_differences(result: dict[str, Any], run_id: str, config: dict[str, Any]) -> list[str]:
    """How a cross-validation differs from the run it is shown beside: another run or target,
    other scenes, observation or reward, fewer or more training episodes per fold."""
    out = []
    if result.get("run_id") != run_id:
        out.append(f"it is of {'run ' + str(result['run_id']) if result.get('run_id') else 'no run'}, not of {run_id}")
    tgt, run_tgt = result.get("target") or {}, config.get("target") or {}
    if (tgt.get("kind"), tgt.get("name")) != (run_tgt.get("kind"), run_tgt.get("name")):
        out.append(f"its target is {tgt.get('kind')} {tgt.get('name')}")
    env, run_env = result.get("env") or {}, config.get("env") or {}
    for key, label in (("scenes", "scenes"), ("observation", "observation")):
        if run_env and env.get(key) != run_env.get(key):
            out.append(f"{label} `{env.get(key)}` (the run: `{run_env.get(key)}`)")
    reward = (env.get("reward") or {}).get("name")
    run_reward = (run_env.get("reward") or {}).get("name") or config.get("reward")
    if run_reward and reward != run_reward:
        out.append(f"reward `{reward}` (the run: `{run_reward}`)")
    episodes = (result.get("dqn") or {}).get("episodes")
    run_episodes = (config.get("dqn") or {}).get("episodes")
    if episodes and run_episodes and episodes != run_episodes:
        out.append(f"its agents trained {episodes} episodes per fold (the run: {run_episodes})")
    return out


def command_text(cmd: list[str]) -> str:
    """A launched command as a reader would type it: `laneprint ...` instead of `python -m laneprint.app.cli ...`."""
    import shlex

    if len(cmd) > 2 and cmd[1:3] == ["-m", "laneprint.app.cli"]:
        cmd = ["laneprint", *cmd[3:]]
    return shlex.join(cmd)


#: A fleet table's columns as the pages show them -> (label, scale).
FLEET_COLUMNS = {
    "target": ("target", None),
    "seed": ("seed", None),
    "state": ("state", None),
    "agent_balanced_accuracy": ("agent BA [%]", 100.0),
    "greedy_balanced_accuracy": ("greedy BA [%]", 100.0),
    "imitation_balanced_accuracy": ("imitation BA [%]", 100.0),
    "agent_minus_greedy": ("agent - greedy BA [points]", 100.0),
    "agent_recall": ("agent recall [%]", 100.0),
    "greedy_recall": ("greedy recall [%]", 100.0),
    "imitation_recall": ("imitation recall [%]", 100.0),
    "meets_target": ("meets target", None),
    "timing_mae_s": ("agent timing MAE [s]", 1.0),
    "run_id": ("run_id", None),
}


def fleet_view(table: pd.DataFrame) -> pd.DataFrame:
    """`rl.fleet.store.fleet_table` for display: percentages, episodes as 'done/total', labelled columns."""
    out = pd.DataFrame(index=table.index)
    for col, (label, scale) in FLEET_COLUMNS.items():
        if col == "state":
            out["episodes"] = [f"{int(e)}/{int(n) or '?'}" for e, n in zip(table["episode"], table["episodes"])]
        out[label] = (pd.to_numeric(table[col], errors="coerce") * scale).round(1) if scale else table[col]
    return out.reset_index(drop=True)


def fleet_label(row: pd.Series | dict) -> str:
    """'<fleet_id>: 100 drivers x 1 seed, 40/100 done (running)'."""
    seeds = int(row.get("n_seeds") or 0)
    return (
        f"{row['fleet_id']}: {row.get('targets')} x {seeds} seed{'s' if seeds != 1 else ''}, "
        f"{int(row.get('n_done') or 0)}/{int(row.get('n_runs') or 0)} done ({row.get('state')})"
    )


def fleet_headline(table: pd.DataFrame) -> str:
    """How many agents meet their target, and the median balanced accuracy of each policy."""
    evaluated = table[table["agent_balanced_accuracy"].notna()]
    if evaluated.empty:
        return "No agent evaluated yet."
    meets = int((evaluated["meets_target"] == True).sum())  # noqa: E712 (None: not evaluated)
    medians = ", ".join(
        f"{who} {100 * evaluated[f'{who}_balanced_accuracy'].median():.1f} %"
        for who in ("agent", "greedy", "imitation")
        if evaluated[f"{who}_balanced_accuracy"].notna().any()
    )
    return (
        f"{meets} of {len(evaluated)} evaluated agents meet their target (recall >= 95 %, balanced accuracy "
        f">= greedy + 5 points); median balanced accuracy (in-sample): {medians}."
    )


def speeds_text(meta: dict[str, Any]) -> str:
    """'60, 70, 80 and 90 km/h (16.7-25.0 m/s)': the speeds the feature lines are read at."""
    kph = [float(v) for v in ((meta or {}).get("settings") or {}).get("feature_speeds_kph") or (60, 70, 80, 90)]
    names = [f"{v:g}" for v in kph]
    listed = ", ".join(names[:-1]) + f" and {names[-1]}" if len(names) > 1 else names[0]
    return f"{listed} km/h ({min(kph) / 3.6:.1f}-{max(kph) / 3.6:.1f} m/s)"


def reference_indicators(lines: pd.DataFrame, chosen: list[str]) -> list[str]:
    """The indicators whose reference lines the Styles page draws: the paper's three (the agents read
    them), then the chosen features', as far as the table has them."""
    from indicators.plots import PAPER_INDICATORS

    have = set(lines["indicator"]) if lines is not None and "indicator" in lines else set()
    return [i for i in dict.fromkeys([*PAPER_INDICATORS, *chosen]) if i in have]


def recording_names(recs: pd.DataFrame) -> dict[str, str]:
    """recording_id -> 'D01 / D01_S80' (driver and session) for progress texts."""
    if recs is None or recs.empty:
        return {}
    return {str(r["recording_id"]): f"{r['driver_id']} / {r['session_id']}" for _, r in recs.iterrows()}


def progress_text(names: dict[str, str]):
    """A translator of a stage's progress messages for people: 'decisions 2a9eff0c82b3454d' becomes
    'reading decisions: recording 3 of 12 (D01 / D01_S80)'."""
    import re

    pattern = re.compile(r"^decisions ([0-9a-f]{8,})$")

    def text(done: int, total: int, message: str) -> str:
        m = pattern.match(message or "")
        if m:
            return f"reading decisions: recording {done + 1} of {total} ({names.get(m.group(1), m.group(1)[:8])})"
        if message == "fits and styles":
            return "fitting each driver's lines, choosing the features and clustering the styles"
        return message

    return text


def never_learnt(metrics: pd.DataFrame | None, config: dict[str, Any]) -> str:
    """A warning when a run never updated its network (no loss in any episode: learning had not begun),
    '' otherwise."""
    if (
        metrics is None
        or metrics.empty
        or ("loss" in metrics and pd.to_numeric(metrics["loss"], errors="coerce").notna().any())
    ):
        return ""
    starts = (config.get("dqn") or {}).get("learning_starts")
    steps = pd.to_numeric(metrics.get("env_steps"), errors="coerce").max() if "env_steps" in metrics else None
    took = f" it took {int(steps):,} transitions in {len(metrics):,} episodes," if steps == steps and steps else ""
    return (
        f"This agent never learnt:{took} and learning starts after "
        f"{f'{int(starts):,}' if starts else 'more'} transitions, so its network was never updated and its "
        "figures below are an untrained network's. Train it with more episodes (or fewer learning-start "
        "transitions)."
    )


def analysis_notice(recorded: str | None, current: str | None, what: str = "run") -> tuple[str, str]:
    """(level, text) saying which analysis a result was made from: level 'warning' for a result made
    with an earlier analysis than the current one ("made with an earlier analysis: re-run"), 'info' for
    one without a fingerprint ("analysis unknown", made before results recorded it), 'ok' otherwise."""
    from laneprint.provenance import analysis_mark

    mark = analysis_mark(recorded, current)
    if mark["analysis"] == "earlier":
        return "warning", (
            f"This {what} was {mark['analysis_label']}. It was made with analysis "
            f"`{recorded}`; the current analysis is `{current or 'none'}` (its styles or reference "
            f"lines differ), so its drivers, typical driver and lines may no longer be the style's."
        )
    if mark["analysis"] == "unknown":
        return "info", (
            f"This {what}: {mark['analysis_label']} (made before results recorded the analysis they "
            "used); re-run it to be sure it matches the current analysis."
        )
    return "ok", f"This {what} was {mark['analysis_label']} (`{current}`)."


def evaluation_heading(ev: dict[str, Any]) -> tuple[str, str]:
    """(subheader, caption) of a run's evaluation, naming the decisions it was scored on: in-sample for a
    trained run; for a personalised run "held out: the N decisions not given" (its imitation row fitted
    on the same K given decisions), or in-sample when all were given."""
    scored_on = str(ev.get("scored_on") or "in-sample")
    if scored_on.startswith("held out"):
        split = ev.get("split") or {}
        return (
            f"Held out: agent vs benchmarks vs driver ({scored_on})",
            f"{scored_on.capitalize()}: the agent was built from the driver's first {split.get('given', 'K')} "
            "decisions, the imitation classifier fitted on the same ones, greedy follows the style's lines; "
            "all are scored on the decisions none of them saw.",
        )
    if scored_on.startswith("in-sample: all"):
        return (
            "In-sample: agent vs benchmarks vs driver",
            f"{scored_on.capitalize()}: every decision of the driver was given to the personalisation, so "
            "there are none left to hold out; the imitation classifier is fitted on the same decisions.",
        )
    return (
        "In-sample: agent vs benchmarks vs driver",
        "In-sample: scored on the decisions the agent was trained on (and the imitation classifier, "
        "when present, fitted on); the held-out figures below hold sessions out.",
    )


def personalize_progress(run_id: str, status: dict[str, Any]) -> tuple[float, str]:
    """(fraction, text) of a personalisation under way: the phase it is in, 'phase 2 of 4' (style, each base
    agent, fine-tuning, evaluating) with its episodes and the time its phase has left when it has any, never
    "(0/?)". Before its first phase is written: starting, placing the driver among the styles."""
    done, total = int(status.get("episode") or 0), int(status.get("episodes") or 0)
    if status.get("state") == "starting" or not status.get("message"):
        return 0.0, f"{run_id}: starting (loading PyTorch, placing the driver among the styles)"
    message = str(status.get("message"))
    if status.get("phase") and status.get("phases"):
        message = f"phase {status['phase']} of {status['phases']}: {message}"
    count = f" ({done:,}/{total:,} episodes{time_left(status)})" if total > 1 else ""
    return (min(1.0, done / total) if total else 0.0), f"{run_id}: {message}{count}"


def personalize_done(run_id: str, status: dict[str, Any], p: dict[str, Any] | None) -> str:
    """What a finished personalisation made, in one line: how, the style, and its figures on the decisions
    it was not given."""
    text = f"{run_id} done: {status.get('message') or 'personalised'}."
    later = (p or {}).get("later_decisions")
    if later:
        lo, hi = later.get("balanced_accuracy_ci") or [None, None]
        ci = f" [{100 * lo:.1f}, {100 * hi:.1f}]" if lo is not None else ""
        text += (
            f" Held out (the {later.get('n_decisions')} decisions not given): balanced accuracy "
            f"{100 * later['balanced_accuracy']:.1f} %{ci}."
        )
    elif p:
        text += " Every decision was given: no held-out figures."
    return text


def run_header(run_id: str, cfg: dict[str, Any], status: dict[str, Any] | None) -> str:
    """The Results page's line about a run: target, reward, lines, seed and what was done (episodes trained;
    for a personalised run, its base and K decisions instead of "0 episodes")."""
    status = status or {}
    tgt = cfg.get("target", {})
    head = (
        f"**{md_escape(run_id)}**: {tgt.get('kind')} **{md_escape(str(tgt.get('name')))}**, reward `{cfg.get('reward')}`, "
        f"lines `{cfg.get('lines_source')}`, seed {cfg.get('seed')}, "
    )
    if cfg.get("kind") == "personalized":
        base = cfg.get("base") or {}
        what = status.get("message") or (
            f"personalised from the {base.get('chosen') or base.get('from')} agent on {cfg.get('decisions')} decisions"
        )
        episodes = int(status.get("episode") or 0)
        tuned = f"fine-tuned {plural(episodes, 'episode')}" if episodes else "not fine-tuned"
        return (
            head + f"personalised on the first {cfg.get('decisions')} of {cfg.get('decisions_available')} "
            f"decisions: {what} ({tuned})"
        )
    return head + f"{status.get('episode', '?')} episodes"


_LEARNER_NAMES = {"dqn": "DQN", "trees": "trees"}


def _percent(x: Any) -> str:
    """'80.5 %' of a share; 'not scored' when it is missing or NaN (a learner without a side's presses)."""
    try:
        return f"{100 * float(x):.1f} %" if np.isfinite(float(x)) else "not scored"
    except (TypeError, ValueError):
        return "not scored"


def learner_text(cfg: dict[str, Any]) -> str:
    """Which learner made the run and, for the default `auto`, the scores it was chosen by: 'Learner: DQN,
    kept by auto (held-out agreement on 120 of the target's 360 approaches over 3 inner folds, mean balanced
    accuracy over the sides: DQN 80.5 %, trees 77.3 %; the trees are kept only when better by more than 1
    point)'."""
    choice = cfg.get("learner_choice")
    learner = str((choice or {}).get("learner") or cfg.get("learner") or "dqn")
    name = _LEARNER_NAMES.get(learner, learner)
    if not choice:
        return f"Learner: {name} (asked for)."
    scores = choice.get("scores") or {}
    margin = (cfg.get("auto") or {}).get("margin")
    text = (
        f"Learner: {name}, kept by `auto` (held-out agreement on {choice.get('n_holdout')} of the target's "
        f"{choice.get('n_train')} approaches over {choice.get('folds') or 1} inner folds, mean balanced accuracy "
        "over the sides: " + ", ".join(f"{_LEARNER_NAMES.get(k, k)} {_percent(v)}" for k, v in scores.items())
    )
    if margin is not None:
        text += f"; the trees are kept only when better by more than {100 * float(margin):g} points"
    text += ")."
    by_side = choice.get("by_side") or {}
    if by_side:
        text += (
            " By side: "
            + "; ".join(
                f"{_LEARNER_NAMES.get(k, k)} " + ", ".join(f"{side} {_percent(v)}" for side, v in sides.items())
                for k, sides in by_side.items()
                if sides
            )
            + "."
        )
    if choice.get("stopped"):
        text += f" Stopped early: {choice['stopped']}."
    return text


def run_results(run: dict[str, Any], crossval: dict[str, Any] | None) -> dict[str, Any]:
    """What a run's results download holds: config, status, in-sample evaluation, its cross-validation."""
    return {
        "run_id": run.get("run_id"),
        "config": run.get("config"),
        "status": run.get("status"),
        "evaluation": run.get("evaluation"),
        "crossval": crossval,
    }


def run_results_json(run: dict[str, Any], crossval: dict[str, Any] | None) -> str:
    import json

    return json.dumps(run_results(run, crossval), indent=2, default=str)


def run_results_csv(run: dict[str, Any], crossval: dict[str, Any] | None) -> str:
    """One row per policy: in-sample figures, and held out with intervals when the run was cross-validated."""
    ev = run.get("evaluation") or {}
    in_sample = ev.get("summary_members") or ev.get("summary")
    table = crossval_table(crossval.get("summary"), in_sample) if crossval else evaluation_table(in_sample)
    return table.assign(run_id=run.get("run_id")).to_csv(index=False)


#: How a run's status message starts while `--learner auto` chooses its learner (`rl.learners.choice`).
LEARNER_CHOICE = "choosing the learner"


def time_left(status: dict[str, Any]) -> str:
    """', about N min left' from a status's episodes and its time since `started_at` ('' before a tenth);
    a job in phases (a personalisation) counts from its phase's start (`phase_started_at`)."""
    from datetime import datetime

    done, total = int(status.get("episode") or 0), int(status.get("episodes") or 0)
    try:
        elapsed = (
            datetime.fromisoformat(str(status["updated_at"]))
            - datetime.fromisoformat(str(status.get("phase_started_at") or status["started_at"]))
        ).total_seconds()
    except (KeyError, ValueError, TypeError):
        return ""
    if not total or done < 0.1 * total or elapsed <= 0:
        return ""
    left = elapsed * (total - done) / done
    return f", about {left / 60:.0f} min left" if left >= 90 else f", about {left:.0f} s left"


def run_doing(status: dict[str, Any]) -> str:
    """What a run is doing beyond its episode count, for its progress text: ': starting the trainer
    (PyTorch) and building its scenes' before the first episode, ': training done, evaluating the
    agent against greedy, imitation and the drivers' after the last, the phase and time left while `auto`
    chooses its learner, '' otherwise."""
    state = status.get("state")
    done, total = int(status.get("episode") or 0), int(status.get("episodes") or 0)
    message = str(status.get("message") or "")
    if state == "running" and message.startswith(LEARNER_CHOICE):  # `auto`: its phase, its episodes summed
        return f" ({message}{time_left(status)})"
    if state == "starting" or (state == "running" and done == 0):
        return " (starting the trainer: loading PyTorch, building the scenes from the analysis)"
    if state == "running" and total and done >= total:
        return " (training done; evaluating the agent against greedy, imitation and the drivers' decisions)"
    if state == "running" and status.get("message") == "evaluating":
        return " (evaluating against greedy, imitation and the drivers' decisions)"
    return ""


# --- directions (overtaking to the left, returning to the right) ----------------------------

DIRECTION_FIT_COLUMNS = [
    "indicator",
    "direction",
    "unit",
    "n",
    "A",
    "b",
    "r2",
    "pearson_r",
    "significant",
    "flag",
    "reason",
]


def direction_fit_summary(fits_by_direction: pd.DataFrame | None, keep: tuple[str, ...] = ()) -> pd.DataFrame:
    """Per-direction fits for a reader: indicator, direction, n, A, b, R², Pearson r, significant, and the
    flag (a fitted line that means little) or the reason there is no line ('... the pooled line stands').
    Empty for an analysis made before directions. `keep`: columns kept first and sorted by first (the
    report's `driver_id`: every driver's fits in one call)."""
    from indicators.plots import unit_of

    f = fits_by_direction
    if f is None or f.empty or "direction" not in f:
        return pd.DataFrame(columns=[*keep, *DIRECTION_FIT_COLUMNS])
    out = f.copy()
    out["unit"] = [unit_of(i) for i in out["indicator"]]
    for col in ("flag", "reason"):
        if col in out:
            out[col] = out[col].fillna("").astype(str)
    ok = out["status"] == "ok" if "status" in out else True
    if "reason" in out:  # a fitted line's reason is empty; a skipped side says why
        out.loc[ok, "reason"] = ""
    out = out[[*keep, *[c for c in DIRECTION_FIT_COLUMNS if c in out.columns]]]
    # the analysis' order of indicators (the paper's three first), left before right
    rank = {ind: i for i, ind in enumerate(dict.fromkeys(out["indicator"]))}
    order = {"indicator": rank, "direction": {"left": 0, "right": 1}}
    out = out.sort_values(
        [*keep, "indicator", "direction"],
        kind="stable",
        key=lambda s: s.map(order[s.name]) if s.name in order else s.astype(str),
    )
    return out.reset_index(drop=True).round(3)


def presses_by_direction_text(meta: dict[str, Any]) -> str:
    """'250 presses to the left (overtaking), 250 to the right (returning)' from the analysis summary;
    '' for an analysis made before directions."""
    counts = ((meta or {}).get("summary") or {}).get("presses_by_direction") or {}
    if not counts:
        return ""
    left, right = int(counts.get("left", 0)), int(counts.get("right", 0))
    return f"{plural(left, 'press', 'presses')} to the left (overtaking), {right:,} to the right (returning)"


def driver_presses_by_direction(decisions: pd.DataFrame, driver_id: str) -> dict[str, int]:
    """Presses of one driver to each side ({} when the decisions table has no lanes)."""
    if not {"target_lane", "ego_lane"} <= set(decisions.columns):
        return {}
    from indicators.directions import press_counts

    return press_counts(decisions[decisions["driver_id"].astype(str) == driver_id])


def drive_label(folder: str, drive: dict[str, Any]) -> str:
    """'normal-s1: run R, 3 lanes, seed 1, 2.9 /km (drivers 3.0), 8 of 8 medians inside' for the drive picker."""
    fid = drive.get("fidelity") or {}
    rate = fid.get("rate")
    what = (
        f", {rate['agent']['per_km']:.2f} /km (drivers {rate['drivers']['per_km']:.2f}), "
        f"{fid['medians_in_iqr']} medians inside"
        if rate and rate["agent"]["per_km"] is not None and rate["drivers"]["per_km"] is not None
        else ""
    )
    return f"{folder}: run {drive.get('run_id')}, {drive.get('lanes', 2)} lanes, seed {drive.get('seed')}{what}"


#: what the rule of `laneprint drive` is for and when it acts instead of the agent, in a sentence
DRIVE_RULE_NOTE = (
    "The rule is the assistant's held-back rule around the agent (docs: Concepts, Closed-loop "
    "driving). It is there for a situation the study's presses do not hold: following a slower "
    "leader with a free lane beside. It changes lane itself when a slower leader has held the ego "
    "back for the target drivers' patience (held back), and completes an overtaking, back into the "
    "lane left (return); otherwise it only holds back the agent's own changes into gaps smaller "
    "than any its drivers took. `laneprint drive --no-held-back` drives the agent alone."
)


def drive_made_by_table(drive: dict[str, Any]) -> pd.DataFrame:
    """Who made each lane change of a drive, per section and in total: the agent, or the rule and which part
    of it (held back, return); a drive reported before attribution is read from its counts."""
    from rl.drive.attribution import made_by

    rows = []
    for r in [*drive.get("sections", []), {**(drive.get("totals") or {}), "speed_limit_kph": None}]:
        m = made_by(r)
        n = sum(m.values())
        rows.append(
            {
                "section": "total" if r.get("speed_limit_kph") is None else f"{r['speed_limit_kph']:g} km/h",
                "lane changes": n,
                "by the agent": m["agent"],
                "rule: held back": m["rule_held_back"],
                "rule: return": m["rule_return"],
                "not requested (SUMO)": m["unattributed"],
                "agent's share [%]": None if not n else round(100 * m["agent"] / n),
            }
        )
    out = pd.DataFrame(rows)
    if len(out) and not out["not requested (SUMO)"].any():
        out = out.drop(columns="not requested (SUMO)")
    return out


def drive_made_by_text(drive: dict[str, Any]) -> str:
    """'Who changed lane: 28 lane changes: the agent 0, the rule 28 (held back 20, return 8); ...' for a drive
    (its `who_drove` sentence, else one made from its totals)."""
    from rl.drive.attribution import made_by_text

    who = drive.get("who_drove") or {}
    return who.get("text") or f"Who changed lane: {made_by_text(drive.get('totals') or {})}."


#: page -> (the page to go to next, what to do there), in the order a study goes through them
NEXT_STEPS: dict[str, tuple[str, str]] = {
    "data": ("Styles", "read the drivers' styles ('Run analysis')"),
    "drivers": ("Styles", "see the styles the drivers fall into and their reference lines"),
    "styles": ("Training", "train an agent for a style"),
    "training": ("Results", "compare a finished agent with its drivers and the greedy benchmark, held out"),
    "results": ("Personalise", "start an agent for one driver from their first decisions"),
}


def next_step(page: str, has_recordings: bool, has_analysis: bool) -> str | None:
    """The line naming what to do next after `page` ('Next: ... on the Styles page'), None when the page's
    own step is not done yet (no recordings on Data, no analysis after it)."""
    if page not in NEXT_STEPS or not has_recordings or (page != "data" and not has_analysis):
        return None
    where, what = NEXT_STEPS[page]
    return f"Next: {what} on the **{where}** page."
