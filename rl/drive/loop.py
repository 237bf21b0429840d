"""Closed loop in SUMO: a trained agent makes the ego's lane changes (`laneprint drive`).

The traffic, road and logging are those of `laneprint simulate --engine sumo`
(`laneprint/simulator/sumo/`: scenario, traffic bubble, section loop, backend);
car following stays SUMO's (Krauss, the ego's vType = the run's style's SUMO
parameters). What changes is who decides a lane change:

- SUMO's own lane changing is switched off for the ego (`setLaneChangeMode`
  `REQUEST_MODE`: no strategic, cooperative, speed-gain or keep-right changes of its
  own; a TraCI request is carried out unless it would collide at once).
- Every ``dt_s`` of the run's `EnvConfig` (0.5 s, the decision rate it was trained
  at), while the ego is at its lane centre (no lane change under way), the agent is
  asked about each neighbouring lane (two lanes: the other lane; three lanes: from the
  middle lane both, one Scene per side whose ``left`` says which, so an agent with the
  'direction' observation knows the side it is asked about). It changes to the side
  with the larger advantage ``Q(change) - Q(keep)`` when that is not negative (a tie
  counts as change, as in training's argmax, `rl.learners.dqn.greedy_actions`), and
  keeps otherwise (`choose_side`); with one neighbour this is exactly the argmax of
  the two-lane loop. Its observation is built exactly as in
  training (`rl.problem.env.observation` on a `Scene`) from the live SUMO state, read the
  way the analysis reads a log (`indicators/decisions.py`): ``C_f`` = nearest
  vehicle ahead in the ego lane, ``C_nf`` / ``C_nb`` = nearest ahead / behind or
  alongside in the target lane, centres and lengths. A vehicle that is not there
  (or beyond the run's ``range_m``) is absent, and the observation shows it as in
  training (nothing within range; indicator undefined, flag 0).
- TO CHANGE becomes ``changeLane(ego, target, dt_s)``: the request lapses by the
  next decision, so the agent is asked afresh if SUMO did not start it.
- The assistant around the agent (`AgentControl.assist`, `rl/drive/heldback.py`; off with
  ``use_rule=False``, the pure agent): a floor under the agent's changes, overtakings carried
  through (no return behind the leader left; the return once it is over), and the held-back rule
  when the ego has followed a slower leader for the target's patience. Each decision says
  who asked for it (`Decision.source`).
- `Watch` only looks, with SUMO's own lane changing left on: the comparator, SUMO's model of
  the same style in the same traffic and seeds (`sumo_model_sections`). Both record how long
  the ego was held back and whether a neighbouring lane held an accepted gap (`FollowStats`).

Afterwards the section's log is assembled as the study's (`run_section`): the
button is pressed at the first sample off the lane centre, so the agent's changes
read like a driver's presses. Each decision is matched to the lane change that
started within ``dt_s`` after it.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from laneprint.progress import ProgressFn, report
from laneprint.simulator.study import session_id
from laneprint.simulator.sumo.scenario import build_network, write_routes
from laneprint.simulator.sumo.section import EGO_ID, SectionLog, run_section
from laneprint.simulator.sumo.settings import SumoSettings
from laneprint.simulator.sumo.traffic import VehicleState
from rl.drive.heldback import (
    FollowStats,
    HeldBackClock,
    HeldBackRule,
    LeftBehind,
    Line,
    above_floors,
    accepts,
    faster,
    held_back,
    holding_limit,
    lag_accepted,
    rule_target,
)
from rl.problem.env import EnvConfig
from rl.problem.rewards import CHANGE, KEEP
from rl.problem.scene import Scene, gaps, indicators, seen

#: setLaneChangeMode bits: 0-7 = 0 (no change of the ego's own), 8-9 = 01 (a TraCI request
#: is carried out unless it collides at once; others' braking is the agent's responsibility)
REQUEST_MODE = 0b01_00000000
N_LANES = 2

#: Q-values of a batch of scenes, shape (n, 2), columns indexed by `CHANGE` and `KEEP`.
QFunction = Callable[[Scene], np.ndarray]


def target_lane(lane: int, n_lanes: int = N_LANES) -> Optional[int]:
    """The lane the agent is asked about on a two-lane road: the other lane (None with one lane)."""
    if n_lanes < 2:
        return None
    return lane + 1 if lane == 0 else lane - 1


def neighbour_lanes(lane: int, n_lanes: int = N_LANES) -> list[int]:
    """The lanes next to `lane` on a road of `n_lanes` (lane 0 rightmost): the left one first, then the right."""
    return [k for k in (lane + 1, lane - 1) if 0 <= k < n_lanes]


def _side(lane: int, target: int) -> str:
    return "left" if target > lane else "right"


def advantages(q: np.ndarray) -> np.ndarray:
    """Q(change) - Q(keep) of each row of a (n, 2) array of Q-values."""
    q = np.asarray(q, dtype=float)
    return q[:, CHANGE] - q[:, KEEP]


def choose_side(adv: dict[int, float], threshold: float | dict[int, float] = 0.0) -> Optional[int]:
    """Of the target lanes whose advantage reaches their threshold, the one with the largest; else None (keep).

    `adv` maps each neighbouring lane to Q(change) - Q(keep) of the scene asking about it; `threshold`
    is one for every lane or one per lane. With the default threshold 0 a tie with keep counts as
    change, as training's argmax does; a tie between two sides goes to the lower lane (the right
    one: keep right). The assistant raises the thresholds to the target drivers' pace by side
    (`HeldBackRule.needs`, `rl.drive.pace`).
    """
    need = threshold if isinstance(threshold, dict) else dict.fromkeys(adv, threshold)
    ok = {k: a for k, a in adv.items() if a >= need[k]}
    if not ok:
        return None
    return max(sorted(ok), key=lambda k: ok[k])  # max keeps the first of equals: the lower lane


#: A vehicle this far [m] off its lane's centre towards a neighbouring lane is changing into it.
ENTERING_M = 0.2


def in_lane(st: VehicleState, lane: int) -> bool:
    """The vehicle is in `lane`, or is changing into it from a neighbouring lane (it keeps its old lane index
    until it crosses the line; on three lanes a car of the far lane may be entering the ego's target lane)."""
    side = lane - st.lane
    return side == 0 or (abs(side) == 1 and st.lat * side > ENTERING_M)


def live_scene(ego: VehicleState, others: dict[str, VehicleState], target: int) -> tuple[Scene, dict[str, Any]]:
    """The decision scene of the ego (the analysis's reading of a log) and the ids of f, nf, nb; a vehicle
    changing into the target lane counts as in it (`in_lane`)."""

    def nearest(lane: int, ahead: bool) -> Optional[tuple[str, VehicleState]]:
        cands = [
            (vid, st)
            for vid, st in others.items()
            if (st.lane == lane if lane == ego.lane else in_lane(st, lane))
            and ((st.x - ego.x > 0) if ahead else (st.x - ego.x <= 0))
        ]
        if not cands:
            return None
        return min(cands, key=lambda c: abs(c[1].x - ego.x))

    picks = {"f": nearest(ego.lane, True), "nf": nearest(target, True), "nb": nearest(target, False)}
    cols: dict[str, np.ndarray] = {"v_e": np.array([ego.v]), "x_e": np.array([ego.x])}
    for role, pick in picks.items():
        st = pick[1] if pick else None
        cols[f"{role}_present"] = np.array([st is not None])
        cols[f"v_{role}"] = np.array([st.v if st else ego.v])
        cols[f"x_{role}"] = np.array([st.x if st else ego.x])
        cols[f"hl_{role}"] = np.array([(ego.length + st.length) / 2 if st else ego.length])
    cols["left"] = np.array([target > ego.lane])
    return Scene(**cols), {role: (pick[0] if pick else None) for role, pick in picks.items()}


@dataclass
class Decision:
    """One TO CHANGE of the agent: when, where to, the scene's indicators."""

    t_s: float
    from_lane: int
    target_lane: int
    v_e_mps: float
    t_f_s: Optional[float]
    t_nf_s: Optional[float]
    dv_nb_mps: Optional[float]
    ids: dict[str, Optional[str]]
    started: bool = False  # a lane change started within dt_s after it
    press_t_s: Optional[float] = None
    advantages: dict[str, float] = field(default_factory=dict)  # side ('left'/'right') -> Q(change) - Q(keep)
    source: str = "agent"  # who asked: 'agent'; 'rule' (held back), 'return' (an overtaking completed)
    too_soon: list[str] = field(default_factory=list)  # sides not asked about: too soon after the last change
    undone: list[str] = field(default_factory=list)  # sides the agent wanted but would at once undo (left only)
    thw_nb_s: Optional[float] = None  # the target lane's follower's time headway [s], when within far_follower_m


class Watch:
    """The `EgoControl` that only looks: every `dt_s` at the lane centre, the scenes of the neighbouring
    lanes and how long the ego has been held back (`FollowStats`). SUMO's own lane changing stays on:
    the comparator of the agent, SUMO's model of the same style in the same traffic."""

    def __init__(self, cfg: EnvConfig, step_s: float, n_lanes: int, rule: HeldBackRule, desired_mps: float) -> None:
        self.cfg = cfg
        self.every = max(1, int(round(cfg.dt_s / step_s)))
        self.n_lanes = n_lanes
        self.rule = rule
        self.desired_mps = desired_mps
        self.clock = HeldBackClock()
        self.stats = FollowStats(cfg.dt_s)
        self.n_asked = 0
        self._steps = 0

    def start(self, api: Any) -> None:
        pass

    def look(
        self, t: float, ego: VehicleState, lateral_m: float, others: dict[str, VehicleState]
    ) -> Optional[tuple[dict[int, tuple[Scene, dict[str, Any]]], bool, float]]:
        """(scene and ids per neighbouring lane, held back, for how long) at a decision step, else None."""
        self._steps += 1
        if self._steps % self.every:
            return None
        if abs(lateral_m) > 1e-6:  # a lane change under way ends a stretch of being held back
            self.clock.reset()
            self.stats.interrupt()
            return None
        lanes = neighbour_lanes(ego.lane, self.n_lanes)
        if not lanes:
            return None
        asked = {lane: live_scene(ego, others, lane) for lane in lanes}
        first = asked[lanes[0]][0]
        held = held_back(first, self.desired_mps, self.rule.slower_mps, self.cfg.range_m)
        return asked, held, self.clock.update(t, held)

    def record(
        self, asked: dict[int, tuple[Scene, dict[str, Any]]], held: bool, held_for: float, adv: Optional[float] = None
    ) -> None:
        scenes = [sc for sc, _ in asked.values()]
        gap = [bool(accepts(self.rule, sc, self.cfg.range_m)[0]) for sc in scenes]
        fast = [g and bool(faster(self.rule, sc, self.cfg.range_m)[0]) for g, sc in zip(gap, scenes)]
        ind = indicators(scenes[0], self.cfg.far_follower_m, self.cfg.range_m)
        above = bool(ind.t_f_ok[0]) and float(ind.t_f[0]) > float(self.cfg.lines.at(ind.v_e[0])["t_f"])
        self.stats.record(held, held_for, any(gap), any(fast), bool(ind.t_f_ok[0]), adv, above)

    def step(self, api: Any, t: float, ego: VehicleState, lateral_m: float, others: dict[str, VehicleState]) -> None:
        seen_now = self.look(t, ego, lateral_m, others)
        if seen_now is not None:
            self.n_asked += 1
            self.record(*seen_now)


class AgentControl(Watch):
    """The `EgoControl` of `run_section`: asks the agent (`q`) every `dt_s` and requests its changes;
    with `use_rule`, the held-back rule asks for a change the agent does not make (`rl.drive.heldback`)."""

    def __init__(
        self,
        q: QFunction,
        cfg: EnvConfig,
        step_s: float,
        n_lanes: int = N_LANES,
        rule: Optional[HeldBackRule] = None,
        desired_mps: float = 0.0,
        use_rule: bool = False,
        dwell_rng: Optional[np.random.Generator] = None,
    ) -> None:
        never = Line(0.0, np.inf)  # no rule given: desired speed 0, never held back
        super().__init__(cfg, step_s, n_lanes, rule or HeldBackRule(np.inf, never, never, never), desired_mps)
        self.q = q
        self.use_rule = use_rule and rule is not None
        self.decisions: list[Decision] = []
        self.overtakings: list[LeftBehind] = []  # overtakings not yet completed, the latest last
        self.lane = -1  # the ego's lane at the last decision step
        self.n_vetoed = 0  # agent's changes not requested: back behind the leader the rule left
        self.n_gated = 0  # agent's changes not requested: a gap below the smallest the target took
        self.n_dwelled = 0  # decision steps with a side not asked about: too soon after the last lane change
        self.n_undone = 0  # decision steps (no leader) with a side to the left the agent wanted but would at once undo
        self.last_change: Optional[tuple[float, str]] = None  # (time, side) the ego last crossed into a lane
        self.dwell_rng = dwell_rng or np.random.default_rng(0)  # the rule's drawn dwells (`dwell_draws`)
        self.drawn: dict[str, float] = {}  # the dwells drawn at the last lane change
        self.n_lagged = 0  # agent's changes not requested: a follower headway below the one drawn for that side
        self.lag_drawn = self.rule.draw_lag(self.dwell_rng)  # per side: the headway drawn at the last change
        self._lane_now: Optional[int] = None

    def start(self, api: Any) -> None:
        api.vehicle.setLaneChangeMode(EGO_ID, REQUEST_MODE)

    def step(self, api: Any, t: float, ego: VehicleState, lateral_m: float, others: dict[str, VehicleState]) -> None:
        if self._lane_now is not None and ego.lane != self._lane_now:
            self.last_change = (t, _side(self._lane_now, ego.lane))
            self.drawn = self.rule.draw_dwell(self.last_change[1], self.dwell_rng)
            self.lag_drawn = self.rule.draw_lag(self.dwell_rng)
        self._lane_now = ego.lane
        seen_now = self.look(t, ego, lateral_m, others)
        if seen_now is None:
            return
        asked, held, held_for = seen_now
        lanes = list(asked)
        adv = dict(zip(lanes, advantages(self.q(Scene.concat([asked[k][0] for k in lanes])))))
        self.n_asked += 1
        self.record(asked, held, held_for, max(adv.values()))
        all_adv = adv
        if self.use_rule and self.last_change is not None:  # no change sooner than the drivers made one
            since, side = t - self.last_change[0], self.last_change[1]
            keep = {k for k in lanes if self.rule.dwell_ok(side, since, _side(ego.lane, k), self.drawn)}
            if len(keep) < len(lanes):
                self.n_dwelled += 1
                asked, adv = {k: asked[k] for k in keep}, {k: adv[k] for k in keep}
                if not asked:
                    return
        need = {k: self.rule.needs(_side(ego.lane, k)) if self.use_rule else 0.0 for k in lanes}
        wanted = adv
        if self.use_rule and self.rule.undo_check and not self.has_leader(asked):
            # back from a lane to the left is a change to the right: it needs what one to the right needs
            undone = {
                k
                for k, a in adv.items()
                if k > ego.lane and a >= need[k] and self.would_undo(ego, others, k, self.rule.needs("right"))
            }
            if undone:
                self.n_undone += 1
                wanted = {k: a for k, a in adv.items() if k not in undone}
        target, source = self.assist(choose_side(wanted, need), asked, held, held_for, ego, others)
        if target is None:
            return
        scene, ids = asked[target]
        ind = indicators(scene, self.cfg.far_follower_m, self.cfg.range_m)
        self.decisions.append(
            Decision(
                t,
                ego.lane,
                target,
                ego.v,
                _defined(ind.t_f, ind.t_f_ok),
                _defined(ind.t_nf, ind.t_nf_ok),
                _defined(ind.dv_nb, ind.dv_nb_ok),
                ids,
                advantages={_side(ego.lane, k): float(a) for k, a in all_adv.items()},
                source=source,
                too_soon=[_side(ego.lane, k) for k in all_adv if k not in adv],
                undone=[_side(ego.lane, k) for k in adv if k not in wanted],
                thw_nb_s=follower_headway(scene, self.cfg.far_follower_m, self.cfg.range_m),
            )
        )
        if self.use_rule and target > ego.lane and ids.get("f") is not None:
            self.overtakings.append(LeftBehind(ego.lane, str(ids["f"])))  # followed until complete
        api.vehicle.changeLane(EGO_ID, target, self.cfg.dt_s)

    def has_leader(self, asked: dict[int, tuple[Scene, dict[str, Any]]]) -> bool:
        """Whether the ego has a leader within range (the same in every side's scene)."""
        return bool(seen(next(iter(asked.values()))[0], self.cfg.range_m)[0][0])

    def would_undo(self, ego: VehicleState, others: dict[str, VehicleState], target: int, threshold: float) -> bool:
        """Whether the agent, put in lane `target` as the traffic is now, would want back into the ego's lane
        at once (an advantage of at least `threshold`, what its own change back there needs). Asked only with
        no leader within range.

        With no leader (where drivers change lane mostly to return right), an agent that does not know
        the side reads an empty lane to the left as a place to return to, and in an empty world it
        weaves: on three-lane `ttc` study 660 the Defensive agent went left without a leader 55 times
        in 48 km (its drivers 12 times in 73 km), 4 s after coming back each time (README, 'Driving like
        its drivers'). With nothing to pass, a change to the left is the driver's only if it would stay.
        Behind a leader the check is not made, where the agent's changes were not at fault: asked from the
        lane it would reach, a side-blind agent also reads the leader left behind as a return's target
        (study 662's Aggressive agent would undo 373 of its 664 steps of wanting to leave the slow lane)."""
        back, _ = live_scene(replace(ego, lane=target), others, ego.lane)
        return bool(advantages(self.q(back))[0] >= threshold)

    @property
    def left_behind(self) -> Optional[LeftBehind]:
        """The overtaking to complete next: the latest, when it left the lane to the ego's right."""
        last = self.overtakings[-1] if self.overtakings else None
        return last if last is not None and last.lane == self.lane - 1 else None

    def assist(
        self,
        agent: Optional[int],
        asked: dict[int, tuple[Scene, dict[str, Any]]],
        held: bool,
        held_for: float,
        ego: VehicleState,
        others: dict[str, VehicleState],
    ) -> tuple[Optional[int], str]:
        """(lane to request or None, who asks): the agent's choice unless it returns behind the leader an
        overtaking left (vetoed), takes a gap below the target's floors (gated) or cuts in front of a
        follower closer in time than the headway drawn for that side at the last change (lagged); else the overtaking's
        return once it is over (that leader passed, or no longer holding the ego back) and the lane left
        holds an accepted gap; else the held-back rule."""
        if not self.use_rule:
            return agent, "agent"
        # back in (or right of) a lane an overtaking left: that one is over; one left farther right waits
        self.lane = ego.lane
        self.overtakings = [o for o in self.overtakings if o.lane < ego.lane]
        r, lb = self.cfg.range_m, self.left_behind
        holding = holding_limit(self.desired_mps, self.rule.slower_mps)  # a leader left this fast: no overtaking
        if agent is not None and lb is not None and lb.vetoes(agent, ego.x, others, r, holding):
            self.n_vetoed += 1
            agent = None
        if agent is not None and not above_floors(self.rule, asked[agent][0], r)[0]:
            self.n_gated += 1
            agent = None
        side = None if agent is None else _side(ego.lane, agent)
        if (
            agent is not None
            and side in self.lag_drawn
            and not lag_accepted(self.rule, asked[agent][0], r, self.lag_drawn[side])[0]
        ):
            self.n_lagged += 1
            agent = None
        if agent is not None:
            return agent, "agent"
        if lb is not None and lb.lane in asked and lb.over(ego.x, others, r, holding):
            back = asked[lb.lane][0]
            if accepts(self.rule, back, r)[0] and above_floors(self.rule, back, r)[0]:
                return lb.lane, "return"
        if held:
            return rule_target(self.rule, {k: sc for k, (sc, _) in asked.items()}, held_for, r), "rule"
        return None, "agent"


def follower_headway(scene: Scene, far_follower_m: float, range_m: float) -> Optional[float]:
    """The time headway [s] of the first scene's target-lane follower, None when there is none within
    `far_follower_m` (or it is stopped)."""
    g = gaps(scene, range_m)
    near = np.isfinite(g["gap_nb"][0]) and g["gap_nb"][0] <= far_follower_m
    return float(g["thw_nb"][0]) if near and np.isfinite(g["thw_nb"][0]) else None


def _defined(x: np.ndarray, ok: np.ndarray) -> Optional[float]:
    return float(x[0]) if bool(ok[0]) else None


def match_presses(decisions: list[Decision], changes: list[dict[str, Any]], window_s: float) -> None:
    """Mark each decision whose lane change started within `window_s` after it (in place)."""
    starts = sorted((c["press_t_s"], c["target_lane"]) for c in changes)
    for d in decisions:
        hit = next((t for t, lane in starts if d.t_s < t <= d.t_s + window_s + 1e-9 and lane == d.target_lane), None)
        d.started, d.press_t_s = hit is not None, hit


@dataclass
class SectionDrive:
    """One section driven by the agent (or by SUMO's model): the log, the decisions, the held-back figures."""

    speed_limit_kph: float
    log: SectionLog
    n_asked: int
    decisions: list[Decision] = field(default_factory=list)
    follow: dict[str, Any] = field(default_factory=dict)  # `FollowStats.summary`
    desired_mps: float = 0.0


def drive_seed(seed: int, section_index: int) -> tuple[np.random.Generator, int]:
    """Traffic generator and SUMO `--seed` of one driven section (apart from the study's runs)."""
    ss = np.random.SeedSequence(seed, spawn_key=(2, section_index))
    return np.random.default_rng(ss), int(ss.generate_state(1)[0] % (2**31 - 1))


def desired_speed(limit_kph: float, ego_params: dict[str, float]) -> float:
    """The ego's desired speed in a section [m/s]: the limit times its vType's speedFactor (SUMO's own)."""
    return limit_kph / 3.6 * float(ego_params.get("speedFactor", 1.0))


#: (section limit [km/h], desired speed [m/s]) -> the section's EgoControl (an AgentControl or a Watch)
ControlFactory = Callable[[float, float], Watch]


def run_sections(
    make: ControlFactory,
    cfg: EnvConfig,
    ego_params: dict[str, float],
    settings: SumoSettings,
    seed: int,
    progress: Optional[ProgressFn] = None,
    label: str = "SUMO section",
) -> list[SectionDrive]:
    """Drive every section of `settings` (its `n_lanes`) with the control `make` gives; one after the other.
    The traffic and SUMO's seed of section j depend on `seed` and j only (`drive_seed`)."""
    out = []
    limits = list(settings.speed_limits_kph)
    with tempfile.TemporaryDirectory(prefix="laneprint-drive-") as workdir:
        for j, limit in enumerate(limits):
            report(progress, j, len(limits), f"{label} {limit:g} km/h")
            folder = Path(workdir) / f"S{int(round(limit))}"
            folder.mkdir()
            net = build_network(folder, settings, float(limit))
            routes = write_routes(folder / "ego.rou.xml", ego_params, settings)
            rng, sumo_seed = drive_seed(seed, j)
            desired = desired_speed(float(limit), ego_params)
            control = make(float(limit), desired)
            log = run_section(settings, net, routes, float(limit), sumo_seed, rng, folder, control)
            decisions = getattr(control, "decisions", [])
            match_presses(decisions, log.lane_changes, cfg.dt_s)
            out.append(
                SectionDrive(
                    float(limit),
                    log,
                    control.n_asked,
                    decisions,
                    {
                        **control.stats.summary(),
                        "vetoed": getattr(control, "n_vetoed", 0),
                        "gated": getattr(control, "n_gated", 0),
                        "lagged": getattr(control, "n_lagged", 0),
                        "dwelled": getattr(control, "n_dwelled", 0),
                        "undone": getattr(control, "n_undone", 0),
                    },
                    desired,
                )
            )
    report(progress, len(limits), len(limits), "driven")
    return out


def drive_sections(
    q: QFunction,
    cfg: EnvConfig,
    ego_params: dict[str, float],
    settings: SumoSettings,
    seed: int,
    progress: Optional[ProgressFn] = None,
    rule: Optional[HeldBackRule] = None,
    use_rule: bool = True,
) -> list[SectionDrive]:
    """Drive every section with the agent `q` (and, with `rule` and `use_rule`, the held-back rule); a
    rule's drawn dwells come from a generator seeded by `seed` and the section's limit."""
    return run_sections(
        lambda limit, desired: AgentControl(
            q,
            cfg,
            settings.step_s,
            settings.n_lanes,
            rule,
            desired,
            use_rule,
            np.random.default_rng([seed, int(round(limit))]),
        ),
        cfg,
        ego_params,
        settings,
        seed,
        progress,
    )


def sumo_model_sections(
    cfg: EnvConfig,
    ego_params: dict[str, float],
    settings: SumoSettings,
    seed: int,
    rule: HeldBackRule,
    progress: Optional[ProgressFn] = None,
) -> list[SectionDrive]:
    """The comparator: the same ego vType, sections, traffic seeds and SUMO seeds, SUMO's LC2013 deciding."""
    return run_sections(
        lambda _, desired: Watch(cfg, settings.step_s, settings.n_lanes, rule, desired),
        cfg,
        ego_params,
        settings,
        seed,
        progress,
        "SUMO's model, section",
    )


def recordings(drives: list[SectionDrive], driver_id: str, simulator: str) -> list[tuple[dict, Any, Any]]:
    """(meta, ego, traffic) of each driven section, as the study's recordings."""
    return [
        (
            {
                "driver_id": driver_id,
                "session_id": session_id(driver_id, d.speed_limit_kph),
                "speed_limit_kph": d.speed_limit_kph,
                "simulator": simulator,
            },
            d.log.ego,
            d.log.traffic,
        )
        for d in drives
    ]
