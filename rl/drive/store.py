"""`laneprint drive`'s edges: the run's agent in, MCAP logs and a JSON report out.

`drive_run(workspace, run_id, ...)` loads a trained run (its `EnvConfig` and
weights, as `laneprint evaluate` does), drives the SUMO sections with it
(`rl.drive.loop`), writes one LOG_FORMAT v1 MCAP per section (`ingest.writers`, as the
SUMO study) and summarises: lane changes, SUMO's collision and emergency-braking
counts, and the indicators at the agent's decisions against its target's
reference lines. The held-back rule (`rl.drive.heldback`, on unless `held_back=False`) is read
from the workspace's analysis; the report says how many changes came from it and from the
agent, and how long the ego was held back. With `sumo_model=True` (the default) the same ego
vType drives the same sections, traffic and seeds with SUMO's own lane changing (LC2013 with
the style's parameters): the comparator's lane changes per km and held-back figures are
reported beside the agent's. With `analyze=True` the study of the workspace plus the drive is
analysed in a scratch workspace (the user's analysis, which the run was trained
on, is left alone) and the style it gives the agent is reported.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ingest.writers import write_mcap
from laneprint.errors import UserError
from laneprint.progress import ProgressFn
from laneprint.reference import INDICATORS, SPEED_LIMITS_KPH
from laneprint.workspace import Workspace, atomic_write_json
from rl.drive.fidelity import drivers_traffic, fidelity
from rl.drive.heldback import DWELL_PERCENTILE, HeldBackRule, merge_summaries, rule_from_analysis
from rl.drive.loop import QFunction, SectionDrive, drive_sections, recordings, sumo_model_sections
from rl.learners.dqn import q_values
from rl.problem.env import EnvConfig, observation
from rl.problem.rewards import ReferenceLines
from rl.runs import Target, load_weights, run_dir, target_drivers

DEFAULT_STYLE = "Normal"
_ATTR = {"t_f": "t_f_s", "t_nf": "t_nf_s", "dv_nb": "dv_nb_mps"}  # indicator -> `Decision` field


def agent_q(net: Any, cfg: EnvConfig) -> QFunction:
    """The trained agent's Q-values of a batch of scenes (the run's observation), shape (n, 2)."""
    return lambda scene: q_values(net, observation(scene, cfg))


def load_run_config(workspace: Workspace, run_id: str) -> dict[str, Any]:
    """The run's config.json (`UserError` when there is no such run)."""
    path = run_dir(workspace, run_id) / "config.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise UserError(f"no run {run_id!r} in {workspace.root} (see `laneprint train`)") from None
    except (OSError, ValueError) as exc:
        raise UserError(f"{path} is not readable JSON: {exc}") from None


def own_traffic(workspace: Workspace, target: Target) -> Optional[tuple[str, int]]:
    """(family, lanes) of the laneprint SUMO study the target's drivers drove, or None (another simulator,
    a mix, or no analysis to name them)."""
    try:
        drivers, _ = target_drivers(workspace, target)
    except UserError:
        return None
    return drivers_traffic(workspace, drivers)


def ego_style(workspace: Workspace, target: Target) -> tuple[str, str]:
    """(SUMO style whose parameters the ego drives with, why): the target's style, else Normal."""
    from laneprint.simulator.sumo.styles import STYLE_PARAMS

    known = {s.lower(): s for s in STYLE_PARAMS}
    if target.kind == "style" and target.name.lower() in known:
        return known[target.name.lower()], "the run's target style"
    if target.kind == "driver" and workspace.has_table("analysis", "styles"):
        styles = workspace.read_table("analysis", "styles")
        row = styles[styles["driver_id"].astype(str) == target.name]
        if len(row) and str(row["style"].iloc[0]).lower() in known:
            return known[str(row["style"].iloc[0]).lower()], f"the analysis's style of driver {target.name}"
    return DEFAULT_STYLE, f"{target.label} has no SUMO style: the {DEFAULT_STYLE} one"


def output_paths(out: Path, session_ids: list[str]) -> list[Path]:
    """Where each section's MCAP goes: `out` itself for one section when it ends in .mcap,
    `<stem>_S<limit>.mcap` beside it for several, `<session_id>.mcap` inside a folder otherwise."""
    if out.suffix == ".mcap":
        if len(session_ids) == 1:
            return [out]
        return [out.with_name(f"{out.stem}_{sid.rsplit('_', 1)[-1]}.mcap") for sid in session_ids]
    return [out / f"{sid}.mcap" for sid in session_ids]


def check_sections(sections: Optional[list[float]]) -> tuple[int, ...]:
    """The sections to drive (`UserError` for a limit the study does not have)."""
    if not sections:
        return tuple(SPEED_LIMITS_KPH)
    bad = [s for s in sections if int(round(s)) not in SPEED_LIMITS_KPH]
    if bad:
        raise UserError(f"--section {bad[0]:g}: the sections are {', '.join(map(str, SPEED_LIMITS_KPH))} km/h")
    return tuple(sorted({int(round(s)) for s in sections}))


def indicators_vs_lines(drives: list[SectionDrive], lines: ReferenceLines) -> dict[str, Any]:
    """Per indicator, at the agent's decisions that started a lane change: how many are defined,
    the median value and the mean absolute and signed difference to the reference line."""
    made = [d for drive in drives for d in drive.decisions if d.started]
    out: dict[str, Any] = {"n_decisions": len(made), "lines": lines.to_dict()}
    for ind in INDICATORS:
        vals = [(getattr(d, _ATTR[ind]), d.v_e_mps) for d in made]
        vals = [(x, v) for x, v in vals if x is not None]
        if not vals:
            out[ind] = {"n": 0, "median": None, "line_median": None, "mae": None, "bias": None}
            continue
        x = np.array([a for a, _ in vals])
        ref = lines.at(np.array([v for _, v in vals]))[ind]
        out[ind] = {"n": len(x), "median": float(np.median(x)), "line_median": float(np.median(ref)),
                    "mae": float(np.mean(np.abs(x - ref))), "bias": float(np.mean(x - ref))}
    return out


def driven_km(drive: SectionDrive) -> float:
    """Distance the ego drove in the section [km]."""
    x = drive.log.ego["ego_x_m"]
    return float(x.iloc[-1] - x.iloc[0]) / 1000.0


def section_row(d: SectionDrive) -> dict[str, Any]:
    """The figures of one driven section (the agent's or SUMO's model's)."""
    made = [c for c in d.log.lane_changes if c["changed"]]
    by_lane: dict[str, int] = {}
    for c in made:
        key = f"{c['from_lane']}>{c['target_lane']}"
        by_lane[key] = by_lane.get(key, 0) + 1
    started = [x for x in d.decisions if x.started]
    return {
        "speed_limit_kph": d.speed_limit_kph, "sumo_seed": d.log.sumo_seed,
        "duration_s": float(d.log.ego["t_s"].iloc[-1]), "km": driven_km(d), "desired_mps": d.desired_mps,
        "decisions_asked": d.n_asked, "change_decisions": len(d.decisions), "lane_changes": len(made),
        "left": sum(c["direction"] == "left" for c in made), "right": sum(c["direction"] == "right" for c in made),
        "agent_changes": sum(x.source == "agent" for x in started),
        "rule_changes": sum(x.source in ("rule", "return") for x in started),  # returns: an overtaking completed
        "return_changes": sum(x.source == "return" for x in started),
        "not_started": sum(not x.started for x in d.decisions),
        "collisions": d.log.n_collisions, "emergency_brakes": d.log.n_emergency_brakes,
        "changes_by_lane": dict(sorted(by_lane.items())), "follow": d.follow,
    }


def section_rows(drives: list[SectionDrive], paths: list[Path]) -> list[dict[str, Any]]:
    """One JSON-ready row per driven section."""
    return [{**section_row(d), "file": str(path)} for d, path in zip(drives, paths)]


_COUNTS = ("decisions_asked", "change_decisions", "lane_changes", "left", "right", "agent_changes", "rule_changes",
           "return_changes", "not_started", "collisions", "emergency_brakes")


def totals(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Sums over sections, the distance, lane changes per km and the held-back figures."""
    out: dict[str, Any] = {k: sum(r[k] for r in rows) for k in _COUNTS}
    out["km"] = sum(r["km"] for r in rows)
    out["lane_changes_per_km"] = out["lane_changes"] / out["km"] if out["km"] > 0 else None
    out["follow"] = merge_summaries([r["follow"] for r in rows])
    return out


def sumo_model_report(drives: list[SectionDrive], agent_totals: dict[str, Any]) -> dict[str, Any]:
    """SUMO's own model of the ego's style in the same traffic: per section, totals, and the agent's
    lane changes per km over the model's."""
    rows = [section_row(d) for d in drives]
    tot = totals(rows)
    model, agent = tot["lane_changes_per_km"], agent_totals["lane_changes_per_km"]
    return {"what": "the same ego vType with SUMO's own lane changing (LC2013, the style's parameters), "
                    "same sections, traffic seeds and SUMO seeds",
            "sections": rows, "totals": tot,
            "rate_ratio": (agent / model) if model and agent is not None else None}


def _sum_counts(counts: list[dict[str, int]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for c in counts:
        for k, v in c.items():
            out[k] = out.get(k, 0) + v
    return dict(sorted(out.items()))


def assigned_style(workspace: Workspace, files: list[Path], driver_id: str) -> dict[str, Any]:
    """Analyse the workspace's recordings plus `files` (as `driver_id`) in a scratch workspace:
    the style given to `driver_id`, its confidence, and every driver's style."""
    from clustering.pipeline import analyze, stored_settings
    from ingest.pipeline import ingest_paths

    cat = workspace.recordings()
    with tempfile.TemporaryDirectory(prefix="laneprint-drive-analysis-") as tmp:
        scratch = Workspace(Path(tmp) / "ws").ensure()
        for rid, did in zip(cat["recording_id"], cat["driver_id"].astype(str)):
            if did != driver_id:  # a previous drive of the same id is replaced by this one
                (scratch.recordings_dir / rid).symlink_to(workspace.recordings_dir / rid, target_is_directory=True)
        rep = ingest_paths(files, scratch, driver_id=driver_id)
        bad = [f for f in rep.files if f.status not in ("ingested", "warning")]
        if bad:
            raise UserError(f"ingest did not store the drive's {bad[0].source} ({bad[0].status}): {bad[0].reason}")
        analyze(scratch, stored_settings(workspace))
        styles = scratch.read_table("analysis", "styles")
    styles["driver_id"] = styles["driver_id"].astype(str)
    row = styles[styles["driver_id"] == driver_id]
    return {"driver_id": driver_id, "style": str(row["style"].iloc[0]) if len(row) else None,
            "confidence": float(row["confidence"].iloc[0]) if len(row) and "confidence" in row else None,
            "styles": dict(zip(styles["driver_id"], styles["style"].astype(str)))}


def held_back_rule(workspace: Workspace, target: Target, cfg: EnvConfig, dwell_percentile: float = DWELL_PERCENTILE,
                   dwell_draw: bool = False, lag_draw: bool = False) -> tuple[Optional[HeldBackRule], str]:
    """(the rule of the run's target from the analysis, a note); None with why when the analysis lacks it."""
    try:
        return (rule_from_analysis(workspace, target, cfg.dt_s, dwell_percentile, dwell_draw, lag_draw),
                "from the workspace's analysis")
    except (ValueError, KeyError, UserError, FileNotFoundError) as exc:
        return None, f"no held-back rule: {exc}"


def calibrated(workspace: Workspace, run_id: str, target: Target, family: str, lanes: int, minutes: float,
               pace: bool, pace_by: str, undo_check: bool, progress: Optional[ProgressFn]) -> dict[str, Any]:
    """The run's closed-loop calibration of the dwell and the follower's headway for this traffic and these
    settings (`rl.drive.calibrate`), made when missing by drives with the default dwell and the floors alone
    on the calibration seeds."""
    from rl.drive.calibrate import calibrate, load_calibration

    setting = {"family": family, "lanes": lanes, "minutes": minutes, "pace": pace, "pace_by": pace_by,
               "undo_check": undo_check}
    stored = load_calibration(workspace, run_id, setting)
    if stored is not None and "lag_draws" in stored:  # one made before the headway was calibrated: again
        return stored

    def drive(seed: int, out: Path, lag: dict[str, list[float]]) -> dict[str, Any]:
        return drive_run(workspace, run_id, minutes=minutes, seed=seed, out=out, lanes=lanes, family=family,
                         sumo_model=False, pace=pace, pace_by=pace_by, undo_check=undo_check,
                         dwell_calibrated=False, lag_calibrated=False, lag_draws=lag, progress=progress)

    return calibrate(workspace, run_id, target, drive, setting)


def rule_pace(workspace: Workspace, target: Target, net: Any, cfg: EnvConfig,
              by: str = "pooled") -> Optional[dict[str, Any]]:
    """The advantage the agent's own changes need to keep its drivers' pace (`rl.drive.pace`, by side or
    pooled); None when the target's drivers are not known."""
    from rl.drive.pace import pace_threshold

    try:
        drivers, _ = target_drivers(workspace, target)
    except UserError:
        return None
    return pace_threshold(workspace, drivers, net, cfg, by)


def drivers_fidelity(workspace: Workspace, target: Target, recs: list[tuple[dict, Any, Any]],
                     seed: int) -> dict[str, Any]:
    """The drive beside the target drivers' recordings and presses (`rl.drive.fidelity`); with `note`
    and no figures when the workspace has no analysis of them."""
    from clustering.pipeline import stored_settings

    try:
        drivers, _ = target_drivers(workspace, target)
        if not workspace.has_table("analysis", "decisions"):
            raise UserError("no analysis decisions table: run `laneprint analyze` first")
    except UserError as exc:
        return {"note": f"no comparison with the drivers: {exc}"}
    return fidelity(workspace, drivers, recs, stored_settings(workspace), seed)


def dwell_mode(rule: Optional[HeldBackRule], held_back: bool, drawn: bool, calibration: Optional[dict],
               percentile: float) -> str:
    """Which wait after a lane change the drive had, in words."""
    if rule is None or not held_back:
        return "none (no held-back rule)"
    if not rule.dwell_s and not rule.dwell_draws:
        return "off"
    if calibration is not None:
        return f"calibrated in closed loop (never under the drivers' {percentile:g}th percentile)"
    if drawn:
        return "drawn from the drivers' own times"
    return f"the drivers' {percentile:g}th percentile"


def lag_mode(rule: Optional[HeldBackRule], held_back: bool, drawn: bool, calibrated_: bool) -> str:
    """Which follower headway the agent's own changes needed, in words."""
    if rule is None or not held_back:
        return "none (no held-back rule)"
    if not rule.lag_draws:
        return "the floors alone"
    if calibrated_:
        return f"calibrated in closed loop ({', '.join(sorted(rule.lag_draws))})"
    if drawn:
        return f"drawn from the drivers' presses ({', '.join(sorted(rule.lag_draws))})"
    return f"given ({', '.join(sorted(rule.lag_draws))})"


def _never() -> HeldBackRule:
    from rl.drive.heldback import Line

    never = Line(0.0, float("inf"))
    return HeldBackRule(float("inf"), never, never, never, source={"why": "no rule in the analysis"})


_NEVER = _never()


def drive_run(workspace: Workspace, run_id: str, *, minutes: float = 10.0, seed: int = 0,
              sections: Optional[list[float]] = None, out: Optional[Path] = None,
              driver_id: Optional[str] = None, analyze: bool = False, lanes: int = 2,
              held_back: bool = True, sumo_model: bool = True, dwell: bool = True,
              dwell_percentile: float = DWELL_PERCENTILE, family: Optional[str] = None,
              pace: bool = True, pace_by: str = "pooled", undo_check: bool = True, dwell_draw: bool = False,
              dwell_calibrated: Optional[bool] = None, lag_draw: bool = False,
              lag_calibrated: Optional[bool] = None, lag_draws: Optional[dict[str, list[float]]] = None,
              progress: Optional[ProgressFn] = None) -> dict[str, Any]:
    """Drive the run's agent in SUMO on a road of `lanes` lanes; write the MCAPs; a JSON-ready report.

    `family`: the SUMO study family whose traffic and style vTypes the drive uses
    (`laneprint.simulator.sumo.settings.FAMILIES`); None: that of the study the agent learnt from when
    its drivers drove a laneprint SUMO study (`rl.drive.fidelity.drivers_traffic`), so that the drive
    and its drivers are in the same kind of traffic, else the default family.

    `held_back`: the assistant's held-back rule acts beside the agent (False: the pure agent; the rule's
    figures are still measured). `sumo_model`: also drive SUMO's own model of the style (the comparator).
    `dwell=False`: the rule without its dwell after a lane change (`HeldBackRule.dwell_s` emptied);
    `dwell_percentile`: the dwell's percentile of the drivers' times from a change to the next press.
    `pace=False`: the agent's own changes need only a positive advantage, not its drivers' pace
    (`HeldBackRule.min_advantage`, `rl.drive.pace`); `pace_by`: that pace read for both sides at once
    ('pooled') or per side ('side', `rl.drive.pace.PACE_BY`). `undo_check=False`: the agent's changes to
    the left are requested even when it would want back at once (`HeldBackRule.undo_check`). `dwell_draw`:
    each lane change draws the next dwell from the drivers' own times (`HeldBackRule.dwell_draws`, seeded by
    `seed` and the section) instead of their `dwell_percentile`; `dwell_calibrated`: drawn from the run's
    closed-loop calibration in this traffic (`rl.drive.calibrate`; made first when the run has none), never
    under the percentile; None (the default): calibrated when the drive is in its drivers' own traffic (the
    family and lanes of their study) with the rule's dwell on and not drawn, else the percentile. `lag_draw`:
    the agent's own change to a side needs a follower headway drawn at each lane change from its drivers'
    presses to that side (`HeldBackRule.lag_draws`); `lag_calibrated`: drawn from the same calibration,
    so that the agent's headways with the draw are like its drivers'; None (the default): calibrated in
    its drivers' own traffic with the rule on and not drawn, else the floors alone; `lag_draws`: these
    headways to draw instead (the calibration's own drives)."""
    from laneprint.simulator.sumo.backend import check_available
    from laneprint.simulator.sumo.settings import DEFAULT_FAMILY, FAMILIES, LANES, family_settings
    from laneprint.simulator.sumo.styles import FAMILY_STYLE_PARAMS
    from rl.drive.pace import PACE_BY

    if family is not None and family not in FAMILIES:
        raise UserError(f"unknown --family {family!r}; choose one of {', '.join(FAMILIES)}")
    if pace_by not in PACE_BY:
        raise UserError(f"unknown --pace-by {pace_by!r}; choose one of {', '.join(PACE_BY)}")
    if dwell_draw and dwell_calibrated:
        raise UserError("--dwell-draw and --dwell-calibrated: choose one")
    if (dwell_draw or dwell_calibrated) and not (held_back and dwell):
        raise UserError("--dwell-draw and --dwell-calibrated set the held-back rule's dwell: not with "
                        "--no-held-back or --no-dwell")
    if lag_draw and lag_calibrated:
        raise UserError("--lag-draw and --lag-calibrated: choose one")
    if (lag_draw or lag_calibrated) and not held_back:
        raise UserError("--lag-draw and --lag-calibrated set the held-back rule's headways: not with --no-held-back")
    if not 0 <= dwell_percentile <= 100:
        raise UserError(f"--dwell-percentile {dwell_percentile:g}: give a percentile from 0 to 100")
    if lanes not in LANES:
        raise UserError(f"--lanes {lanes}: a SUMO highway has {' or '.join(map(str, LANES))} lanes")
    if not 0 < minutes <= 120:
        raise UserError("--minutes must be more than 0 and at most 120")
    config = load_run_config(workspace, run_id)
    target = Target(**config["target"])
    cfg = EnvConfig.from_dict(config["env"])
    own = own_traffic(workspace, target)
    family = family or (own[0] if own else DEFAULT_FAMILY)
    if family == "sublane":  # the controller reads a lane change under way from the ego leaving its lane centre
        raise UserError("laneprint drive does not drive on sublanes (--family sublane): give --family ttc or "
                        "acceptance")
    in_own_traffic = own == (family, lanes)
    if dwell_calibrated is None:
        dwell_calibrated = in_own_traffic and held_back and dwell and not dwell_draw
    if lag_calibrated is None:
        lag_calibrated = in_own_traffic and held_back and not lag_draw
    style_params = FAMILY_STYLE_PARAMS[family]
    net = load_weights(workspace, run_id)
    limits = check_sections(sections)
    driver_id = driver_id or f"agent-{run_id}"
    out = Path(out) if out is not None else workspace.root / "drives" / f"{run_id}-s{seed}"
    if out.suffix != ".mcap" and out.exists() and not out.is_dir():
        raise UserError(f"--out {out} exists and is not a folder")
    check_available()
    style, why = ego_style(workspace, target)
    settings = family_settings(family, lanes, speed_limits_kph=limits, minutes=minutes)
    rule, rule_note = held_back_rule(workspace, target, cfg, dwell_percentile, dwell_draw, lag_draw)
    if rule is not None and not dwell:
        rule = replace(rule, dwell_s={}, dwell_draws={}, source={**rule.source, "dwell_s": "off (--no-dwell)"})
    calibration = None
    if rule is not None and (dwell_calibrated or lag_calibrated):
        calibration = calibrated(workspace, run_id, target, family, lanes, minutes, pace, pace_by, undo_check,
                                 progress)
    if calibration is not None and dwell_calibrated:
        rule = replace(rule, dwell_draws={k: [max(x, rule.dwell_s.get(k, 0.0)) for x in v]
                                          for k, v in calibration["draws"].items()},
                       source={**rule.source,
                               "dwell_s": f"drawn from the closed-loop calibration: {calibration['note']}"})
    if rule is not None and lag_draws is not None:
        rule = replace(rule, lag_draws=lag_draws, source={**rule.source, "lag_draws": "given (a calibration drive)"})
    if calibration is not None and lag_calibrated:
        rule = replace(rule, lag_draws=calibration["lag_draws"],
                       source={**rule.source, "lag_draws": f"drawn from the closed-loop calibration: "
                                                           f"{calibration['note']}"})
    if rule is not None and not undo_check:
        rule = replace(rule, undo_check=False, source={**rule.source, "undo_check": "off (--no-undo-check)"})
    paced = rule_pace(workspace, target, net, cfg, pace_by) if rule is not None and pace else None
    if paced is not None:
        rule = rule.with_pace(paced)
    drives = drive_sections(agent_q(net, cfg), cfg, style_params[style], settings, seed, progress, rule,
                            use_rule=held_back)
    lanes_opt = "" if lanes == 2 else f", {lanes} lanes"
    simulator = f"Eclipse SUMO {drives[0].log.sumo_version} (laneprint drive {run_id}, seed {seed}{lanes_opt})"
    recs = recordings(drives, driver_id, simulator)
    paths = output_paths(out, [meta["session_id"] for meta, _, _ in recs])
    for path, (meta, ego, traffic) in zip(paths, recs):
        path.parent.mkdir(parents=True, exist_ok=True)
        write_mcap(path, meta, ego, traffic)
    rows = section_rows(drives, paths)
    result: dict[str, Any] = {
        "run_id": run_id, "target": config["target"], "driver_id": driver_id, "seed": seed, "minutes": minutes,
        "sumo_version": drives[0].log.sumo_version, "sumo_api": drives[0].log.api,
        "ego_style": style, "ego_style_reason": why, "decision_every_s": cfg.dt_s, "lanes": lanes, "family": family,
        "drivers_traffic": ({"family": own[0], "lanes": own[1], "same_as_drive": in_own_traffic} if own else None),
        "side_input": cfg.observation == "direction",
        "files": [str(p) for p in paths], "sections": rows, "totals": totals(rows),
        "held_back": {"on": bool(held_back and rule is not None), "rule": rule.to_dict() if rule else None,
                      "note": rule_note, "desired_speed": f"section limit x speedFactor "
                                                          f"{style_params[style].get('speedFactor', 1.0):g} "
                                                          f"(the {style} vType)"},
        "pace": paced or {"note": "off (--no-pace)" if rule is not None else "no held-back rule"},
        "dwell": dwell_mode(rule, held_back, dwell_draw, calibration if dwell_calibrated else None, dwell_percentile),
        "lag": lag_mode(rule, held_back, lag_draw, lag_calibrated),
        "dwell_calibration": ({k: v for k, v in calibration.items() if k not in ("draws", "lag_draws")}
                              if calibration and dwell_calibrated else None),
        "lag_calibration": ({k: v for k, v in calibration.items() if k not in ("draws", "lag_draws", "stays")}
                            if calibration and lag_calibrated else None),
        "changes_by_lane": _sum_counts([r["changes_by_lane"] for r in rows]),
        "indicators": indicators_vs_lines(drives, cfg.lines),
        "decisions": [{"speed_limit_kph": d.speed_limit_kph, **asdict(x)} for d in drives for x in d.decisions],
    }
    result["fidelity"] = drivers_fidelity(workspace, target, recs, seed)
    if sumo_model:
        model = sumo_model_sections(cfg, style_params[style], settings, seed, rule or _NEVER, progress)
        result["sumo_model"] = sumo_model_report(model, result["totals"])
    if analyze:
        result["analysis"] = assigned_style(workspace, paths, driver_id)
        result["analysis"]["target_style"] = target.name if target.kind == "style" else None
    if out.suffix != ".mcap":
        atomic_write_json(out / "drive.json", result)
    return result
