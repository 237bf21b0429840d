"""`laneprint drive RUN_ID --engine sumo`: a trained agent drives in SUMO (see `rl/drive/loop.py`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from laneprint.cliutil import DEFAULT_WS, JsonOpt, WorkspaceOpt, progress_bar, run_command
from laneprint.workspace import Workspace
from laneprint.options import Section, Settings, configurable
from rl.drive.heldback import by_side_text
from rl.drive.settings import DriveSettings
from rl.drive.attribution import made_by


def _f(x: Any, spec: str = ".2f") -> str:
    return "-" if x is None else format(x, spec)


@configurable("drive", Section("drive", DriveSettings, visible=("minutes", "seed", "lanes", "family", "analyze")))
def drive_command(
    settings: Settings,
    run_id: Annotated[str, typer.Argument(help="A trained run of the workspace (see `laneprint train`).")],
    section: Annotated[
        Optional[list[float]],
        typer.Option(
            "--section", help="Speed limit in km/h of a section to drive, repeatable (default 60, 70, 80, 90)."
        ),
    ] = None,
    out: Annotated[
        Optional[Path],
        typer.Option(
            "--out",
            "-o",
            help="FILE.mcap (one section; <stem>_S<limit>.mcap for several) or a folder "
            "(default WORKSPACE/drives/RUN_ID-sSEED/).",
        ),
    ] = None,
    workspace: WorkspaceOpt = DEFAULT_WS,
    as_json: JsonOpt = False,
) -> None:
    """Let a trained agent make the ego's lane changes in SUMO traffic; write the drive as MCAP logs."""

    def work() -> dict[str, Any]:
        from rl.drive.store import drive_run

        with progress_bar(not as_json) as bar:
            return drive_run(Workspace(workspace), run_id, settings.drive, sections=section, out=out, progress=bar)

    run_command(work, as_json, render)


def _per_km(r: dict[str, Any]) -> Optional[float]:
    return r["lane_changes"] / r["km"] if r.get("km") else None


def render_model(result: dict[str, Any], console: Console) -> None:
    """The comparator beside the agent: SUMO's own model of the style in the same traffic."""
    m = result["sumo_model"]
    t = Table(title=f"SUMO's own lane changing (LC2013, {result['ego_style']} vType), same traffic and seeds")
    for c in (
        "section",
        "lane changes (L/R)",
        "per km",
        "agent per km",
        "collisions",
        "emergency brakes",
        "held back",
        "longest passed up [s]",
    ):
        t.add_column(c, justify="right")
    agent = result["sections"] + [dict(result["totals"], speed_limit_kph=None)]
    for r, a in zip(m["sections"] + [dict(m["totals"], speed_limit_kph=None)], agent):
        t.add_row(
            "total" if r["speed_limit_kph"] is None else f"{r['speed_limit_kph']:g} km/h",
            f"{r['lane_changes']} ({r['left']}/{r['right']})",
            _f(_per_km(r)),
            _f(_per_km(a)),
            str(r["collisions"]),
            str(r["emergency_brakes"]),
            _f(r["follow"]["held_share"], ".0%"),
            _f(r["follow"]["longest_passed_up_s"], ".1f"),
        )
    console.print(t)
    console.print(f"agent / SUMO's model, lane changes per km: {_f(m['rate_ratio'])}", highlight=False)


def _ci(pair: Any, spec: str = ".2f") -> str:
    return "" if not pair or pair[0] is None else f" [{format(pair[0], spec)}, {format(pair[1], spec)}]"


def render_fidelity(fid: dict[str, Any], console: Console) -> None:
    """The drive beside its target drivers: lane changes per km, sides, indicators at the presses."""
    if "rate" not in fid:
        console.print(fid.get("note", "no comparison with the drivers"), highlight=False, soft_wrap=True)
        return
    r = fid["rate"]
    a, d = r["agent"], r["drivers"]
    rng = d["per_km_range"]
    console.print(
        f"like its drivers ({', '.join(fid['drivers'])}): lane changes per km {_f(a['per_km'])}{_ci(a['per_km_ci'])} "
        f"against {_f(d['per_km'])}{_ci(d['per_km_ci'])} (drivers {_f(rng[0]) if rng else '-'}-"
        f"{_f(rng[1]) if rng else '-'}), ratio {_f(r['ratio'])} "
        f"({'within' if r['within_tolerance'] else 'outside'} +-{fid['tolerance']:.0%}); to the left "
        f"{_f(a['left_share'], '.0%')} against {_f(d['left_share'], '.0%')}",
        highlight=False,
        soft_wrap=True,
    )
    if "lanes" in fid:
        render_lanes(fid["lanes"], console)
    t = Table(
        title=f"indicators at the drive's {fid['agent_presses']} presses against the drivers' "
        f"(read as the analysis reads a log; medians with 95 % intervals)"
    )
    for c in (
        "indicator",
        "n drive / drivers",
        "drive median [95 %]",
        "drivers median [95 %]",
        "drivers IQR",
        "in IQR",
        "Wasserstein",
        "KS (p)",
    ):
        t.add_column(c, justify="right")
    for name, v in fid["indicators"].items():
        x, y = v["agent"], v["drivers"]
        t.add_row(
            name,
            f"{x['n']} / {y['n']}",
            _f(x["median"], ".1f") + _ci(x["median_ci"], ".1f"),
            _f(y["median"], ".1f") + _ci(y["median_ci"], ".1f"),
            f"{_f(y['q1'], '.1f')}-{_f(y['q3'], '.1f')}",
            "-" if v["median_in_iqr"] is None else ("yes" if v["median_in_iqr"] else "no"),
            _f(v["wasserstein"], ".1f"),
            f"{_f(v['ks'])} ({_f(v['ks_p'])})",
        )
    console.print(t)


def render_lanes(lanes: dict[str, Any], console: Console) -> None:
    """Time in each lane and lane changes per km by lane pair, the drive's against the drivers'."""
    a, d = lanes["agent"], lanes["drivers"]
    share = sorted(set(a["time_share"]) | set(d["time_share"]), key=int)
    pairs = sorted(set(a["pairs_per_km"]) | set(d["pairs_per_km"]))
    console.print(
        "by lane, drive against drivers: time in lane "
        + ", ".join(
            f"{k} {_f(a['time_share'].get(k, 0.0), '.0%')} / {_f(d['time_share'].get(k, 0.0), '.0%')}" for k in share
        )
        + "; changes per km "
        + ", ".join(f"{k} {_f(a['pairs_per_km'].get(k, 0.0))} / {_f(d['pairs_per_km'].get(k, 0.0))}" for k in pairs),
        highlight=False,
        soft_wrap=True,
    )


def _by_whom(row: dict[str, Any]) -> str:
    """'0 / 20 / 8' (agent / rule held back / rule return), with '+ 1 not requested' when SUMO made one."""
    m = made_by(row)
    extra = f" + {m['unattributed']} not requested" if m["unattributed"] else ""
    return f"{m['agent']} / {m['rule_held_back']} / {m['rule_return']}{extra}"


def _own_traffic(result: dict[str, Any]) -> str:
    own = result.get("drivers_traffic")
    if not own:
        return " (its drivers drove another simulator)"
    if own["same_as_drive"]:
        return " (its drivers' own)"
    return f" (its drivers drove {own['family']} traffic on {own['lanes']} lanes)"


def render(result: dict[str, Any], console: Console) -> None:
    """Who made the lane changes (first: the agent, or the assistant's rule and which part of it), the drive's
    tables per section, then the indicators at the agent's decisions against its lines."""
    who = result.get("who_drove") or {}
    if who.get("text"):
        console.print(f"[bold]{escape(who['text'])}[/bold]", highlight=False, soft_wrap=True)
        console.print(
            "(the rule: the assistant's held-back rule, `laneprint drive --no-held-back` drives without it; "
            "'held back': it changed lane after a slower leader held the ego back for its patience, "
            "'return': it completed an overtaking, back into the lane left)",
            highlight=False,
            soft_wrap=True,
        )
    t = Table(
        title=f"{result['run_id']} ({result['target']['kind']} {result['target']['name']}) in SUMO "
        f"{result['sumo_version']}: {result.get('lanes', 2)} lanes, {result.get('family', 'ttc')} traffic"
        f"{_own_traffic(result)}, "
        f"{result['minutes']:g} min per section, "
        f"seed {result['seed']}, "
        f"ego vType {result['ego_style']}, asked every {result['decision_every_s']:g} s"
    )
    cols = (
        "section",
        "asked",
        "decided",
        "lane changes (L/R)",
        "by agent / held back / return",
        "per km",
        "not started",
        "collisions",
        "emergency brakes",
        "held back",
        "longest passed up [s]",
    )
    for c in cols:
        t.add_column(c, justify="right")
    for r in result["sections"] + [dict(result["totals"], speed_limit_kph=None)]:
        t.add_row(
            "total" if r["speed_limit_kph"] is None else f"{r['speed_limit_kph']:g} km/h",
            str(r["decisions_asked"]),
            str(r["change_decisions"]),
            f"{r['lane_changes']} ({r['left']}/{r['right']})",
            _by_whom(r),
            _f(_per_km(r)),
            str(r["not_started"]),
            str(r["collisions"]),
            str(r["emergency_brakes"]),
            _f(r["follow"]["held_share"], ".0%"),
            _f(r["follow"]["longest_passed_up_s"], ".1f"),
        )
    console.print(t)
    hb = result.get("held_back") or {}
    if hb.get("rule"):
        rule = hb["rule"]
        console.print(
            f"held-back rule {'on' if hb['on'] else 'off (--no-held-back: measured only)'}: patience "
            f"{rule['patience_s']:g} s ({rule['source'].get('patience_s', '')}); desired speed "
            f"{hb['desired_speed']}; 'longest passed up': the longest time, while held back, that a "
            "neighbouring lane held a gap the target accepts",
            highlight=False,
            soft_wrap=True,
        )
        dwell = ", ".join(f"{k} {v:.1f} s" for k, v in rule.get("dwell_s", {}).items()) or "none"
        console.print(
            f"dwell after a lane change: {result.get('dwell', '')}; floor {dwell}; "
            f"decision steps with a side held by it: {result['totals']['follow'].get('dwelled', 0)}",
            highlight=False,
            soft_wrap=True,
        )
        console.print(
            f"follower's headway the agent's own changes need: {result.get('lag', '')}", highlight=False, soft_wrap=True
        )
        tot, fo = result["totals"], result["totals"]["follow"]
        console.print(
            f"of the rule's {tot['rule_changes']} changes, {tot['return_changes']} completed an overtaking; "
            f"agent's changes not requested: {fo.get('vetoed', 0)} decision steps back behind the leader "
            f"an overtaking left, {fo.get('gated', 0)} into a gap below the target's floors, "
            f"{fo.get('lagged', 0)} in front of a follower closer than the headway drawn, "
            f"{fo.get('undone', 0)} to the left with no leader that it would at once undo",
            highlight=False,
            soft_wrap=True,
        )
    else:
        console.print(hb.get("note", "no held-back rule"), highlight=False, soft_wrap=True)
    pace = result.get("pace") or {}
    if "min_advantage" in pace:
        needs = by_side_text(pace.get("min_advantage_by_side", {})) or f"{pace['min_advantage']:g}"
        console.print(
            f"pace: the agent's own change needs an advantage of at least {needs} ({pace['note']})",
            highlight=False,
            soft_wrap=True,
        )
    elif pace:
        console.print(f"pace: {pace['note']}", highlight=False, soft_wrap=True)
    if "sumo_model" in result:
        render_model(result, console)
    if result.get("lanes", 2) > 2:
        console.print(
            "lane changes by lane (from>to): "
            + (", ".join(f"{k} {v}" for k, v in result["changes_by_lane"].items()) or "none"),
            highlight=False,
            soft_wrap=True,
        )
        if not result.get("side_input"):
            console.print(
                "note: the run's observation has no side input (train with --observation direction): "
                "it is asked about both sides alike",
                highlight=False,
                soft_wrap=True,
            )
    ind = result["indicators"]
    it = Table(
        title=f"indicators at the {ind['n_decisions']} changes made (the agent's and the rule's) "
        f"vs its target's lines "
        f"({ind['lines'].get('source') or 'run lines'})"
    )
    for c in ("indicator", "defined", "median", "line (median)", "MAE", "bias"):
        it.add_column(c, justify="right")
    for name in ("t_f", "t_nf", "dv_nb"):
        r = ind[name]
        it.add_row(name, str(r["n"]), _f(r["median"]), _f(r["line_median"]), _f(r["mae"]), _f(r["bias"]))
    console.print(it)
    if "fidelity" in result:
        render_fidelity(result["fidelity"], console)
    if "analysis" in result:
        a = result["analysis"]
        verdict = (
            ""
            if a["target_style"] is None
            else (
                " (its target)"
                if str(a["style"]).lower() == a["target_style"].lower()
                else f" (target {a['target_style']})"
            )
        )
        console.print(
            f"analysis of the study plus the drive: {a['driver_id']} is {a['style']}{verdict}, "
            f"confidence {_f(a['confidence'])}",
            highlight=False,
            soft_wrap=True,
        )
    console.print("wrote " + ", ".join(result["files"]), highlight=False, soft_wrap=True, markup=False)
