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

Afterwards the section's log is assembled as the study's (`run_section`): the
button is pressed at the first sample off the lane centre, so the agent's changes
read like a driver's presses. Each decision is matched to the lane change that
started within ``dt_s`` after it.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from laneprint.progress import ProgressFn, report
from laneprint.simulator.study import session_id
from laneprint.simulator.sumo.scenario import build_network, write_routes
from laneprint.simulator.sumo.section import EGO_ID, SectionLog, run_section
from laneprint.simulator.sumo.settings import SumoSettings
from laneprint.simulator.sumo.traffic import VehicleState
from rl.problem.env import EnvConfig
from rl.problem.rewards import CHANGE, KEEP
from rl.problem.scene import Scene, indicators

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


def advantages(q: np.ndarray) -> np.ndarray:
    """Q(change) - Q(keep) of each row of a (n, 2) array of Q-values."""
    q = np.asarray(q, dtype=float)
    return q[:, CHANGE] - q[:, KEEP]


def choose_side(adv: dict[int, float]) -> Optional[int]:
    """The target lane with the largest advantage when it is not negative, else None (keep).

    `adv` maps each neighbouring lane to Q(change) - Q(keep) of the scene asking about it. A
    tie with keep (advantage exactly 0) counts as change, as training's argmax does; a tie
    between two sides goes to the lower lane (the right one: keep right).
    """
    if not adv:
        return None
    lane = max(sorted(adv), key=lambda k: adv[k])  # max keeps the first of equals: the lower lane
    return lane if adv[lane] >= 0 else None


def live_scene(ego: VehicleState, others: dict[str, VehicleState], target: int) -> tuple[Scene, dict[str, Any]]:
    """The decision scene of the ego (the analysis's reading of a log) and the ids of f, nf, nb."""
    def nearest(lane: int, ahead: bool) -> Optional[tuple[str, VehicleState]]:
        cands = [(vid, st) for vid, st in others.items()
                 if st.lane == lane and ((st.x - ego.x > 0) if ahead else (st.x - ego.x <= 0))]
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


class AgentControl:
    """The `EgoControl` of `run_section`: asks the agent (`q`) every `dt_s` and requests its changes."""

    def __init__(self, q: QFunction, cfg: EnvConfig, step_s: float, n_lanes: int = N_LANES) -> None:
        self.q = q
        self.cfg = cfg
        self.every = max(1, int(round(cfg.dt_s / step_s)))
        self.n_lanes = n_lanes
        self.n_asked = 0
        self.decisions: list[Decision] = []
        self._steps = 0

    def start(self, api: Any) -> None:
        api.vehicle.setLaneChangeMode(EGO_ID, REQUEST_MODE)

    def step(self, api: Any, t: float, ego: VehicleState, lateral_m: float,
             others: dict[str, VehicleState]) -> None:
        self._steps += 1
        if self._steps % self.every or abs(lateral_m) > 1e-6:
            return  # not a decision step, or a lane change is under way
        lanes = neighbour_lanes(ego.lane, self.n_lanes)
        if not lanes:
            return
        asked = {lane: live_scene(ego, others, lane) for lane in lanes}
        adv = dict(zip(lanes, advantages(self.q(Scene.concat([asked[k][0] for k in lanes])))))
        self.n_asked += 1
        target = choose_side(adv)
        if target is None:
            return
        scene, ids = asked[target]
        ind = indicators(scene, self.cfg.far_follower_m, self.cfg.range_m)
        self.decisions.append(Decision(t, ego.lane, target, ego.v, _defined(ind.t_f, ind.t_f_ok),
                                       _defined(ind.t_nf, ind.t_nf_ok), _defined(ind.dv_nb, ind.dv_nb_ok), ids,
                                       advantages={("left" if k > ego.lane else "right"): float(a)
                                                   for k, a in adv.items()}))
        api.vehicle.changeLane(EGO_ID, target, self.cfg.dt_s)


def _defined(x: np.ndarray, ok: np.ndarray) -> Optional[float]:
    return float(x[0]) if bool(ok[0]) else None


def match_presses(decisions: list[Decision], changes: list[dict[str, Any]], window_s: float) -> None:
    """Mark each decision whose lane change started within `window_s` after it (in place)."""
    starts = sorted((c["press_t_s"], c["target_lane"]) for c in changes)
    for d in decisions:
        hit = next((t for t, lane in starts if d.t_s < t <= d.t_s + window_s + 1e-9 and lane == d.target_lane),
                   None)
        d.started, d.press_t_s = hit is not None, hit


@dataclass
class SectionDrive:
    """One section driven by the agent: the log and the agent's decisions."""

    speed_limit_kph: float
    log: SectionLog
    n_asked: int
    decisions: list[Decision] = field(default_factory=list)


def drive_seed(seed: int, section_index: int) -> tuple[np.random.Generator, int]:
    """Traffic generator and SUMO `--seed` of one driven section (apart from the study's runs)."""
    ss = np.random.SeedSequence(seed, spawn_key=(2, section_index))
    return np.random.default_rng(ss), int(ss.generate_state(1)[0] % (2**31 - 1))


def drive_sections(q: QFunction, cfg: EnvConfig, ego_params: dict[str, float], settings: SumoSettings,
                   seed: int, progress: Optional[ProgressFn] = None) -> list[SectionDrive]:
    """Drive every section of `settings` (its `n_lanes`) with the agent `q`; SUMO runs one after the other."""
    out = []
    limits = list(settings.speed_limits_kph)
    with tempfile.TemporaryDirectory(prefix="laneprint-drive-") as workdir:
        for j, limit in enumerate(limits):
            report(progress, j, len(limits), f"SUMO section {limit:g} km/h")
            folder = Path(workdir) / f"S{int(round(limit))}"
            folder.mkdir()
            net = build_network(folder, settings, float(limit))
            routes = write_routes(folder / "ego.rou.xml", ego_params, settings)
            rng, sumo_seed = drive_seed(seed, j)
            control = AgentControl(q, cfg, settings.step_s, settings.n_lanes)
            log = run_section(settings, net, routes, float(limit), sumo_seed, rng, folder, control)
            match_presses(control.decisions, log.lane_changes, cfg.dt_s)
            out.append(SectionDrive(float(limit), log, control.n_asked, control.decisions))
    report(progress, len(limits), len(limits), "driven")
    return out


def recordings(drives: list[SectionDrive], driver_id: str, simulator: str) -> list[tuple[dict, Any, Any]]:
    """(meta, ego, traffic) of each driven section, as the study's recordings."""
    return [({"driver_id": driver_id, "session_id": session_id(driver_id, d.speed_limit_kph),
              "speed_limit_kph": d.speed_limit_kph, "simulator": simulator}, d.log.ego, d.log.traffic)
            for d in drives]
