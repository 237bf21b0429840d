"""`laneprint drive`'s edges: the run's agent in, MCAP logs and a JSON report out.

`drive_run(workspace, run_id, settings)` is four steps, each a function of its own:

1. `plan_drive`: the trained run (its `EnvConfig` and weights, as `laneprint evaluate` loads them),
   what the settings leave to the workspace (the family of the drivers' traffic, whether the dwell and
   the follower's headway are calibrated), the ego's SUMO style and the assistant's held-back rule
   (`rl.drive.heldback`, read from the workspace's analysis and shaped by the settings in one place,
   `assistant_rule`). The settings themselves were checked when made (`DriveSettings`).
2. `simulate`: the SUMO sections driven with the agent (`rl.drive.loop`) and, with `sumo_model`, the same
   ego vType in the same sections, traffic and seeds with SUMO's own lane changing (LC2013 with the
   style's parameters), the comparator.
3. `write_logs`: one LOG_FORMAT v1 MCAP per section (`ingest.writers`, as the SUMO study).
4. `drive_report`: lane changes, SUMO's collision and emergency-braking counts, the indicators at the
   agent's decisions against its target's reference lines, how many changes came from the rule and
   from the agent and how long the ego was held back, the comparator's figures beside the agent's and,
   with `analyze`, the style an analysis of the study plus the drive (in a scratch workspace; the
   user's analysis, which the run was trained on, is left alone) gives the agent.

The run's closed-loop calibration (`rl.drive.calibrate`) drives with `simulate` and `write_logs` too.
Errors name the settings (`SettingError`), which the command line says as its flags.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ingest.writers import write_mcap
from laneprint.errors import SettingError, UserError
from laneprint.progress import ProgressFn
from laneprint.reference import INDICATORS, SPEED_LIMITS_KPH
from laneprint.workspace import Workspace, atomic_write_json
from rl.drive.attribution import MADE_BY, made_by, made_by_counts, who_drove
from rl.drive.fidelity import drivers_traffic, fidelity
from rl.drive.heldback import DWELL_PERCENTILE, HeldBackRule, merge_summaries, rule_from_analysis
from rl.drive.settings import DriveSettings
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
    """The sections to drive (`SettingError` for a limit the study does not have)."""
    if not sections:
        return tuple(SPEED_LIMITS_KPH)
    bad = [s for s in sections if int(round(s)) not in SPEED_LIMITS_KPH]
    if bad:
        raise SettingError(
            f"{{0}} {bad[0]:g}: the sections are {', '.join(map(str, SPEED_LIMITS_KPH))} km/h", "section"
        )
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
        out[ind] = {
            "n": len(x),
            "median": float(np.median(x)),
            "line_median": float(np.median(ref)),
            "mae": float(np.mean(np.abs(x - ref))),
            "bias": float(np.mean(x - ref)),
        }
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
        "speed_limit_kph": d.speed_limit_kph,
        "sumo_seed": d.log.sumo_seed,
        "duration_s": float(d.log.ego["t_s"].iloc[-1]),
        "km": driven_km(d),
        "desired_mps": d.desired_mps,
        "decisions_asked": d.n_asked,
        "change_decisions": len(d.decisions),
        "lane_changes": len(made),
        "left": sum(c["direction"] == "left" for c in made),
        "right": sum(c["direction"] == "right" for c in made),
        "agent_changes": sum(x.source == "agent" for x in started),
        "rule_changes": sum(x.source in ("rule", "return") for x in started),  # returns: an overtaking completed
        "return_changes": sum(x.source == "return" for x in started),
        "made_by": made_by_counts(d.decisions, made),
        "not_started": sum(not x.started for x in d.decisions),
        "collisions": d.log.n_collisions,
        "emergency_brakes": d.log.n_emergency_brakes,
        "changes_by_lane": dict(sorted(by_lane.items())),
        "follow": d.follow,
    }


def section_rows(drives: list[SectionDrive], paths: list[Path]) -> list[dict[str, Any]]:
    """One JSON-ready row per driven section."""
    return [{**section_row(d), "file": str(path)} for d, path in zip(drives, paths)]


_COUNTS = (
    "decisions_asked",
    "change_decisions",
    "lane_changes",
    "left",
    "right",
    "agent_changes",
    "rule_changes",
    "return_changes",
    "not_started",
    "collisions",
    "emergency_brakes",
)


def totals(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Sums over sections, the distance, lane changes per km and the held-back figures."""
    out: dict[str, Any] = {k: sum(r[k] for r in rows) for k in _COUNTS}
    out["made_by"] = {k: sum(made_by(r)[k] for r in rows) for k in MADE_BY}
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
    return {
        "what": "the same ego vType with SUMO's own lane changing (LC2013, the style's parameters), "
        "same sections, traffic seeds and SUMO seeds",
        "sections": rows,
        "totals": tot,
        "rate_ratio": (agent / model) if model and agent is not None else None,
    }


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
    return {
        "driver_id": driver_id,
        "style": str(row["style"].iloc[0]) if len(row) else None,
        "confidence": float(row["confidence"].iloc[0]) if len(row) and "confidence" in row else None,
        "styles": dict(zip(styles["driver_id"], styles["style"].astype(str))),
    }


def held_back_rule(
    workspace: Workspace,
    target: Target,
    cfg: EnvConfig,
    dwell_percentile: float = DWELL_PERCENTILE,
    dwell_draw: bool = False,
    lag_draw: bool = False,
) -> tuple[Optional[HeldBackRule], str]:
    """(the rule of the run's target from the analysis, a note); None with why when the analysis lacks it."""
    try:
        return (
            rule_from_analysis(workspace, target, cfg.dt_s, dwell_percentile, dwell_draw, lag_draw),
            "from the workspace's analysis",
        )
    except (ValueError, KeyError, UserError, FileNotFoundError) as exc:
        return None, f"no held-back rule: {exc}"


def calibrated(
    workspace: Workspace,
    agent: Agent,
    settings: DriveSettings,
    paced: Optional[dict[str, Any]],
    progress: Optional[ProgressFn],
) -> dict[str, Any]:
    """The run's closed-loop calibration of the dwell and the follower's headway for this traffic and these
    settings (`rl.drive.calibrate`); made when missing by the calibration's own drives: every section, the
    analysis's rule with its default dwell and the floors alone (or the headways the calibration gives),
    no comparator. They are simulated and written as a drive is (`simulate`, `write_logs`), not planned
    again: no calibration calls itself."""
    from rl.drive.calibrate import calibrate, load_calibration

    s = settings
    setting = {
        "family": s.family,
        "lanes": s.lanes,
        "minutes": s.minutes,
        "pace": s.pace,
        "pace_by": s.pace_by,
        "undo_check": s.undo_check,
    }
    stored = load_calibration(workspace, agent.run_id, setting)
    if stored is not None and "lag_draws" in stored:  # one made before the headway was calibrated: again
        return stored
    plain = DriveSettings(
        minutes=s.minutes,
        lanes=s.lanes,
        family=s.family,
        sumo_model=False,
        pace=s.pace,
        pace_by=s.pace_by,
        undo_check=s.undo_check,
        dwell_calibrated=False,
        lag_calibrated=False,
    )
    rule, note = held_back_rule(workspace, agent.target, agent.cfg)
    style, why = ego_style(workspace, agent.target)
    traffic = sumo_traffic(plain, check_sections(None))

    def drive(seed: int, out: Path, lag: dict[str, list[float]]) -> dict[str, Any]:
        plan = DrivePlan(
            agent,
            replace(plain, seed=seed),
            traffic,
            out,
            f"agent-{agent.run_id}",
            None,
            style,
            why,
            assistant_rule(rule, plain, lag_draws=lag, paced=paced),
            note,
            paced,
            None,
        )
        driven = simulate(plan, progress)
        return {"decisions": decision_rows(driven.drives), "files": [str(p) for p in write_logs(driven, out)]}

    return calibrate(workspace, agent.run_id, agent.target, drive, setting)


def rule_pace(
    workspace: Workspace, target: Target, net: Any, cfg: EnvConfig, by: str = "pooled"
) -> Optional[dict[str, Any]]:
    """The advantage the agent's own changes need to keep its drivers' pace (`rl.drive.pace`, by side or
    pooled); None when the target's drivers are not known."""
    from rl.drive.pace import pace_threshold

    try:
        drivers, _ = target_drivers(workspace, target)
    except UserError:
        return None
    return pace_threshold(workspace, drivers, net, cfg, by)


def drivers_fidelity(
    workspace: Workspace, target: Target, recs: list[tuple[dict, Any, Any]], seed: int
) -> dict[str, Any]:
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


def dwell_mode(
    rule: Optional[HeldBackRule], held_back: bool, drawn: bool, calibration: Optional[dict], percentile: float
) -> str:
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


@dataclass(frozen=True)
class Agent:
    """A trained run's agent: its config.json, target, environment and weights."""

    run_id: str
    config: dict[str, Any]
    target: Target
    cfg: EnvConfig
    net: Any


def load_agent(workspace: Workspace, run_id: str) -> Agent:
    """The run's agent (`UserError` when there is no such run)."""
    config = load_run_config(workspace, run_id)
    return Agent(
        run_id, config, Target(**config["target"]), EnvConfig.from_dict(config["env"]), load_weights(workspace, run_id)
    )


@dataclass(frozen=True)
class DrivePlan:
    """A drive made ready to simulate: the agent, the settings with the family and both calibration
    switches resolved, the SUMO traffic, where the logs go, the ego's style and the assistant's rule."""

    agent: Agent
    settings: DriveSettings  # family, dwell_calibrated and lag_calibrated resolved
    traffic: Any  # `laneprint.simulator.sumo.settings.SumoSettings` of the sections driven
    out: Path
    driver_id: str
    own: Optional[tuple[str, int]]  # (family, lanes) of the traffic the target's drivers drove, when known
    style: str  # the SUMO style whose vType the ego drives with
    style_reason: str
    rule: Optional[HeldBackRule]  # the assistant's held-back rule as the settings make it
    rule_note: str
    paced: Optional[dict[str, Any]]  # `rl.drive.pace.pace_threshold`'s result, when the rule keeps the pace
    calibration: Optional[dict[str, Any]]  # the run's closed-loop calibration, when the settings use it

    @property
    def ego_params(self) -> dict[str, float]:
        from laneprint.simulator.sumo.styles import FAMILY_STYLE_PARAMS

        return FAMILY_STYLE_PARAMS[str(self.settings.family)][self.style]


@dataclass(frozen=True)
class Driven:
    """What a drive drove: the agent's sections, their recordings (meta, ego, traffic) and, with the
    comparator, SUMO's own model's sections."""

    drives: list[SectionDrive]
    recordings: list[tuple[dict, Any, Any]]
    model: Optional[list[SectionDrive]]


def sumo_traffic(settings: DriveSettings, limits: tuple[int, ...]) -> Any:
    """The SUMO settings of the drive's family, lanes, sections and minutes."""
    from laneprint.simulator.sumo.settings import family_settings

    return family_settings(str(settings.family), settings.lanes, speed_limits_kph=limits, minutes=settings.minutes)


def assistant_rule(
    rule: Optional[HeldBackRule],
    settings: DriveSettings,
    calibration: Optional[dict[str, Any]] = None,
    lag_draws: Optional[dict[str, list[float]]] = None,
    paced: Optional[dict[str, Any]] = None,
) -> Optional[HeldBackRule]:
    """The analysis's held-back `rule` as the settings make it, every change in one place: without its
    dwell (`dwell` off), with the dwell drawn from the closed-loop `calibration` (`dwell_calibrated`;
    never under the rule's floor), with the follower headways `lag_draws` given (a calibration's drive) or
    calibrated (`lag_calibrated`), without the undo check, and with the pace `paced`; `source` says which."""
    if rule is None:
        return None
    s, source = settings, dict(rule.source)
    if not s.dwell:
        rule = replace(rule, dwell_s={}, dwell_draws={})
        source["dwell_s"] = "off (--no-dwell)"
    if calibration is not None and s.dwell_calibrated:
        rule = replace(
            rule,
            dwell_draws={k: [max(x, rule.dwell_s.get(k, 0.0)) for x in v] for k, v in calibration["draws"].items()},
        )
        source["dwell_s"] = f"drawn from the closed-loop calibration: {calibration['note']}"
    if lag_draws is not None:
        rule = replace(rule, lag_draws=lag_draws)
        source["lag_draws"] = "given (a calibration drive)"
    if calibration is not None and s.lag_calibrated:
        rule = replace(rule, lag_draws=calibration["lag_draws"])
        source["lag_draws"] = f"drawn from the closed-loop calibration: {calibration['note']}"
    if not s.undo_check:
        rule = replace(rule, undo_check=False)
        source["undo_check"] = "off (--no-undo-check)"
    rule = replace(rule, source=source)
    return rule.with_pace(paced) if paced is not None else rule


def plan_drive(
    workspace: Workspace,
    run_id: str,
    settings: DriveSettings,
    sections: Optional[list[float]] = None,
    out: Optional[Path] = None,
    progress: Optional[ProgressFn] = None,
) -> DrivePlan:
    """The drive of the run's agent that the settings (checked when they were made) ask for, ready to
    simulate: what needs the workspace is resolved and checked here. The family: the settings', else that
    of the study the agent learnt from when its drivers drove a laneprint SUMO study
    (`rl.drive.fidelity.drivers_traffic`), else the default. `dwell_calibrated` and `lag_calibrated` left
    None: on in the drivers' own traffic (their family and lanes) with the rule on and not drawn. The run's
    closed-loop calibration is made here when it is wanted and missing (`calibrated`)."""
    from laneprint.simulator.sumo.backend import check_available
    from laneprint.simulator.sumo.settings import DEFAULT_FAMILY

    s = settings
    agent = load_agent(workspace, run_id)
    own = own_traffic(workspace, agent.target)
    family = s.family or (own[0] if own else DEFAULT_FAMILY)
    if family == "sublane":  # the controller reads a lane change under way from the ego leaving its lane centre
        raise SettingError(
            "laneprint drive does not drive on sublanes ({0} sublane): give {0} ttc or acceptance", "family"
        )
    in_own_traffic = own == (family, s.lanes)
    s = replace(
        s,
        family=family,
        dwell_calibrated=(
            s.dwell_calibrated
            if s.dwell_calibrated is not None
            else in_own_traffic and s.held_back and s.dwell and not s.dwell_draw
        ),
        lag_calibrated=(
            s.lag_calibrated if s.lag_calibrated is not None else in_own_traffic and s.held_back and not s.lag_draw
        ),
    )
    limits = check_sections(sections)
    out = Path(out) if out is not None else workspace.root / "drives" / f"{run_id}-s{s.seed}"
    if out.suffix != ".mcap" and out.exists() and not out.is_dir():
        raise SettingError(f"{{0}} {out} exists and is not a folder", "out")
    check_available()
    style, why = ego_style(workspace, agent.target)
    rule, rule_note = held_back_rule(workspace, agent.target, agent.cfg, s.dwell_percentile, s.dwell_draw, s.lag_draw)
    paced = rule_pace(workspace, agent.target, agent.net, agent.cfg, s.pace_by) if rule is not None and s.pace else None
    calibration = None
    if rule is not None and (s.dwell_calibrated or s.lag_calibrated):
        calibration = calibrated(workspace, agent, s, paced, progress)
    return DrivePlan(
        agent,
        s,
        sumo_traffic(s, limits),
        out,
        s.driver_id or f"agent-{run_id}",
        own,
        style,
        why,
        assistant_rule(rule, s, calibration, paced=paced),
        rule_note,
        paced,
        calibration,
    )


def simulate(plan: DrivePlan, progress: Optional[ProgressFn] = None) -> Driven:
    """Drive the plan's sections in SUMO with the agent (and the rule, when on); with `sumo_model` the
    same sections, traffic and seeds again with SUMO's own lane changing of the ego's style."""
    s, agent = plan.settings, plan.agent
    drives = drive_sections(
        agent_q(agent.net, agent.cfg),
        agent.cfg,
        plan.ego_params,
        plan.traffic,
        s.seed,
        progress,
        plan.rule,
        use_rule=s.held_back,
    )
    lanes_opt = "" if s.lanes == 2 else f", {s.lanes} lanes"
    simulator = f"Eclipse SUMO {drives[0].log.sumo_version} (laneprint drive {agent.run_id}, seed {s.seed}{lanes_opt})"
    model = None
    if s.sumo_model:
        model = sumo_model_sections(agent.cfg, plan.ego_params, plan.traffic, s.seed, plan.rule or _NEVER, progress)
    return Driven(drives, recordings(drives, plan.driver_id, simulator), model)


def write_logs(driven: Driven, out: Path) -> list[Path]:
    """Write one LOG_FORMAT v1 MCAP per driven section (`output_paths`); their paths."""
    paths = output_paths(out, [meta["session_id"] for meta, _, _ in driven.recordings])
    for path, (meta, ego, traffic) in zip(paths, driven.recordings):
        path.parent.mkdir(parents=True, exist_ok=True)
        write_mcap(path, meta, ego, traffic)
    return paths


def decision_rows(drives: list[SectionDrive]) -> list[dict[str, Any]]:
    """The agent's change decisions of every section, JSON-ready."""
    return [{"speed_limit_kph": d.speed_limit_kph, **asdict(x)} for d in drives for x in d.decisions]


def drive_report(workspace: Workspace, plan: DrivePlan, driven: Driven, paths: list[Path]) -> dict[str, Any]:
    """The drive's JSON-ready report: per section and in total, the held-back rule, pace, dwell and
    headway, the indicators at the agent's decisions against its lines, the drive beside its drivers,
    SUMO's own model (with the comparator) and the style an analysis gives it (with `analyze`)."""
    s, agent, rule, calibration, own = plan.settings, plan.agent, plan.rule, plan.calibration, plan.own
    log = driven.drives[0].log
    rows = section_rows(driven.drives, paths)
    result: dict[str, Any] = {
        "run_id": agent.run_id,
        "target": agent.config["target"],
        "who_drove": {},  # filled below: who made the lane changes comes first in the report
        "driver_id": plan.driver_id,
        "seed": s.seed,
        "minutes": s.minutes,
        "sumo_version": log.sumo_version,
        "sumo_api": log.api,
        "ego_style": plan.style,
        "ego_style_reason": plan.style_reason,
        "decision_every_s": agent.cfg.dt_s,
        "lanes": s.lanes,
        "family": s.family,
        "drivers_traffic": (
            {"family": own[0], "lanes": own[1], "same_as_drive": own == (s.family, s.lanes)} if own else None
        ),
        "side_input": agent.cfg.observation == "direction",
        "files": [str(p) for p in paths],
        "sections": rows,
        "totals": totals(rows),
        "held_back": {
            "on": bool(s.held_back and rule is not None),
            "rule": rule.to_dict() if rule else None,
            "note": plan.rule_note,
            "desired_speed": f"section limit x speedFactor "
            f"{plan.ego_params.get('speedFactor', 1.0):g} "
            f"(the {plan.style} vType)",
        },
        "pace": plan.paced or {"note": "off (--no-pace)" if rule is not None else "no held-back rule"},
        "dwell": dwell_mode(
            rule, s.held_back, s.dwell_draw, calibration if s.dwell_calibrated else None, s.dwell_percentile
        ),
        "lag": lag_mode(rule, s.held_back, s.lag_draw, bool(s.lag_calibrated)),
        "dwell_calibration": (
            {k: v for k, v in calibration.items() if k not in ("draws", "lag_draws")}
            if calibration and s.dwell_calibrated
            else None
        ),
        "lag_calibration": (
            {k: v for k, v in calibration.items() if k not in ("draws", "lag_draws", "stays")}
            if calibration and s.lag_calibrated
            else None
        ),
        "changes_by_lane": _sum_counts([r["changes_by_lane"] for r in rows]),
        "indicators": indicators_vs_lines(driven.drives, agent.cfg.lines),
        "decisions": decision_rows(driven.drives),
    }
    result["who_drove"] = who_drove(rows, result["totals"], result["held_back"]["on"])
    result["fidelity"] = drivers_fidelity(workspace, agent.target, driven.recordings, s.seed)
    if driven.model is not None:
        result["sumo_model"] = sumo_model_report(driven.model, result["totals"])
    if s.analyze:
        result["analysis"] = assigned_style(workspace, paths, plan.driver_id)
        result["analysis"]["target_style"] = agent.target.name if agent.target.kind == "style" else None
    return result


def drive_run(
    workspace: Workspace,
    run_id: str,
    settings: Optional[DriveSettings] = None,
    *,
    sections: Optional[list[float]] = None,
    out: Optional[Path] = None,
    progress: Optional[ProgressFn] = None,
) -> dict[str, Any]:
    """Drive the run's agent in SUMO as `settings` ask (`DriveSettings`, each field documented there) on
    the `sections` (speed limits; default all), write the MCAPs to `out` (default
    WORKSPACE/drives/RUN_ID-sSEED/; a folder also gets the report as drive.json) and return the report:
    `plan_drive`, `simulate`, `write_logs`, `drive_report`."""
    plan = plan_drive(workspace, run_id, settings or DriveSettings(), sections, out, progress)
    driven = simulate(plan, progress)
    paths = write_logs(driven, plan.out)
    result = drive_report(workspace, plan, driven, paths)
    if plan.out.suffix != ".mcap":
        atomic_write_json(plan.out / "drive.json", result)
    return result
