"""The analysis stage wired together.

`analyze_tables(decisions, settings)` is everything after decision extraction and
is pure (frames in, frames out): correlations and fits of every indicator, the
clustering feature set (chosen by the data with `features='auto'`), styles,
reference lines (a flagged fit becomes its level, see `reference_lines`) and the
warnings a user must see. `analyze(workspace, settings, progress)` reads the
workspace's recordings, extracts decisions, calls `analyze_tables`, stores the
`analysis/` stage folder in one swap and returns a JSON-ready report.
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import laneprint
from clustering import choice as choosing
from clustering.behaviour import PARAMETERS, Behaviour, driver_behaviour
from clustering.confidence import bootstrap_stability
from clustering.features import driver_features, feature_names, transform_features
from clustering.selection import (
    MAX_IMPUTED,
    FeatureSetScore,
    choose_features,
    clustering_rows,
    resolve_features,
    score_feature_set,
)
from clustering.styles import StyleClusterer
from indicators.decisions import empty_decisions, extract_decisions
from indicators.following import FOLLOWING, empty_following, following_episodes, following_levels
from indicators.directions import POOLED, fits_by_direction, press_counts
from indicators.settings import AnalysisSettings
from indicators.stats import (
    FEATURE_UNITS,
    INDICATORS,
    PAPER_INDICATORS,
    correlate,
    fit_flag,
    fit_lines,
    fit_pooled,
    indicator_points,
)
from laneprint.errors import UserError
from laneprint.progress import ProgressFn, report
from laneprint.reference import PAPER_TABLE1
from laneprint.schemas import DECISIONS, REFERENCE_LINES
from laneprint.workspace import DamagedFile, Workspace

SKIPPED_COLUMNS = ["what", "id", "reason"]
STYLE_COLUMNS = [
    "driver_id",
    "style",
    "cluster",
    "confidence",
    "posterior",
    "stability",
    "margin",
    "is_typical",
    "n_decisions",
    "defensiveness",
    "assigned_by",
    "note",
    "reading_agreement",
    "unsure",
]
REF_COLUMNS = REFERENCE_LINES.names


def _n_decisions(decisions: pd.DataFrame, drivers: list[str]) -> pd.Series:
    presses = decisions[decisions["label"] == "change"]
    return presses.groupby("driver_id")["decision_id"].nunique().reindex(drivers, fill_value=0).astype(int)


def assign_styles(
    feats: pd.DataFrame,
    notes: dict[str, list[str]],
    n_dec: pd.Series,
    fits: pd.DataFrame,
    settings: AnalysisSettings,
    points: pd.DataFrame | None = None,
) -> tuple[pd.DataFrame, StyleClusterer | None, list[dict[str, str]]]:
    """Cluster drivers with enough presses, assign the rest to the nearest centre, pick typical drivers.

    confidence = bootstrap stability when computed (see `clustering.confidence`), else
    the mixture posterior of `StyleClusterer`; both are kept as their own columns.
    """
    skipped: list[dict[str, str]] = []
    usable = feats.notna().any(axis=1)
    fit_on = clustering_rows(feats, n_dec, settings)
    styles = pd.DataFrame(
        {
            "driver_id": feats.index.astype(str),
            "style": "unassigned",
            "cluster": -1,
            "confidence": 0.0,
            "posterior": 0.0,
            "stability": np.nan,
            "margin": 0.0,
            "is_typical": False,
            "n_decisions": n_dec.reindex(feats.index).to_numpy(),
            "defensiveness": np.nan,
            "assigned_by": "none",
            "note": [("; ".join(notes.get(d, []))) for d in feats.index],
        }
    )
    styles = styles.set_index("driver_id", drop=False)
    for d in feats.index[~usable]:
        why = (
            "no presses"
            if n_dec.get(d, 0) == 0
            else "no defined values of " + "/".join(settings.feature_indicators) + " at any press"
        )
        skipped.append({"what": "driver", "id": str(d), "reason": f"no style: {why}"})
    if len(fit_on) == 0:
        return styles.reset_index(drop=True), None, skipped
    Xt = transform_features(feats, settings)
    clf = StyleClusterer(
        k=settings.k,
        choose_k=settings.choose_k,
        k_range=settings.k_range,
        n_init=settings.n_init,
        random_state=settings.random_state,
    ).fit(Xt.loc[fit_on])
    rows = feats.index[usable]
    labels, conf, margin = clf.predict_confidence(Xt.loc[rows])
    defn = clf.defensiveness(Xt.loc[rows])
    styles.loc[rows, "cluster"] = labels
    styles.loc[rows, "style"] = [clf.names_[i] for i in labels]
    styles.loc[rows, "posterior"] = conf
    styles.loc[rows, "confidence"] = conf
    styles.loc[rows, "margin"] = margin
    styles.loc[rows, "defensiveness"] = defn
    if settings.n_bootstrap > 0 and len(rows) <= settings.bootstrap_max_drivers and points is not None:
        stab = bootstrap_stability(points, list(rows), labels, clf, settings)
        styles.loc[rows, "stability"] = stab
        styles.loc[rows, "confidence"] = stab
    fitted = set(fit_on)
    styles.loc[rows, "assigned_by"] = ["clustered" if d in fitted else "nearest centre" for d in rows]
    for d in rows:
        if d not in fitted:
            styles.loc[d, "note"] = "; ".join(
                filter(None, [styles.loc[d, "note"], f"only {n_dec[d]} presses: assigned to the nearest centre"])
            )
    # typical driver: nearest the centre among members with enough presses and all fits ok
    dist = pd.Series(clf.distances(Xt.loc[rows]).min(axis=1), index=rows)
    ok_fits = fits[fits["status"] == "ok"].groupby("driver_id")["indicator"].nunique()
    for c in range(clf.k_):
        members = [d for d, lab in zip(rows, labels) if lab == c]
        if not members:
            continue

        def rank(d: str) -> tuple:
            return (-int(n_dec[d] >= settings.min_typical_decisions), -int(ok_fits.get(d, 0)), float(dist[d]))

        styles.loc[min(members, key=rank), "is_typical"] = True
    styles["cluster"] = styles["cluster"].astype("int64")
    styles["n_decisions"] = styles["n_decisions"].astype("int64")
    styles["is_typical"] = styles["is_typical"].astype(bool)
    return styles.reset_index(drop=True), clf, skipped


def reference_lines(
    styles: pd.DataFrame,
    fits: pd.DataFrame,
    points: pd.DataFrame,
    settings: AnalysisSettings,
    by_direction: pd.DataFrame | None = None,
) -> tuple[pd.DataFrame, list[dict[str, str]]]:
    """Per style the typical driver's and the pooled lines, per driver its own, plus Table 1.

    A typical driver's or a driver's OLS line that is flagged (`indicators.stats.fit_flag`:
    low R², a slope interval spanning 0, few points) is not used as it is: with
    `flagged_lines='level'` (default) the line is the driver's level, A = 0 and b = the
    median of its values, and column `fit` says 'level' and `source` why; with 'ols' the
    flagged fit is kept (the study's way). Column `fit` is 'ols', 'level' or 'paper'.

    Column `direction` is 'both' for lines fitted on every press; with `by_direction`
    (`indicators.directions.fits_by_direction`), the typical driver's and each driver's
    lines on one side ('left', 'right') are added where that side has a fit.
    """
    rows, skipped = [], []
    ok = fits[fits["status"] == "ok"].set_index(["driver_id", "indicator"])

    def from_fit(scope: str, name: str, kind: str, ind: str, f: Any, source: str) -> dict[str, Any]:
        flag = str(f.get("flag", "") or "") if hasattr(f, "get") else ""
        row = {
            "scope": scope,
            "name": name,
            "kind": kind,
            "indicator": ind,
            "A": float(f["A"]),
            "b": float(f["b"]),
            "A_lo": float(f["A_lo"]),
            "A_hi": float(f["A_hi"]),
            "b_lo": float(f["b_lo"]),
            "b_hi": float(f["b_hi"]),
            "r2": float(f["r2"]),
            "n": int(f["n"]),
            "source": source,
            "fit": str(f.get("fit", "ols")) if hasattr(f, "get") else "ols",
            "flag": flag,
        }
        if flag and settings.flagged_lines == "level" and np.isfinite(f.get("level", np.nan)):
            row.update(
                A=0.0,
                b=float(f["level"]),
                A_lo=np.nan,
                A_hi=np.nan,
                b_lo=np.nan,
                b_hi=np.nan,
                fit="level",
                source=f"{source}: level (median of {int(f['n'])}), its line is flagged: {flag}",
            )
        return row

    assigned = styles[styles["cluster"] >= 0]
    for style, members in assigned.sort_values("cluster").groupby("style", sort=False):
        typical = members[members["is_typical"]]["driver_id"].tolist()
        drivers = members["driver_id"].tolist()
        for ind in INDICATORS:
            fit, why = fit_pooled(points, drivers, ind, settings)
            pooled = (
                None
                if fit is None
                else {**fit.__dict__, "flag": fit_flag(fit, settings), "level": pooled_level(points, drivers, ind)}
            )
            if typical and (typical[0], ind) in ok.index:
                rows.append(
                    from_fit("style", style, "typical", ind, ok.loc[(typical[0], ind)], f"typical driver {typical[0]}")
                )
            elif ind in PAPER_INDICATORS:  # the agents need the style's line: a stand-in, which says what it is
                no_fit = f"typical driver {typical[0] if typical else '-'} has no {ind} fit"
                line, what = stand_in(style, ind, drivers, pooled, points)
                rows.append(from_fit("style", style, "typical", ind, line, f"{what} ({no_fit})"))
                skipped.append(
                    {"what": "reference_line", "id": f"{style}:typical:{ind}", "reason": f"{no_fit}: {what} stands in"}
                )
            else:
                skipped.append(
                    {
                        "what": "reference_line",
                        "id": f"{style}:typical:{ind}",
                        "reason": f"typical driver {typical[0] if typical else '-'} has no {ind} fit",
                    }
                )
            if pooled is not None:
                rows.append(from_fit("style", style, "pooled", ind, pooled, f"pooled over {len(drivers)} driver(s)"))
            else:
                skipped.append({"what": "reference_line", "id": f"{style}:pooled:{ind}", "reason": why})
    for (drv, ind), f in ok.iterrows():
        rows.append(from_fit("driver", str(drv), "driver", ind, f, f"driver {drv}"))
    for r in rows:
        r["direction"] = POOLED
    if by_direction is not None:
        rows += side_lines(assigned, by_direction, from_fit)
    for style, lines in PAPER_TABLE1.items():
        for ind, (A, b) in lines.items():
            rows.append(
                {
                    "scope": "style",
                    "name": style,
                    "kind": "paper",
                    "indicator": ind,
                    "A": A,
                    "b": b,
                    "A_lo": np.nan,
                    "A_hi": np.nan,
                    "b_lo": np.nan,
                    "b_hi": np.nan,
                    "r2": np.nan,
                    "n": 0,
                    "source": "Table 1 (Li & Liu), SI units",
                    "fit": "paper",
                    "flag": "",
                    "direction": POOLED,
                }
            )
    out = pd.DataFrame(rows, columns=REF_COLUMNS + ["fit", "flag", "direction"])
    out["n"] = out["n"].astype("int64")
    return out, skipped


def stand_in(
    style: str, ind: str, drivers: list[str], pooled: dict[str, Any] | None, points: pd.DataFrame
) -> tuple[dict[str, Any], str]:
    """A style's line for one of the study's indicators its typical driver has no fit of: the
    style's pooled fit, else the level of its members' values, else of every driver's, else
    Table 1's line (the style's, or Normal's for a style Table 1 does not name)."""
    if pooled is not None:
        return pooled, f"pooled over {len(drivers)} driver(s)"
    everyone = sorted(points["driver_id"].astype(str).unique())
    for who, label in ((drivers, "the style's"), (everyone, "every driver's")):
        level = pooled_level(points, who, ind)
        if np.isfinite(level):
            n = int((points["indicator"].eq(ind) & points["driver_id"].isin(who) & points["used"]).sum())
            return (
                {
                    "A": 0.0,
                    "b": level,
                    "A_lo": np.nan,
                    "A_hi": np.nan,
                    "b_lo": np.nan,
                    "b_hi": np.nan,
                    "r2": np.nan,
                    "n": n,
                    "flag": "",
                    "fit": "level",
                },
                f"level of {label} {n} defined value(s)",
            )
    A, b = PAPER_TABLE1.get(style, PAPER_TABLE1["Normal"])[ind]  # `ind` is one of the study's three
    return (
        {
            "A": A,
            "b": b,
            "A_lo": np.nan,
            "A_hi": np.nan,
            "b_lo": np.nan,
            "b_hi": np.nan,
            "r2": np.nan,
            "n": 0,
            "flag": "",
            "fit": "paper",
        },
        f"Table 1's line (no {ind} defined at any press)",
    )


def side_lines(assigned: pd.DataFrame, by_direction: pd.DataFrame, from_fit: Any) -> list[dict[str, Any]]:
    """Reference lines of one direction: each style's typical driver's and each driver's, where fitted."""
    rows = []
    ok = by_direction[by_direction["status"] == "ok"]
    typical = dict(
        zip(assigned.loc[assigned["is_typical"], "driver_id"], assigned.loc[assigned["is_typical"], "style"])
    )
    for f in ok.to_dict("records"):
        drv, side = str(f["driver_id"]), f["direction"]
        if drv in typical:
            rows.append(
                {
                    **from_fit(
                        "style",
                        typical[drv],
                        "typical",
                        f["indicator"],
                        f,
                        f"typical driver {drv}, presses to the {side}",
                    ),
                    "direction": side,
                }
            )
        rows.append(
            {
                **from_fit("driver", drv, "driver", f["indicator"], f, f"driver {drv}, presses to the {side}"),
                "direction": side,
            }
        )
    return rows


def pooled_level(points: pd.DataFrame, drivers: list[str], indicator: str) -> float:
    """Median of the usable values of `indicator` over `drivers`' presses."""
    sel = points[(points["indicator"] == indicator) & points["driver_id"].isin(drivers) & points["used"]]
    return float(sel["y"].median()) if len(sel) else float("nan")


_LEADER, _TARGET_LEADER, _FOLLOWER = (
    "leader in the ego lane",
    "leader in the target lane",
    "follower in the target lane",
)
_ROLE = {
    "t_f": _LEADER,
    "gap_f": _LEADER,
    "thw_f": _LEADER,
    "dv_f": _LEADER,
    "t_nf": _TARGET_LEADER,
    "gap_nf": _TARGET_LEADER,
    "dv_nf": _TARGET_LEADER,
    "dv_nb": _FOLLOWER,
    "gap_nb": _FOLLOWER,
    "thw_nb": _FOLLOWER,
}


def excluded_values(points: pd.DataFrame, settings: AnalysisSettings) -> list[dict[str, str]]:
    """One 'value' row per press and indicator left out of the fits, with why: for the study's
    three and the clustering's indicators (the others' statuses are in the decisions table)."""
    keep = set(PAPER_INDICATORS) | set(settings.feature_indicators)
    out = points[~points["used"].to_numpy(dtype=bool) & points["indicator"].isin(keep).to_numpy()]
    if out.empty:
        return []
    why = {
        "absent": lambda ind: f"{ind} undefined: no {_ROLE[ind]}",
        "not_closing": lambda ind: f"{ind} undefined: the gap to the {_ROLE[ind]} is not closing",
        "following": lambda ind: (
            f"{ind} left out of fits: closing speed below {settings.min_closing_mps:g} m/s (following a slow leader)"
        ),
        "receding": lambda ind: (
            f"{ind} left out of fits: the leader pulls away faster than "
            f"{settings.max_receding_mps:g} m/s (not a gap the driver is held by)"
        ),
        "far": lambda ind: f"{ind} left out of fits: {_ROLE[ind]} beyond {settings.far_follower_m:g} m (no influence)",
        "stopped": lambda ind: f"{ind} undefined: a headway of a car at (nearly) standstill",
    }
    return [
        {"what": "value", "id": f"{d}:{ind}", "reason": why[st](ind) if st in why else f"{ind} left out of fits: {st}"}
        for d, ind, st in zip(out["decision_id"], out["indicator"], out["status"])
    ]


def analyze_tables(
    decisions: pd.DataFrame,
    settings: AnalysisSettings | None = None,
    drivers: list[str] | None = None,
    following: pd.DataFrame | None = None,
) -> dict[str, pd.DataFrame]:
    """Correlations, fits, feature sets, styles, reference lines and skipped rows from a
    decisions table (pure).

    `drivers`: drivers to report even when they have no decisions (e.g. the catalogue's).
    `following`: the drives' steady-following episodes (`indicators.following`), whence the
    `thw_follow` feature; without them that feature is undefined (and its sets not scored).
    """
    settings = settings or AnalysisSettings()
    following = empty_following() if following is None else following
    drivers = sorted(set(map(str, decisions["driver_id"].unique())) | set(map(str, drivers or [])))
    points = indicator_points(decisions, settings, following)
    correlations = correlate(decisions, settings, points, drivers)
    fits = fit_lines(decisions, settings, points, drivers)
    n_dec = _n_decisions(decisions, drivers)
    behaviour = driver_behaviour(decisions, following, drivers, settings.random_state)
    choice = None
    if settings.features in (
        choosing.RELIABLE,
        choosing.SEPARATED,
        choosing.CONSENSUS,
        *choosing.HELDOUT_CHOICES,
    ) or choosing.is_behaviour(settings.features):
        choice = choosing.choose(decisions, following, points, drivers, n_dec, behaviour, settings)
    if choice is not None and choosing.reads_behaviour(choice.name):
        settings = settings.with_(feature_indicators=choice.parameters)
        styles, clf, skipped = behaviour_styles(choice, behaviour, drivers, n_dec, fits, settings)
        feature_sets = choice_table(choice, settings.features)
        feature_cols: list[str] = []
    else:
        requested = settings.features
        if choice is not None:  # an indicator set won the held-out choice: read the drivers by it
            settings = settings.with_(features=choice.name or "ttc")
        settings, feature_sets = feature_settings(points, drivers, n_dec, settings)
        if choice is not None:
            feature_sets = choice_table(choice, requested, feature_sets)
            settings = settings.with_(features=requested)
        feats, notes = driver_features(points, drivers, settings)
        styles, clf, skipped = assign_styles(feats, notes, n_dec, fits, settings, points)
        styles = styles.merge(feats.reset_index(), on="driver_id", how="left")
        feature_cols = feature_names(settings)
        if choice is None and requested == "auto":
            choice = choosing.silhouette_alternatives(points, drivers, n_dec, settings, feature_sets)
    styles = honest_confidence(styles, choice, behaviour)
    styles = styles.merge(behaviour_table_wide(behaviour), on="driver_id", how="left")
    at_decisions = tuple(i for i in settings.feature_indicators if i in INDICATORS)
    side_fits = fits_by_direction(decisions, settings, drivers, tuple(dict.fromkeys(PAPER_INDICATORS + at_decisions)))
    refs, ref_skipped = reference_lines(styles, fits, points, settings, side_fits)
    for d in drivers:
        if n_dec[d] == 0:
            has_states = bool(len(decisions)) and (decisions["driver_id"].astype(str) == d).any()
            skipped.append(
                {
                    "what": "driver",
                    "id": d,
                    "reason": "no presses (only keep states)" if has_states else "no decisions in any recording",
                }
            )
    for _, f in fits[fits["status"] != "ok"].iterrows():
        skipped.append({"what": "indicator", "id": f"{f['driver_id']}:{f['indicator']}", "reason": f["reason"]})
    skipped.extend(ref_skipped)
    skipped.extend(excluded_values(points, settings))
    return {
        "decisions": decisions,
        "following": following,
        "correlations": correlations,
        "fits": fits,
        "fits_by_direction": side_fits,
        "feature_sets": feature_sets,
        "styles": styles[STYLE_COLUMNS + feature_cols + choosing.behaviour_columns()],
        "behaviour": behaviour_long(behaviour),
        "style_descriptions": pd.DataFrame(
            list(choosing.describe_styles(styles, behaviour).items()), columns=["style", "description"]
        ),
        "reference_lines": refs,
        "skipped": pd.DataFrame(skipped, columns=SKIPPED_COLUMNS),
        "k_scores": pd.DataFrame({"k": list(clf.k_scores_), "score": list(clf.k_scores_.values())})
        if clf is not None
        else pd.DataFrame({"k": pd.Series(dtype="int64"), "score": pd.Series(dtype=float)}),
    }


FEATURE_SET_COLUMNS = [
    "name",
    "indicators",
    "k",
    "silhouette",
    "stability",
    "score",
    "imputed",
    "presses_read",
    "heldout_ll",
    "heldout_se",
    "plausible",
    "chosen",
    "requested",
    "reliability",
]


def choice_table(choice: "choosing.Choice", requested: str, measured: pd.DataFrame | None = None) -> pd.DataFrame:
    """The readings the held-out choice scored, best first, with the silhouette figures of the
    chosen indicator set where `measured` has them."""
    rows = []
    for sc in choice.scores:
        row = {
            "name": sc.name,
            "indicators": ",".join(sc.parameters),
            "k": len(set(sc.labels.values())),
            "silhouette": np.nan,
            "stability": np.nan,
            "score": np.nan,
            "imputed": np.nan,
            "presses_read": np.nan,
            "heldout_ll": sc.heldout_ll,
            "heldout_se": sc.se,
            "plausible": sc.plausible,
            "chosen": sc.chosen,
            "requested": requested,
            "reliability": sc.reliability,
        }
        if np.isfinite(sc.silhouette):
            stab = sc.stability
            row.update(
                {
                    "silhouette": sc.silhouette,
                    "stability": stab,
                    "score": sc.silhouette * (stab if np.isfinite(stab) else 1.0),
                }
            )
        if measured is not None and sc.name in set(measured["name"]):
            m = measured[measured["name"] == sc.name].iloc[0]
            row.update({c: m[c] for c in ("silhouette", "stability", "score", "imputed", "presses_read")})
        rows.append(row)
    return pd.DataFrame(rows, columns=FEATURE_SET_COLUMNS)


def behaviour_styles(
    choice: "choosing.Choice",
    behaviour: Behaviour,
    drivers: list[str],
    n_dec: pd.Series,
    fits: pd.DataFrame,
    settings: AnalysisSettings,
) -> tuple[pd.DataFrame, StyleClusterer | None, list[dict[str, str]]]:
    """The styles table of a chosen behaviour reading (columns as `assign_styles`'), its clusterer
    and the drivers skipped."""
    style, conf, defn = choosing.assign(choice, behaviour, drivers, n_dec, settings)
    clf = choice.clusterer
    names = list(clf.names_) if clf is not None else []
    fit_on = set(clf_rows(choice))
    styles = pd.DataFrame(
        {
            "driver_id": drivers,
            "style": style.to_numpy(),
            "cluster": [names.index(s) if s in names else -1 for s in style],
            "confidence": conf.to_numpy(),
            "posterior": conf.to_numpy(),
            "stability": np.nan,
            "margin": np.nan,
            "is_typical": False,
            "n_decisions": n_dec.reindex(drivers).to_numpy(),
            "defensiveness": defn.to_numpy(),
            "assigned_by": [
                "clustered" if d in fit_on else ("nearest centre" if style[d] != "unassigned" else "none")
                for d in drivers
            ],
            "note": [
                ""
                if d in fit_on or style[d] == "unassigned"
                else f"only {n_dec[d]} presses: assigned to the nearest centre"
                for d in drivers
            ],
        }
    )
    skipped = [
        {"what": "driver", "id": d, "reason": "no style: no presses"} for d in drivers if style[d] == "unassigned"
    ]
    if clf is not None:
        assigned = [d for d in drivers if style[d] != "unassigned"]
        X = behaviour.values.loc[assigned, clf.feature_names_in_]
        dist = pd.Series(clf.distances(X).min(axis=1), index=assigned)
        ok_fits = fits[fits["status"] == "ok"].groupby("driver_id")["indicator"].nunique()
        for name in names:
            members = [d for d in assigned if style[d] == name]
            if members:
                best = min(
                    members,
                    key=lambda d: (
                        -int(n_dec[d] >= settings.min_typical_decisions),
                        -int(ok_fits.get(d, 0)),
                        float(dist[d]),
                    ),
                )
                styles.loc[styles["driver_id"] == best, "is_typical"] = True
    styles["cluster"] = styles["cluster"].astype("int64")
    styles["n_decisions"] = styles["n_decisions"].astype("int64")
    styles["is_typical"] = styles["is_typical"].astype(bool)
    return styles, clf, skipped


def clf_rows(choice: "choosing.Choice") -> list[str]:
    """The drivers that placed the chosen reading's centres."""
    chosen = next((s for s in choice.scores if s.chosen), None)
    return list(chosen.labels) if chosen is not None else []


def honest_confidence(styles: pd.DataFrame, choice: "choosing.Choice | None", behaviour: Behaviour) -> pd.DataFrame:
    """Confidence = the driver's own data's (bootstrap or parameter draws) x the share of plausible
    readings that agree, at most (n + 1) / (n + 2) for n presses (`choice.succession`), with the
    reasons a driver is unsure in column `unsure`."""
    styles = styles.copy()
    st = styles.set_index("driver_id")["style"]
    if choice is not None:
        agreement, others = choosing.reading_agreement(choice, st)
    else:
        agreement, others = pd.Series(1.0, index=st.index), {d: [] for d in st.index}
    params = choice.parameters if choice is not None and choosing.reads_behaviour(choice.name) else ()
    data_conf = styles["confidence"].to_numpy(dtype=float)
    agree = agreement.reindex(styles["driver_id"]).fillna(1.0).to_numpy()
    cap = np.array([choosing.succession(int(n)) for n in styles["n_decisions"]])
    styles["reading_agreement"] = agree
    styles["confidence"] = np.where(styles["style"] == "unassigned", 0.0, np.minimum(data_conf * agree, cap))
    styles["unsure"] = [
        "" if s == "unassigned" else choosing.unsure_reasons(d, int(n), c, a, others.get(d, []), behaviour, params)
        for d, s, n, c, a in zip(styles["driver_id"], styles["style"], styles["n_decisions"], data_conf, agree)
    ]
    return styles


def behaviour_table_wide(behaviour: Behaviour) -> pd.DataFrame:
    """Per driver its behaviour parameters in seconds and metres (styles-table columns)."""
    wide = np.exp(behaviour.values.where(behaviour.defined > 0))
    wide.columns = choosing.behaviour_columns(tuple(wide.columns))
    return wide.reset_index()


BEHAVIOUR_COLUMNS = ["driver_id", "parameter", "value", "lo", "hi", "se_log", "informed_by", "unit", "meaning"]


def behaviour_long(behaviour: Behaviour) -> pd.DataFrame:
    """The `behaviour` table: one row per driver and parameter, the value and its 95 % interval in
    units, the standard error on the log scale, and how many presses (episodes) inform it."""
    from clustering.behaviour import DRIVE_PARAMETERS, VARIABLES

    rows = []
    for d in behaviour.values.index:
        for p in PARAMETERS:
            mu, se, n = behaviour.values.loc[d, p], behaviour.se.loc[d, p], int(behaviour.defined.loc[d, p])
            unit, meaning = (VARIABLES[p][3], VARIABLES[p][4]) if p in VARIABLES else DRIVE_PARAMETERS[p]
            ok = np.isfinite(mu) and n > 0
            rows.append(
                {
                    "driver_id": d,
                    "parameter": p,
                    "value": float(np.exp(mu)) if ok else np.nan,
                    "lo": float(np.exp(mu - 1.96 * se)) if ok and np.isfinite(se) else np.nan,
                    "hi": float(np.exp(mu + 1.96 * se)) if ok and np.isfinite(se) else np.nan,
                    "se_log": float(se) if ok else np.nan,
                    "informed_by": n,
                    "unit": unit,
                    "meaning": meaning,
                }
            )
    return pd.DataFrame(rows, columns=BEHAVIOUR_COLUMNS)


def feature_settings(
    points: pd.DataFrame, drivers: list[str], n_dec: pd.Series, settings: AnalysisSettings
) -> tuple[AnalysisSettings, pd.DataFrame]:
    """`settings` with `feature_indicators` resolved from `settings.features`, and the table of the
    feature sets measured (every candidate with 'auto', the requested one otherwise)."""
    if settings.features == "auto":
        chosen, scores = choose_features(points, drivers, n_dec, settings)
    else:
        chosen, inds = resolve_features(settings.features)
        scores = [score_feature_set(points, drivers, n_dec, settings, chosen, inds)]
    best: FeatureSetScore = next(s for s in scores if s.name == chosen)
    table = pd.DataFrame(
        [
            {
                **s.to_dict(),
                "indicators": ",".join(s.indicators),
                "chosen": s.name == chosen,
                "requested": settings.features,
            }
            for s in scores
        ],
        columns=FEATURE_SET_COLUMNS,
    )
    return settings.with_(feature_indicators=best.indicators), table


def extract_all(
    workspace: Workspace, settings: AnalysisSettings, progress: ProgressFn | None = None
) -> tuple[pd.DataFrame, list[dict[str, str]], int, pd.DataFrame]:
    """Decisions of every stored recording, what was skipped, the number of recordings, and
    the recordings' steady-following episodes (`indicators.following`)."""
    catalogue = workspace.recordings()
    total = len(catalogue)
    frames, follows, skipped = [], [], []
    for path, why in workspace.damaged.items():  # a damaged catalogue entry: left out, named
        skipped.append({"what": "file", "id": path, "reason": f"damaged, left out ({why})"})
    for i, rid in enumerate(catalogue["recording_id"]):
        report(progress, i, total, f"decisions {rid}")
        try:
            meta, ego, traffic = workspace.load_recording(rid)
        except DamagedFile as exc:
            skipped.append({"what": "recording", "id": str(rid), "reason": str(exc)})
            continue
        try:
            dec, sk = extract_decisions(meta, ego, traffic, settings)
        except Exception as exc:  # a malformed recording must not stop the others
            dec, sk = (
                empty_decisions(),
                [
                    {
                        "what": "recording",
                        "id": str(rid),
                        "reason": f"decision extraction failed: {type(exc).__name__}: {exc}",
                    }
                ],
            )
        try:  # its decisions stand without it
            follows.append(following_episodes(meta, ego, traffic, settings))
        except Exception as exc:
            sk.append(
                {
                    "what": "recording",
                    "id": str(rid),
                    "reason": f"steady-following extraction failed: {type(exc).__name__}: {exc}",
                }
            )
        frames.append(dec)
        skipped.extend(sk)
    report(progress, total, total, "decisions extracted")
    non_empty = [f for f in frames if len(f)]
    decisions = pd.concat(non_empty, ignore_index=True) if non_empty else empty_decisions()
    follows = [f for f in follows if len(f)]
    following = pd.concat(follows, ignore_index=True) if follows else empty_following()
    return decisions, skipped, total, following


def code_version() -> dict[str, str | None]:
    """laneprint version and the git commit of the source tree when available."""
    commit = None
    try:
        commit = (
            subprocess.run(
                ["git", "rev-parse", "HEAD"],
                cwd=Path(__file__).resolve().parent,
                capture_output=True,
                text=True,
                timeout=5,
            ).stdout.strip()
            or None
        )
    except (OSError, subprocess.SubprocessError):
        pass
    return {"version": laneprint.__version__, "git_commit": commit}


def summary(tables: dict[str, pd.DataFrame]) -> dict[str, Any]:
    """Headline numbers: counts, the share of drivers with a significant correlation, the
    feature set used for the styles, flagged fits and the warnings a user must see."""
    corr = tables["correlations"]
    dec = tables["decisions"]
    drivers = list(tables["styles"]["driver_id"])
    tested = corr[corr["reason"] == ""]
    share = {}
    for ind in INDICATORS:
        t = tested[tested["indicator"] == ind]
        share[ind] = float(t["significant"].mean()) if len(t) else None
    paper = tested[tested["indicator"].isin(PAPER_INDICATORS)]
    by_driver = paper.groupby("driver_id")["significant"]
    features = feature_summary(tables.get("feature_sets"))
    return {
        "n_drivers": len(drivers),
        "n_presses": int((dec["label"] == "change").sum()) if len(dec) else 0,
        "n_keep_states": int((dec["label"] == "keep").sum()) if len(dec) else 0,
        "share_significant": share,
        "share_drivers_all_significant": float(by_driver.all().mean()) if len(paper) else None,
        "share_drivers_any_significant": float(by_driver.any().mean()) if len(paper) else None,
        "n_skipped": int(len(tables["skipped"])),
        "styles": {str(k): int(v) for k, v in tables["styles"]["style"].value_counts().items()},
        "typical_drivers": {str(r.style): str(r.driver_id) for r in tables["styles"].itertuples() if r.is_typical},
        "confidence_is": (
            "the share of draws of the driver's own estimates (bootstrap of its presses, or its "
            "parameters from their standard errors) that keep its style, times the share of "
            "plausible readings that agree, at most (n + 1) / (n + 2) for n presses"
        ),
        "style_descriptions": descriptions(tables),
        "unsure_drivers": {str(r.driver_id): str(r.unsure) for r in tables["styles"].itertuples() if r.unsure},
        "features": features,
        "presses_by_direction": press_counts(dec) if len(dec) else {"left": 0, "right": 0},
        "flagged_fits": flagged_counts(tables["fits"]),
        "warnings": warnings(tables, features),
    }


def descriptions(tables: dict[str, pd.DataFrame]) -> dict[str, str]:
    """Per style what sets it apart, in words (the `style_descriptions` table as a dict)."""
    t = tables.get("style_descriptions")
    return {} if t is None or t.empty else dict(zip(t["style"].astype(str), t["description"].astype(str)))


def feature_summary(feature_sets: pd.DataFrame | None) -> dict[str, Any] | None:
    """The feature set used for the styles and the figures of every set measured."""
    if feature_sets is None or feature_sets.empty:
        return None
    chosen = feature_sets[feature_sets["chosen"]].iloc[0]
    return {
        "requested": str(chosen["requested"]),
        "chosen": str(chosen["name"]),
        "indicators": str(chosen["indicators"]).split(","),
        "candidates": [
            {**r, "indicators": str(r["indicators"]).split(",")}
            for r in _records(feature_sets.drop(columns=["requested"]))
        ],
    }


def flagged_counts(fits: pd.DataFrame) -> dict[str, dict[str, int]]:
    """Per indicator: fitted lines and how many of them are flagged."""
    ok = fits[fits["status"] == "ok"]
    flagged = ok["flag"].astype(str) != "" if "flag" in ok else pd.Series(False, index=ok.index)
    return {
        ind: {"fitted": int((ok["indicator"] == ind).sum()), "flagged": int(((ok["indicator"] == ind) & flagged).sum())}
        for ind in INDICATORS
    }


def warnings(tables: dict[str, pd.DataFrame], features: dict[str, Any] | None) -> list[str]:
    """One line per result the user should not take at face value."""
    out = []
    styles = tables["styles"]
    clustered = styles[styles["assigned_by"] == "clustered"]
    assigned = styles[styles["cluster"] >= 0]
    k = int(assigned["cluster"].max()) + 1 if len(assigned) else 0
    if k and len(clustered) <= k:
        out.append(
            f"k = {k} styles from {len(clustered)} clustered driver(s): each style holds at most one driver, "
            "so the styles say nothing about groups of drivers (use --k with fewer styles, or more drivers)"
        )
    for style, members in assigned.groupby("style"):
        if len(members) == 1:
            out.append(
                f"style {style} holds one driver ({members['driver_id'].iloc[0]}): its reference lines "
                "are that driver's alone"
            )
    chosen = [c for c in (features or {}).get("candidates", []) if c["chosen"]]
    if chosen and (chosen[0]["imputed"] or 0) > MAX_IMPUTED:
        out.append(
            f"features {chosen[0]['name']}: {100 * chosen[0]['imputed']:.0f} % of the drivers' features are "
            "undefined and imputed, so the styles rest on little (try --features auto)"
        )
    counts = flagged_counts(tables["fits"])
    shown = list(PAPER_INDICATORS) + [i for i in (features or {}).get("indicators", []) if i not in PAPER_INDICATORS]
    bad = [
        f"{ind} {counts[ind]['flagged']} of {counts[ind]['fitted']}"
        for ind in shown
        if ind in counts and counts[ind]["flagged"]
    ]
    if bad:
        out.append(
            "per-driver lines flagged (R² below the threshold, slope interval spanning 0, or few points): "
            + ", ".join(bad)
            + "; a flagged line is replaced by the driver's level in the reference lines"
        )
    refs = tables["reference_lines"]
    if "fit" in refs:
        pooled = refs["direction"] == POOLED if "direction" in refs else True
        levels = refs[(refs["kind"] == "typical") & (refs["fit"] == "level") & refs["indicator"].isin(shown) & pooled]
        for style, g in levels.groupby("name", sort=False):
            what = ", ".join(f"{r.indicator} {r.b:.3g} {FEATURE_UNITS[r.indicator]}" for r in g.itertuples())
            out.append(
                f"{style}: the typical driver's line of {', '.join(g['indicator'])} is flagged, so its "
                f"reference is the level ({what}); see the fits' flags for why"
            )
    return out


def _records(df: pd.DataFrame) -> list[dict[str, Any]]:
    return [
        {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in r.items()}
        for r in df.to_dict("records")
    ]


def build_report(tables: dict[str, pd.DataFrame], meta: dict[str, Any]) -> dict[str, Any]:
    """JSON-ready report: per driver decisions/correlations/fits/style; per style members and lines."""
    styles = tables["styles"].set_index("driver_id")
    corr, fits = tables["correlations"], tables["fits"]
    drivers = {}
    for d in styles.index:
        s = styles.loc[d]
        drivers[d] = {
            "n_decisions": int(s["n_decisions"]),
            "style": s["style"],
            "confidence": float(s["confidence"]),
            "is_typical": bool(s["is_typical"]),
            "note": s["note"],
            "unsure": str(s.get("unsure", "") or ""),
            "correlations": _records(corr[corr["driver_id"] == d].drop(columns="driver_id")),
            "fits": _records(
                fits[fits["driver_id"] == d][
                    [
                        "indicator",
                        "A",
                        "b",
                        "A_lo",
                        "A_hi",
                        "b_lo",
                        "b_hi",
                        "r2",
                        "n",
                        "status",
                        "reason",
                        "flag",
                        "level",
                    ]
                ]
            ),
        }
    kept = following_levels(tables.get("following")).set_index("driver_id")
    for d, rep in drivers.items():
        rep["following"] = (
            {"episodes": int(kept.loc[d, "episodes"]), "thw_follow_s": float(kept.loc[d, "thw_follow_s"])}
            if d in kept.index
            else {"episodes": 0, "thw_follow_s": None}
        )
    refs = tables["reference_lines"]
    style_rep = {}
    for name, g in styles[styles["cluster"] >= 0].sort_values("cluster").groupby("style", sort=False):
        lines = refs[(refs["scope"] == "style") & (refs["name"] == name)]
        style_rep[name] = {
            "members": list(g.index),
            "typical": [d for d in g.index if g.loc[d, "is_typical"]],
            "description": (meta["summary"].get("style_descriptions") or {}).get(name, ""),
            "reference_lines": _records(lines.drop(columns=["scope", "name"])),
        }
    return {
        "workspace": meta.get("workspace"),
        "summary": meta["summary"],
        "drivers": drivers,
        "styles": style_rep,
        "skipped": _records(tables["skipped"]),
        "settings": meta["settings"],
        "fingerprint": meta.get("data_fingerprint"),
        "analysis_fingerprint": meta.get("analysis_fingerprint"),
        "code": meta.get("code"),
    }


def stored_settings(workspace: Workspace) -> AnalysisSettings:
    """The settings the workspace's analysis ran with (its resolved feature set included);
    defaults when there is no analysis or its meta cannot be read."""
    try:
        return AnalysisSettings.from_dict(workspace.read_meta("analysis").get("settings", {}))
    except (UserError, OSError, ValueError, TypeError):
        return AnalysisSettings()


def analyze(
    workspace: Workspace, settings: AnalysisSettings | None = None, progress: ProgressFn | None = None
) -> dict[str, Any]:
    """Run the stage on a workspace: store `analysis/` and return the JSON-ready report."""
    settings = settings or AnalysisSettings()
    if not workspace.root.is_dir() or workspace.recordings().empty:
        raise UserError(f"no recordings in workspace {workspace.root}: run `laneprint ingest PATH` first")
    workspace.check_writable()  # before the work: its tables are written at the end
    decisions, skipped, n_rec, following = extract_all(workspace, settings, progress)
    report(progress, 0, 1, "fits and styles")
    tables = analyze_tables(
        decisions, settings, drivers=list(workspace.recordings()["driver_id"].astype(str)), following=following
    )
    extra = pd.DataFrame(skipped, columns=SKIPPED_COLUMNS)
    tables["skipped"] = pd.concat([extra, tables["skipped"]], ignore_index=True)
    headline = summary(tables)
    used = headline["features"]
    if used:  # the indicators the styles were read by, as resolved from `features`
        settings = settings.with_(feature_indicators=tuple(used["indicators"]))
    meta = {
        "stage": "analysis",
        "workspace": str(workspace.root),
        "settings": settings.to_dict(),
        "code": code_version(),
        "data_fingerprint": workspace.fingerprint(),
        "n_recordings": n_rec,
        "summary": headline,
    }
    workspace.write_tables(
        "analysis",
        tables,
        meta,  # it adds the analysis's fingerprint
        schemas={"decisions": DECISIONS, "reference_lines": REFERENCE_LINES, "following": FOLLOWING},
    )
    report(progress, 1, 1, "analysis stored")
    return build_report(tables, workspace.read_meta("analysis"))
