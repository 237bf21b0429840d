"""The held-back rule of the assistant: leave a slower leader the agent would follow for ever.

Why (issue 19, "out of its world"): the agents learn from the study's presses, and its
drivers press almost only while closing in on a leader (t_f defined, median 4.1 s on the
shipped study). A leader the ego has caught up with and follows at its speed (closing
speed < 1 m/s: t_f undefined) never looks like a press scene to them, so in other
traffic they follow slower leaders for minutes while the next lane is free. The agent is
right about the scenes it learnt; the gap is a situation its data does not hold. So the
assistant, not the agent, carries a rule for it:

    when the ego has been **held back** for `patience_s` (a leader in its lane within
    range is slower than the ego's desired speed by `slower_mps`, and the ego itself is
    that much below its desired speed), and a neighbouring lane holds a gap the target
    **accepts** (lead gap, lag gap and the follower's time headway at least the target's
    lines at the ego's speed) and is **faster** (no leader there within range, or one at
    least `slower_mps` faster than the ego's leader), request the change.

An overtaking (a change to the left from behind a leader, the rule's or the agent's) is carried
through (`LeftBehind`): **until it is over** (the ego has passed the leader it left: that
vehicle's centre behind the ego's, or out of sight; or that leader no longer holds the ego back:
it is as fast as the ego's desired speed less `slower_mps`, the limit of being held back) the
agent's change back into the lane it left is not requested, and **once over**, when the agent
keeps and that lane holds a gap the target accepts, the assistant returns there (source 'return').
Overtakings stack: on three lanes, one from lane 0 to 1 and then one from 1 to 2 are completed in
turn, back to lane 1 and then to lane 0 (keep right to where the ego came from). Measured why:
without the first, the shipped study's Defensive agent returned right 5-8 s after most of the
rule's changes, behind the truck it had followed (t_nf about 4 s), and weaved every 15 s; without
the second, once the floors below kept it from cutting in, the agents stayed in the left lane after
an overtaking (their study's presses to the right are closing-in scenes too: a free right lane is
none), the Normal one changing lane 0.3 times per km against SUMO's model's 2.7-3.4; without the
stack, on three lanes they stayed in the middle lane.

The same lines also give the assistant a **floor** under every change, the agent's included: no
change is requested into a gap smaller than the smallest the target took (each line's `floor`,
the 5th percentile of its presses' values; `above_floors`). Out of its world the agent can ask
for a change no driver of its study made (measured: the shipped study's Aggressive agent, in
SUMO, returned right with a lead gap of about 1 m, t_nf 0.9 s, and collided; the Normal one with
a lead gap above its floor but t_nf 0.8 s, closing at 13 m/s). The time to collision with the
target lane's leader has a floor too (`t_nf_floor_s`, the 5th percentile of t_nf at the presses).

Above the floor, the agent's own change in front of a near follower can need that follower's **time
headway drawn** at each lane change, per side (`lag_draws`, `lag_accepted`): until the next change its
own changes to that side wait for at least the headway drawn. Why: the agent decides state by state
and, asked every 0.5 s, changes at the first state that reads as a press, near the low end of its
drivers' spread. Returning right past an overtaken car the follower's headway only grows, so on study
723 the Defensive agent returned at a median 0.81 s where its drivers returned at 2.45 s (their IQR
1.02-3.77; replayed along its own training approaches it changed a median 3 s before its drivers'
returns). A driver's critical gap is itself a draw (traffic engineering's gap acceptance). In its
drivers' own traffic the draws are calibrated in closed loop (`rl.drive.calibrate`, the default there);
`drive --lag-draw` draws from the headways at which the target's drivers pressed to that side with a
follower within `far_follower_m` (`lag_headways`); elsewhere the floors alone hold it.

And with no leader within range, a change of the agent's **to the left is requested only if the
agent would not undo it** at once (`undo_check`; `rl.drive.loop.AgentControl.would_undo`): put in
the target lane as the traffic is, and asked about the lane it would leave, it must not want back
(advantage below its pace's `min_advantage`). With nothing to pass, an agent that does not know the
side (it learnt returns to the right as changes into a free lane) wants both ways and weaves
(measured on study 660: README).

Where its numbers come from (`rule_from_analysis`):

- accepted gaps: the analysis's reference lines of the target (a style's typical driver,
  or the driver) for `gap_nf`, `gap_nb` and `thw_nb` (`indicators/acceptance.py`: what the
  driver accepted at its presses; a flagged line is the driver's level), read within the
  speeds of the fit's presses (as the clustering reads feature lines: no extrapolation);
  a follower beyond `far_follower_m` does not count (as in the analysis's fits).
  The lines are central values at the presses, so the rule takes only gaps at least as
  large as the typical press's: a conservative choice for a rule that acts on its own.
- patience: the median time the target's drivers had followed their leader (closing
  speed below the analysis's `min_closing_mps`, 1 m/s) right before a press, over the
  presses that came after following (shipped study: 5.5-7.25 s per style, 12-16 presses
  each, 8 % of all); with fewer than `MIN_FOLLOWED` such presses, `DEFAULT_PATIENCE_S`.
- desired speed: not in the data (the study's drivers drive at their own speed); the
  vehicle's set speed. `laneprint drive` uses the section's limit times the ego vType's
  SUMO `speedFactor`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import Any, Optional

import numpy as np
import pandas as pd

from laneprint.reference import FAR_FOLLOWER_M
from rl.problem.scene import Scene, gaps, indicators, seen

#: the target lane's indicators the rule reads (`indicators.acceptance`)
ACCEPT_INDICATORS: tuple[str, ...] = ("gap_nf", "gap_nb", "thw_nb")
FOLLOWING_MPS = 1.0  # [m/s] closing speed below which the ego follows its leader (AnalysisSettings.min_closing_mps)
MIN_FOLLOWED = 5  # presses after following needed to read a patience from the data
DEFAULT_PATIENCE_S = 10.0  # [s] patience when the data has too few presses after following
SLOWER_MPS = 1.0  # [m/s] how much slower than desired a leader (and the ego) must be to hold the ego back


@dataclass(frozen=True)
class Line:
    """An acceptance line `value = A v_e + b`, read with v_e clipped to [v_lo, v_hi] (the fit's presses)
    and never below `floor` (the 5th percentile of the values at the presses: a line read at a low
    speed can fall under anything the driver took)."""

    A: float
    b: float
    v_lo: float = 0.0
    v_hi: float = np.inf
    floor: float = 0.0

    def at(self, v_e: np.ndarray | float) -> np.ndarray:
        return np.maximum(self.A * np.clip(np.asarray(v_e, dtype=float), self.v_lo, self.v_hi) + self.b, self.floor)


@dataclass(frozen=True)
class HeldBackRule:
    """The rule's numbers (see the module doc); `source` says where each came from."""

    patience_s: float
    gap_nf: Line  # [m] lead gap in the target lane
    gap_nb: Line  # [m] lag gap in the target lane
    thw_nb: Line  # [s] the target-lane follower's time headway to the ego
    slower_mps: float = SLOWER_MPS
    far_follower_m: float = FAR_FOLLOWER_M
    t_nf_floor_s: float = 0.0  # [s] no change closing in on the target lane's leader faster than this
    dv_nb_floor_mps: float = -np.inf  # [m/s] no change in front of a follower closing faster than -this (<= 0)
    dwell_s: dict[str, float] = field(default_factory=dict)  # 'left>right' etc.: least time from a change to the next
    min_advantage: float = 0.0  # the agent's own change needs Q(change) - Q(keep) at least this (rl.drive.pace)
    min_advantage_by_side: dict[str, float] = field(default_factory=dict)  # 'left'/'right': this instead, by side
    undo_check: bool = True  # with no leader, no change of the agent's to the left that it would at once undo
    source: dict[str, str] = field(default_factory=dict)
    # 'left>right' etc.: what each lane change draws the next dwell of that kind from (`draw_dwell`) instead
    # of `dwell_s`: the drivers' own times from a change to the next press (`drive --dwell-draw`) or the
    # closed-loop calibration's dwells (`drive --dwell-calibrated`, `rl.drive.calibrate`)
    dwell_draws: dict[str, list[float]] = field(default_factory=dict)
    # 'left'/'right': the drivers' follower time headways (thw_nb) at their presses to that side with a
    # follower within far_follower_m; the agent's own change to a side needs a follower headway at least
    # the one drawn for that side at the ego's last lane change (`draw_lag`, `lag_accepted`)
    lag_draws: dict[str, list[float]] = field(default_factory=dict)

    def dwell_ok(
        self, last_side: Optional[str], since_s: float, side: str, drawn: Optional[dict[str, float]] = None
    ) -> bool:
        """Whether a change to `side` may be requested `since_s` after the last lane change (to `last_side`);
        `drawn`: the dwells drawn at that change (`draw_dwell`), where they replace `dwell_s`."""
        if last_side is None:
            return True
        kind = f"{last_side}>{side}"
        return since_s >= (drawn[kind] if drawn and kind in drawn else self.dwell_s.get(kind, 0.0))

    def draw_dwell(self, last_side: str, rng: np.random.Generator) -> dict[str, float]:
        """At a lane change to `last_side`: one dwell per kind that starts there, each drawn from that kind's
        `dwell_draws` (empty when there are none)."""
        return {k: float(rng.choice(v)) for k, v in sorted(self.dwell_draws.items()) if k.startswith(f"{last_side}>")}

    def draw_lag(self, rng: np.random.Generator) -> dict[str, float]:
        """One follower headway [s] per side that the agent's own changes to it need until the next lane
        change, each drawn from that side's `lag_draws` (empty when there are none)."""
        return {k: float(rng.choice(v)) for k, v in sorted(self.lag_draws.items()) if v}

    def needs(self, side: str) -> float:
        """The advantage the agent's own change to `side` ('left' or 'right') needs (its drivers' pace)."""
        return self.min_advantage_by_side.get(side, self.min_advantage)

    def with_pace(self, pace: dict[str, Any]) -> "HeldBackRule":
        """This rule with the pace `rl.drive.pace.pace_threshold` found (one threshold, or one per side)."""
        return replace(
            self,
            min_advantage=pace["min_advantage"],
            min_advantage_by_side=dict(pace.get("min_advantage_by_side", {})),
            source={**self.source, "min_advantage": pace["note"]},
        )

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["dv_nb_floor_mps"] = None if not np.isfinite(self.dv_nb_floor_mps) else self.dv_nb_floor_mps
        for k in ACCEPT_INDICATORS:  # JSON has no infinity
            d[k]["v_hi"] = None if not np.isfinite(d[k]["v_hi"]) else d[k]["v_hi"]
        return d

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "HeldBackRule":
        d = dict(d)
        if d.get("dv_nb_floor_mps", 0.0) is None:
            d["dv_nb_floor_mps"] = -np.inf
        for k in ACCEPT_INDICATORS:
            line = dict(d[k])
            line["v_hi"] = np.inf if line.get("v_hi") is None else line["v_hi"]
            d[k] = Line(**line)
        return HeldBackRule(**d)


def target_gaps(scene: Scene, range_m: float) -> dict[str, np.ndarray]:
    """Lead gap, lag gap [m] and the follower's time headway [s] of each scene (NaN where not defined)."""
    return {k: v for k, v in gaps(scene, range_m).items() if k in ACCEPT_INDICATORS}


def accepts(rule: HeldBackRule, scene: Scene, range_m: float) -> np.ndarray:
    """Whether each scene's target lane holds a gap the target accepts (absent vehicles constrain nothing)."""
    g = target_gaps(scene, range_m)
    lead_ok = ~np.isfinite(g["gap_nf"]) | (g["gap_nf"] >= rule.gap_nf.at(scene.v_e))
    near = np.isfinite(g["gap_nb"]) & (g["gap_nb"] <= rule.far_follower_m)
    lag_ok = g["gap_nb"] >= rule.gap_nb.at(scene.v_e)
    thw_ok = ~np.isfinite(g["thw_nb"]) | (g["thw_nb"] >= rule.thw_nb.at(scene.v_e))
    return lead_ok & (~near | (lag_ok & thw_ok))


def above_floors(rule: HeldBackRule, scene: Scene, range_m: float) -> np.ndarray:
    """Whether each scene's target lane has no gap below the smallest the target took (the lines' floors),
    no leader there closer in time to collision than the smallest t_nf it took, and no follower there
    closing on the ego faster than any it let close (dv_nb below its floor)."""
    g = target_gaps(scene, range_m)
    ind = indicators(scene, rule.far_follower_m, range_m)
    t_nf = np.where(ind.t_nf_ok, ind.t_nf, np.inf)
    lead_ok = (~np.isfinite(g["gap_nf"]) | (g["gap_nf"] >= rule.gap_nf.floor)) & (t_nf >= rule.t_nf_floor_s)
    near = np.isfinite(g["gap_nb"]) & (g["gap_nb"] <= rule.far_follower_m)
    thw_ok = ~np.isfinite(g["thw_nb"]) | (g["thw_nb"] >= rule.thw_nb.floor)
    dv_ok = ~ind.dv_nb_ok | (ind.dv_nb >= rule.dv_nb_floor_mps)
    return lead_ok & (~near | ((g["gap_nb"] >= rule.gap_nb.floor) & thw_ok & dv_ok))


def lag_accepted(rule: HeldBackRule, scene: Scene, range_m: float, headway_s: float) -> np.ndarray:
    """Whether each scene's target lane has no follower within `rule.far_follower_m`, or one whose time
    headway to the ego (thw_nb) is at least `headway_s` (a stopped follower's is not defined: accepted)."""
    g = target_gaps(scene, range_m)
    near = np.isfinite(g["gap_nb"]) & (g["gap_nb"] <= rule.far_follower_m)
    return ~near | (np.nan_to_num(g["thw_nb"], nan=np.inf) >= headway_s)


def faster(rule: HeldBackRule, scene: Scene, range_m: float) -> np.ndarray:
    """Whether each scene's target lane is faster than the ego's: no leader there within range, or one at
    least `slower_mps` faster than the ego's leader."""
    _, nf, _ = seen(scene, range_m)
    return ~nf | (scene.v_nf >= scene.v_f + rule.slower_mps)


def by_side_text(by_side: dict[str, float]) -> str:
    """'0.4 to the left, 0 to the right' ('' when empty): the pace's thresholds by side."""
    return ", ".join(f"{v:g} to the {k}" for k, v in by_side.items())


def holding_limit(desired_mps: float, slower_mps: float) -> float:
    """The speed [m/s] below which a leader holds the ego back: its desired speed less `slower_mps`."""
    return desired_mps - slower_mps


def held_back(scene: Scene, desired_mps: float, slower_mps: float, range_m: float) -> bool:
    """The ego (first scene) follows a leader slower than its desired speed and is itself held below it."""
    f, _, _ = seen(scene, range_m)
    limit = holding_limit(desired_mps, slower_mps)
    return bool(f[0] and scene.v_f[0] < limit and scene.v_e[0] < limit)


@dataclass
class HeldBackClock:
    """How long the ego has been held back without a break, from the decision steps it is told about."""

    since: Optional[float] = None

    def update(self, t_s: float, held: bool) -> float:
        """The time held back at `t_s` (0 when not held back now)."""
        if not held:
            self.since = None
            return 0.0
        if self.since is None:
            self.since = t_s
        return t_s - self.since

    def reset(self) -> None:
        self.since = None


def rule_target(rule: HeldBackRule, scenes: dict[int, Scene], held_for_s: float, range_m: float) -> Optional[int]:
    """The lane the rule asks for (the faster of the accepted ones; None: the rule does not fire)."""
    if held_for_s < rule.patience_s:
        return None
    ok = [k for k, s in scenes.items() if bool(accepts(rule, s, range_m)[0] and faster(rule, s, range_m)[0])]
    if not ok:
        return None

    def speed(k: int) -> float:
        f, nf, _ = seen(scenes[k], range_m)
        return float(scenes[k].v_nf[0]) if nf[0] else np.inf

    return max(sorted(ok, reverse=True), key=speed)  # max keeps the first of equals: the left lane


@dataclass(frozen=True)
class LeftBehind:
    """The lane an overtaking left (a change to the left from behind a leader) and that leader."""

    lane: int
    leader_id: str

    def passed(self, ego_x: float, others: dict[str, Any], range_m: float) -> bool:
        """The ego has passed that leader (its centre behind the ego's), or it is out of sight."""
        st = others.get(self.leader_id)
        return st is None or st.x < ego_x or st.x - ego_x > range_m

    def over(self, ego_x: float, others: dict[str, Any], range_m: float, holding_mps: float) -> bool:
        """The overtaking is over: that leader is passed or out of sight, or it no longer holds the ego
        back (its speed at least `holding_mps`, the held-back rule's `holding_limit`). A leader that has
        sped up is not being overtaken: behind it the ego does not catch up again (measured on study 662:
        the Aggressive agent waited in the fast lane, its return vetoed, while the car it had changed out
        behind pulled away to 146 m ahead)."""
        st = others.get(self.leader_id)
        return self.passed(ego_x, others, range_m) or (st is not None and st.v >= holding_mps)

    def vetoes(self, target: int, ego_x: float, others: dict[str, Any], range_m: float, holding_mps: float) -> bool:
        """A change to `target` would return behind the leader while the overtaking is not over."""
        return target == self.lane and not self.over(ego_x, others, range_m, holding_mps)


# --- from the analysis --------------------------------------------------------------------


_COLUMN = {"gap_nf": "nf_gap_m", "gap_nb": "nb_gap_m", "thw_nb": "thw_nb_s"}  # indicator -> decisions column
FLOOR_PERCENTILE = 5.0
#: The dwell's percentile of the drivers' times from a lane change to the next press (`drive
#: --dwell-percentile`). At 5, the drivers' floor, a third to half of the agents' stays in the left lane
#: on the `acceptance` family's study 647 end within a second of it (an agent without memory wants back
#: as soon as the dwell allows); 25 brings that family's closed loop near its drivers but takes the
#: shipped study's Aggressive agent under half of SUMO's model's rate out of its world (README, 'The
#: dwell'), so the default stays the floor. `drive --dwell-draw` draws each dwell from the drivers' times
#: instead (`HeldBackRule.dwell_draws`; README, 'The dwell drawn').
DWELL_PERCENTILE = FLOOR_PERCENTILE
MIN_DWELL_PAIRS = 5  # consecutive lane changes of a kind needed to read a dwell from the data


MIN_LAG_PRESSES = 10  # presses to a side with a near follower needed to draw that side's headways alone


def lag_headways(decisions: pd.DataFrame, far_follower_m: float = FAR_FOLLOWER_M) -> dict[str, list[float]]:
    """Per side ('left'/'right'), the follower time headways thw_nb [s] at the drivers' presses to that
    side with a follower within `far_follower_m`; a side with fewer than `MIN_LAG_PRESSES` takes both
    sides' together, and with fewer than that in all there are none."""
    p = decisions[(decisions["label"] == "change") & decisions["lc_direction"].isin(["left", "right"])]
    p = p[(p["nb_gap_m"] <= far_follower_m) & np.isfinite(p["thw_nb_s"].astype(float))]
    if len(p) < MIN_LAG_PRESSES:
        return {}
    pooled = sorted(p["thw_nb_s"].astype(float).tolist())
    by_side = {side: sorted(g["thw_nb_s"].astype(float).tolist()) for side, g in p.groupby("lc_direction")}
    return {
        side: (by_side[side] if len(by_side.get(side, [])) >= MIN_LAG_PRESSES else pooled) for side in ("left", "right")
    }


def dwell_times(decisions: pd.DataFrame) -> dict[str, list[float]]:
    """Per kind of consecutive presses ('left>right' etc.), the drivers' times [s] from a lane change to
    the next press in the same recording."""
    p = decisions[(decisions["label"] == "change") & decisions["lc_direction"].notna()]
    p = p.sort_values(["recording_id", "press_t_s"])
    gaps_by: dict[str, list[float]] = {}
    for _, rec in p.groupby("recording_id", sort=False):
        t_press = rec["press_t_s"].to_numpy(dtype=float)
        t_change = rec["lane_change_t_s"].to_numpy(dtype=float)
        side = rec["lc_direction"].astype(str).to_numpy()
        last = None
        for i in range(len(rec)):
            if last is not None and t_press[i] > t_change[last]:
                gaps_by.setdefault(f"{side[last]}>{side[i]}", []).append(float(t_press[i] - t_change[last]))
            if np.isfinite(t_change[i]):
                last = i
    return dict(sorted(gaps_by.items()))


def dwell_from(decisions: pd.DataFrame, percentile: float = DWELL_PERCENTILE) -> tuple[dict[str, float], str]:
    """(least time [s] from a lane change to the next press, per kind 'left>right' etc., where from):
    `percentile` over the drivers' consecutive changes in one recording (`dwell_times`), for kinds with
    at least `MIN_DWELL_PAIRS` of them. The agent decides state by state without memory; the drivers do
    not press again at once after a change (measured: without this the agents changed back 3 s after a
    change, the drivers never sooner than 5-16 s after a change to the left), and an agent that wants
    back at once comes back as soon as the dwell allows (`DWELL_PERCENTILE`)."""
    gaps_by = dwell_times(decisions)
    dwell = {k: float(np.percentile(v, percentile)) for k, v in gaps_by.items() if len(v) >= MIN_DWELL_PAIRS}
    counts = ", ".join(f"{k} {len(v)}" for k, v in gaps_by.items()) or "none"
    return dwell, f"percentile {percentile:g} of the time from a lane change to the next press ({counts})"


def _line(
    lines: pd.DataFrame, fits: Optional[pd.DataFrame], ind: str, typical: Optional[str], presses: pd.DataFrame
) -> tuple[Line, str]:
    row = lines[lines["indicator"] == ind]
    if row.empty:
        raise KeyError(ind)
    r = row.iloc[0]
    v_lo, v_hi, span = 0.0, np.inf, ""
    if fits is not None and typical is not None:
        fit = fits[(fits["driver_id"].astype(str) == typical) & (fits["indicator"] == ind)]
        if len(fit) and np.isfinite(fit["v_min"].iloc[0]) and np.isfinite(fit["v_max"].iloc[0]):
            v_lo, v_hi = float(fit["v_min"].iloc[0]), float(fit["v_max"].iloc[0])
            span = f", read within {v_lo:.1f}-{v_hi:.1f} m/s"
    vals = presses[_COLUMN[ind]].to_numpy(dtype=float) if _COLUMN[ind] in presses else np.array([])
    vals = vals[np.isfinite(vals)]
    floor = float(np.percentile(vals, FLOOR_PERCENTILE)) if len(vals) else 0.0
    span += f", at least {floor:.2f} (percentile {FLOOR_PERCENTILE:g} of {len(vals)} presses)" if len(vals) else ""
    return Line(float(r["A"]), float(r["b"]), v_lo, v_hi, floor), f"{r['source']}{span}"


def _finite(presses: pd.DataFrame, column: str) -> np.ndarray:
    x = presses[column].to_numpy(dtype=float) if column in presses else np.array([])
    return x[np.isfinite(x)]


def following_before_press(decisions: pd.DataFrame, step_s: float = 0.5) -> np.ndarray:
    """Per press, how long [s] the driver had followed its leader (present, closing slower than
    `FOLLOWING_MPS`) over the states right before it, the press's own state included; 0 when not."""
    d = decisions.sort_values(["recording_id", "press_index", "t_s"])
    closing = (d["ego_v_mps"] - d["f_v_mps"]).to_numpy(dtype=float)
    follow = d["f_present"].to_numpy(dtype=bool) & (np.nan_to_num(closing, nan=np.inf) < FOLLOWING_MPS)
    out = []
    press = (d["label"] == "change").to_numpy()
    for _, idx in d.groupby(["recording_id", "press_index"], sort=False).indices.items():
        if not press[idx[-1]]:
            continue  # an approach that ends without a press
        run = follow[idx][::-1]
        n = len(run) if run.all() else int(np.argmin(run))
        out.append(n * step_s)
    return np.asarray(out, dtype=float)


def patience_from(decisions: pd.DataFrame, step_s: float = 0.5) -> tuple[float, str]:
    """(patience [s], where it came from): the median following time before the presses that came
    after following, or `DEFAULT_PATIENCE_S` with fewer than `MIN_FOLLOWED` of them."""
    times = following_before_press(decisions[decisions["press_index"].notna()], step_s)
    followed = times[times > 0]
    if len(followed) < MIN_FOLLOWED:
        return DEFAULT_PATIENCE_S, (
            f"default {DEFAULT_PATIENCE_S:g} s: {len(followed)} of {len(times)} presses came "
            f"after following (fewer than {MIN_FOLLOWED})"
        )
    return float(np.median(followed)), (
        f"median following time before the {len(followed)} of {len(times)} "
        f"presses that came after following (range {followed.min():g}-"
        f"{followed.max():g} s)"
    )


def rule_from_analysis(
    workspace: Any,
    target: Any,
    step_s: float = 0.5,
    dwell_percentile: float = DWELL_PERCENTILE,
    dwell_draw: bool = False,
    lag_draw: bool = False,
) -> HeldBackRule:
    """The rule of a run's target from the workspace's analysis (`ValueError` when the analysis lacks
    the acceptance lines: analyse again with a current laneprint); its dwell at `dwell_percentile`, or
    with `dwell_draw` drawn at each change from the drivers' own times (`HeldBackRule.dwell_draws`);
    with `lag_draw`, the follower headways the agent's own changes need drawn from its drivers' presses
    (`HeldBackRule.lag_draws`)."""
    lines = workspace.read_table("analysis", "reference_lines")
    if "direction" in lines:  # reference lines stored without directions are every press's
        lines = lines[lines["direction"].astype(str) == "both"]
    fits = workspace.read_table("analysis", "fits") if workspace.has_table("analysis", "fits") else None
    decisions = workspace.read_table("analysis", "decisions")
    styles = workspace.read_table("analysis", "styles")
    if target.kind == "style":
        members = styles[styles["style"].astype(str).str.lower() == target.name.lower()]
        drivers = members["driver_id"].astype(str).tolist()
        typ = members.loc[members["is_typical"].astype(bool), "driver_id"].astype(str).tolist()
        typical = typ[0] if typ else None
        sel = lines[
            (lines["scope"] == "style")
            & (lines["name"].astype(str).str.lower() == target.name.lower())
            & (lines["kind"] == "typical")
        ]
    else:
        drivers, typical = [str(target.name)], str(target.name)
        sel = lines[(lines["scope"] == "driver") & (lines["name"].astype(str) == str(target.name))]
    if "thw_nb_s" not in decisions:
        from indicators.acceptance import add_acceptance

        decisions = add_acceptance(decisions)
    typ_presses = decisions[(decisions["driver_id"].astype(str) == str(typical)) & (decisions["label"] == "change")]
    t_nf = _finite(typ_presses, "t_nf_s")
    t_nf_floor = float(np.percentile(t_nf, FLOOR_PERCENTILE)) if len(t_nf) else 0.0
    dv_nb = _finite(typ_presses, "dv_nb_mps")
    # a follower slower than the ego never closes in: only faster ones than the target let close are refused
    dv_nb_floor = min(float(np.percentile(dv_nb, FLOOR_PERCENTILE)), 0.0) if len(dv_nb) else -np.inf
    try:
        got = {ind: _line(sel, fits, ind, typical, typ_presses) for ind in ACCEPT_INDICATORS}
    except KeyError as exc:
        raise ValueError(
            f"the analysis has no {exc.args[0]} line for {target.label}: run `laneprint analyze` "
            "again (acceptance indicators)"
        ) from None
    mine = decisions[decisions["driver_id"].astype(str).isin(drivers)]
    patience, why = patience_from(mine, step_s)
    dwell, dwell_why = dwell_from(mine, dwell_percentile)
    draws = {k: v for k, v in dwell_times(mine).items() if len(v) >= MIN_DWELL_PAIRS} if dwell_draw else {}
    lag = lag_headways(mine) if lag_draw else {}
    lag_why = (
        "the floors alone"
        if not lag_draw
        else f"drawn at each lane change from the follower headways at {target.label}'s presses with a follower "
        f"within {FAR_FOLLOWER_M:g} m ({', '.join(f'{k} {len(v)}' for k, v in lag.items())})"
        if lag
        else f"none: fewer than {MIN_LAG_PRESSES} presses of {target.label} with a follower within {FAR_FOLLOWER_M:g} m"
    )
    if draws:
        dwell_why = (
            f"drawn at each lane change from the drivers' times from a change to the next press "
            f"({', '.join(f'{k} {len(v)}' for k, v in draws.items())}); where none, {dwell_why}"
        )
    source = {k: v[1] for k, v in got.items()} | {
        "patience_s": f"{why}, {target.label}",
        "slower_mps": "the analysis's min_closing_mps (1 m/s)",
        "t_nf_floor_s": f"percentile {FLOOR_PERCENTILE:g} of t_nf at {len(t_nf)} presses of {typical}",
        "dv_nb_floor_mps": f"percentile {FLOOR_PERCENTILE:g} of dv_nb at {len(dv_nb)} presses of {typical}, at most 0",
        "dwell_s": f"{dwell_why}, {target.label}",
        "lag_draws": lag_why,
        "undo_check": "on: with no leader, no change to the left the agent "
        "would at once undo (README, 'Driving like its drivers')",
    }
    return HeldBackRule(
        patience,
        got["gap_nf"][0],
        got["gap_nb"][0],
        got["thw_nb"][0],
        t_nf_floor_s=t_nf_floor,
        dv_nb_floor_mps=dv_nb_floor,
        dwell_s=dwell,
        source=source,
        dwell_draws=draws,
        lag_draws=lag,
    )


# --- measured in the closed loop ---------------------------------------------------------------


@dataclass
class FollowStats:
    """What the ego did while held back, from every decision step of a drive (agent or SUMO's model).

    `longest_passed_up_s`: within one unbroken stretch of being held back, the time during which a
    neighbouring lane held a gap the target accepts, summed; the largest over the stretches (the
    issue's "follows a slower leader for more than 60 s while the target lane holds a gap its own
    lines accept"). `longest_passed_up_faster_s` counts only gaps in a faster lane (the rule's trigger).
    """

    dt_s: float
    n_steps: int = 0
    n_held: int = 0
    n_held_tf_undefined: int = 0  # held back with t_f undefined (not closing): no press scene of the study
    n_held_tf_above_line: int = 0  # held back with t_f undefined or above the target's t_f line at v_e
    longest_held_s: float = 0.0
    longest_passed_up_s: float = 0.0
    longest_passed_up_faster_s: float = 0.0
    adv_held: list[float] = field(default_factory=list)  # the agent's largest Q(change) - Q(keep), held back
    adv_free: list[float] = field(default_factory=list)  # the same at the other steps
    _gap_s: float = 0.0
    _fast_s: float = 0.0

    def record(
        self,
        held: bool,
        held_for_s: float,
        gap_ok: bool,
        fast_ok: bool,
        t_f_defined: bool,
        adv: Optional[float] = None,
        t_f_above_line: bool = False,
    ) -> None:
        self.n_steps += 1
        if adv is not None:
            (self.adv_held if held else self.adv_free).append(float(adv))
        if not held:
            self.interrupt()
            return
        self.n_held += 1
        self.n_held_tf_undefined += int(not t_f_defined)
        self.n_held_tf_above_line += int(not t_f_defined or t_f_above_line)
        self.longest_held_s = max(self.longest_held_s, held_for_s + self.dt_s)
        self._gap_s += self.dt_s if gap_ok else 0.0
        self._fast_s += self.dt_s if (gap_ok and fast_ok) else 0.0
        self.longest_passed_up_s = max(self.longest_passed_up_s, self._gap_s)
        self.longest_passed_up_faster_s = max(self.longest_passed_up_faster_s, self._fast_s)

    def interrupt(self) -> None:
        """A stretch of being held back ends (not held back, or a lane change under way)."""
        self._gap_s = self._fast_s = 0.0

    def summary(self) -> dict[str, Any]:
        def q(xs: list[float]) -> Optional[list[float]]:
            return [float(v) for v in np.percentile(xs, [10, 50, 90])] if xs else None

        return {
            "decision_steps": self.n_steps,
            "held_steps": self.n_held,
            "held_share": self.n_held / self.n_steps if self.n_steps else None,
            "held_tf_undefined_steps": self.n_held_tf_undefined,
            "held_tf_above_line_steps": self.n_held_tf_above_line,
            "longest_held_s": self.longest_held_s,
            "longest_passed_up_s": self.longest_passed_up_s,
            "longest_passed_up_faster_s": self.longest_passed_up_faster_s,
            "advantage_held_p10_p50_p90": q(self.adv_held),
            "advantage_free_p10_p50_p90": q(self.adv_free),
            "advantage_held_nonneg": sum(a >= 0 for a in self.adv_held),
        }


def merge_summaries(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Totals over sections of `FollowStats.summary` rows (longest: the largest; advantages dropped)."""
    out: dict[str, Any] = {
        k: sum(r.get(k, 0) for r in rows)
        for k in (
            "decision_steps",
            "held_steps",
            "held_tf_undefined_steps",
            "held_tf_above_line_steps",
            "advantage_held_nonneg",
            "vetoed",
            "gated",
            "lagged",
            "dwelled",
            "undone",
        )
    }
    out["held_share"] = out["held_steps"] / out["decision_steps"] if out["decision_steps"] else None
    for k in ("longest_held_s", "longest_passed_up_s", "longest_passed_up_faster_s"):
        out[k] = max((r[k] for r in rows), default=0.0)
    return out
