"""`laneprint annotate RUN_ID RECORDING_ID --out FILE.mcap`: decisions back into the log.

The stored recording is written again as a log format v1 MCAP (`ingest.writers.write_mcap`,
so `laneprint ingest` reads it like the original: same samples, same presses)
with four more JSON channels, one message per agent step (every ``dt_s`` of the
run, 0.5 s by default, from the recording's first sample):

- ``/laneprint/agent``: the run's decision (``change`` / ``keep`` / ``none``),
  ``action`` (0 change, 1 keep), ``q_change``, ``q_keep``, ``q_margin`` = q_change - q_keep;
- ``/laneprint/greedy``: the study's greedy benchmark (`rl.baselines.greedy`) with the run's
  reference lines: decision, action and its two immediate rewards;
- ``/laneprint/driver``: ``change`` at the step at or after each press of the
  button (rising edge; ``press_t_s`` its exact time), else ``keep``; ``button`` the
  button's state at the step;
- ``/laneprint/scene``: what the decision sees: ego and target lane, the ids of
  C_f / C_nf / C_nb, the indicators t_f, t_nf, dv_nb where defined and the run's
  reference lines at the ego's speed.

Strings are small enums (Foxglove's State Transitions panel), numbers plot
(Plot panel), e.g. ``/laneprint/agent.q_margin`` or ``/laneprint/scene.t_f``.

The scene at a step is read as the analysis reads it (`indicators.decisions.ego_at`,
`neighbours`). Rules where the study is silent:

- **Target lane** at a step: the lane to the left (lane + 1) when the recording
  has one (any vehicle ever drove in it), else the lane to the right.
- **Steps without a defined observation**: the agent learnt when to leave a
  leader, so a step whose ego lane has no leader within the sensing range
  (``range_m``) has status ``no_leader``, and a step with no adjacent lane
  ``no_target_lane``. At such steps neither the agent nor the greedy benchmark
  is asked: decision ``none``, no action, no Q-values (the fields are left out,
  never filled with a number). The driver's channel is written at every step.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from indicators.decisions import ego_at, neighbours
from indicators.settings import AnalysisSettings
from ingest.logformat import NS_PER_S
from ingest.writers import ExtraChannel, write_mcap
from laneprint.errors import SettingError, UserError
from laneprint.progress import ProgressFn, report
from laneprint.workspace import Workspace
from rl.learners.dqn import q_values
from rl.problem.env import EnvConfig, observation, scenes_from_decisions
from rl.baselines.greedy import greedy_actions
from rl.problem.rewards import CHANGE, RewardSettings, action_rewards
from rl.runs import load_weights, run_dir
from rl.problem.scene import Scene, indicators, seen

TOPIC_AGENT, TOPIC_GREEDY = "/laneprint/agent", "/laneprint/greedy"
TOPIC_DRIVER, TOPIC_SCENE = "/laneprint/driver", "/laneprint/scene"
METADATA_NAME = "laneprint_annotation"

#: Why a step has no decision (see the module doc).
STATUS = {
    "ok": "observation defined: agent and greedy decide",
    "no_leader": "no leader in the ego lane within the sensing range: no decision to take",
    "no_target_lane": "no adjacent lane to change to",
}
DECISIONS = ("change", "keep", "none")

_NUM, _INT = {"type": "number"}, {"type": "integer"}
_STEP = {"t_s": _NUM, "step": _INT}
_DECIDER = {
    "status": {"type": "string", "enum": list(STATUS)},
    "decision": {"type": "string", "enum": list(DECISIONS)},
    "action": {"type": "integer", "enum": [0, 1]},
}
SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    TOPIC_AGENT: (
        "laneprint.AgentDecision",
        {
            "type": "object",
            "properties": {**_STEP, **_DECIDER, "q_change": _NUM, "q_keep": _NUM, "q_margin": _NUM},
            "required": ["t_s", "step", "status", "decision"],
        },
    ),
    TOPIC_GREEDY: (
        "laneprint.GreedyDecision",
        {
            "type": "object",
            "properties": {**_STEP, **_DECIDER, "r_change": _NUM, "r_keep": _NUM},
            "required": ["t_s", "step", "status", "decision"],
        },
    ),
    TOPIC_DRIVER: (
        "laneprint.DriverDecision",
        {
            "type": "object",
            "properties": {
                **_STEP,
                "decision": {"type": "string", "enum": ["change", "keep"]},
                "button": {"type": "boolean"},
                "press_t_s": _NUM,
                "direction": {"type": "string", "enum": ["left", "right"]},
            },
            "required": ["t_s", "step", "decision", "button"],
        },
    ),
    TOPIC_SCENE: (
        "laneprint.DecisionScene",
        {
            "type": "object",
            "properties": {
                **_STEP,
                "status": {"type": "string", "enum": list(STATUS)},
                "ego_lane": _INT,
                "target_lane": _INT,
                "ego_v_mps": _NUM,
                "f_id": {"type": "string"},
                "nf_id": {"type": "string"},
                "nb_id": {"type": "string"},
                "t_f": _NUM,
                "t_nf": _NUM,
                "dv_nb": _NUM,
                "t_f_line": _NUM,
                "t_nf_line": _NUM,
                "dv_nb_line": _NUM,
            },
            "required": ["t_s", "step", "status", "ego_lane"],
        },
    ),
}


def target_lanes(ego_lane: np.ndarray, top_lane: int) -> np.ndarray:
    """The lane each step's decision is about: left (lane + 1) when it exists, else right (-1: none)."""
    return np.where(ego_lane + 1 <= top_lane, ego_lane + 1, ego_lane - 1)


def decision_steps(
    ego: pd.DataFrame,
    traffic: pd.DataFrame,
    cfg: EnvConfig,
    settings: AnalysisSettings | None = None,
    side: int | None = None,
) -> tuple[pd.DataFrame, Scene]:
    """One row per agent step (t_s, ego_lane, target_lane, status, neighbour ids) and its scenes.

    `side`: None asks about the lane `target_lanes` picks; +1 / -1 about the lane to the left / right
    (status 'no_target_lane' where there is none), with the side in the scenes as `drive` has it."""
    settings = settings or AnalysisSettings()
    ego = ego.sort_values("t_s", kind="mergesort").reset_index(drop=True)
    t0, t1 = float(ego["t_s"].iloc[0]), float(ego["t_s"].iloc[-1])
    grid = t0 + cfg.dt_s * np.arange(int(np.floor((t1 - t0) / cfg.dt_s + 1e-9)) + 1)
    e = ego_at(pd.DataFrame({"state": np.arange(len(grid)), "t_s": grid}), ego)
    lanes = [int(ego["ego_lane"].max())] + ([int(traffic["lane"].max())] if len(traffic) else [])
    lane = e["ego_lane"].to_numpy(dtype=np.int64)
    if side is None:
        e["target_lane"] = target_lanes(lane, max(lanes))
    else:
        e["target_lane"] = np.where((lane + side >= 0) & (lane + side <= max(lanes)), lane + side, -1)
    cols = neighbours(e, traffic, settings)
    rows = pd.DataFrame({"ego_x_m": e["ego_x_m"], "ego_v_mps": e["ego_v_mps"]})
    if side is not None:  # the scenes know their side ('direction' observation)
        rows["ego_lane"], rows["target_lane"] = lane, e["target_lane"].to_numpy(dtype=np.int64)
    for role in ("f", "nf", "nb"):
        rows[f"{role}_present"] = ~np.isnan(cols[f"{role}_x_m"])
        for k in ("x_m", "v_mps", "gap_m"):
            rows[f"{role}_{k}"] = cols[f"{role}_{k}"]
    scene = scenes_from_decisions(rows, float(ego["ego_length_m"].iloc[0]))
    leader = seen(scene, cfg.range_m)[0]
    status = np.where(e["target_lane"] < 0, "no_target_lane", np.where(leader, "ok", "no_leader"))
    steps = pd.DataFrame(
        {
            "step": np.arange(len(grid)),
            "t_s": grid,
            "ego_lane": e["ego_lane"].astype(np.int64),
            "target_lane": e["target_lane"].astype(np.int64),
            "ego_v_mps": e["ego_v_mps"],
            "status": status,
            "button": e["lc_button"].astype(bool).to_numpy(),
            "f_id": cols["f_id"],
            "nf_id": cols["nf_id"],
            "nb_id": cols["nb_id"],
        }
    )
    return steps, scene


def driver_presses(ego: pd.DataFrame, steps: pd.DataFrame, dt_s: float) -> pd.DataFrame:
    """Each press (rising edge of the button) with the step it is stamped on: the first at or after it."""
    ego = ego.sort_values("t_s", kind="mergesort").reset_index(drop=True)
    btn = ego["lc_button"].to_numpy(dtype=bool)
    idx = np.flatnonzero(btn & ~np.r_[False, btn[:-1]])
    t = ego["t_s"].to_numpy(dtype=float)[idx]
    step = np.minimum(np.ceil((t - steps["t_s"].iloc[0]) / dt_s - 1e-9).astype(np.int64), len(steps) - 1)
    direction = ego["lc_direction"].to_numpy(dtype=object)[idx] if "lc_direction" in ego else [None] * len(idx)
    return pd.DataFrame({"press_t_s": t, "step": step, "direction": direction})


def decide(net: torch.nn.Module, cfg: EnvConfig, steps: pd.DataFrame, scene: Scene) -> pd.DataFrame:
    """Q-values and actions of the agent, the greedy benchmark's actions and rewards, the indicators:
    one row per step, NaN (actions -1) where the status is not 'ok'."""
    ok = (steps["status"] == "ok").to_numpy()
    n = len(steps)
    out = pd.DataFrame(index=range(n))
    q = np.full((n, 2), np.nan)
    if ok.any():
        q[ok] = q_values(net, observation(scene.take(np.flatnonzero(ok)), cfg))
    out["q_change"], out["q_keep"] = q[:, 0], q[:, 1]
    # argmax with ties to TO CHANGE, as rl.learners.dqn.greedy_actions
    out["agent_action"] = np.where(ok, np.where(q[:, 0] >= q[:, 1], CHANGE, 1 - CHANGE), -1)
    ind = indicators(scene, cfg.far_follower_m, cfg.range_m)
    r_change, r_keep = action_rewards(ind, cfg.lines, RewardSettings(name="paper"), cfg.dt_s)
    out["greedy_action"] = np.where(ok, greedy_actions(ind, cfg.lines, dt=cfg.dt_s), -1)
    out["r_change"], out["r_keep"] = np.where(ok, r_change, np.nan), np.where(ok, r_keep, np.nan)
    ref = cfg.lines.at(ind.v_e)
    for k, defined in (("t_f", ind.t_f_ok), ("t_nf", ind.t_nf_ok), ("dv_nb", ind.dv_nb_ok)):
        out[k] = np.where(defined, getattr(ind, k), np.nan)
        out[f"{k}_line"] = ref[k]
    return out


def _word(action: int) -> str:
    return "none" if action < 0 else ("change" if action == CHANGE else "keep")


def _num(x: float) -> float | None:
    return None if not np.isfinite(x) else round(float(x), 6)


def _compact(d: dict[str, Any]) -> bytes:
    """A message without its undefined fields (None is never written as a number)."""
    return json.dumps({k: v for k, v in d.items() if v is not None}, separators=(",", ":")).encode()


def messages(steps: pd.DataFrame, dec: pd.DataFrame, presses: pd.DataFrame) -> dict[str, list[bytes]]:
    """The four channels' messages, one per step each."""
    out: dict[str, list[bytes]] = {t: [] for t in SCHEMAS}
    pressed = presses.drop_duplicates("step", keep="first").set_index("step")
    for i, (s, d) in enumerate(zip(steps.itertuples(index=False), dec.itertuples(index=False))):
        base = {"t_s": round(float(s.t_s), 6), "step": int(s.step)}
        agent = int(d.agent_action)
        out[TOPIC_AGENT].append(
            _compact(
                {
                    **base,
                    "status": s.status,
                    "decision": _word(agent),
                    "action": agent if agent >= 0 else None,
                    "q_change": _num(d.q_change),
                    "q_keep": _num(d.q_keep),
                    "q_margin": _num(d.q_change - d.q_keep),
                }
            )
        )
        greedy = int(d.greedy_action)
        out[TOPIC_GREEDY].append(
            _compact(
                {
                    **base,
                    "status": s.status,
                    "decision": _word(greedy),
                    "action": greedy if greedy >= 0 else None,
                    "r_change": _num(d.r_change),
                    "r_keep": _num(d.r_keep),
                }
            )
        )
        press = pressed.loc[i] if i in pressed.index else None
        direction = press["direction"] if press is not None and press["direction"] in ("left", "right") else None
        out[TOPIC_DRIVER].append(
            _compact(
                {
                    **base,
                    "decision": "change" if press is not None else "keep",
                    "button": bool(s.button),
                    "direction": direction,
                    "press_t_s": None if press is None else round(float(press["press_t_s"]), 6),
                }
            )
        )
        out[TOPIC_SCENE].append(
            _compact(
                {
                    **base,
                    "status": s.status,
                    "ego_lane": int(s.ego_lane),
                    "target_lane": int(s.target_lane) if s.target_lane >= 0 else None,
                    "ego_v_mps": _num(s.ego_v_mps),
                    "f_id": s.f_id,
                    "nf_id": s.nf_id,
                    "nb_id": s.nb_id,
                    "t_f": _num(d.t_f),
                    "t_nf": _num(d.t_nf),
                    "dv_nb": _num(d.dv_nb),
                    "t_f_line": _num(d.t_f_line),
                    "t_nf_line": _num(d.t_nf_line),
                    "dv_nb_line": _num(d.dv_nb_line),
                }
            )
        )
    return out


def summarise(steps: pd.DataFrame, dec: pd.DataFrame, presses: pd.DataFrame) -> dict[str, Any]:
    """Counts of steps by status and decision, and what the agent and greedy said at the driver's presses."""
    ok = steps["status"] == "ok"
    at_press = dec.loc[presses["step"].to_numpy()]
    return {
        "steps": int(len(steps)),
        "steps_by_status": {k: int((steps["status"] == k).sum()) for k in STATUS},
        "agent_change_steps": int((dec["agent_action"] == CHANGE).sum()),
        "greedy_change_steps": int((dec["greedy_action"] == CHANGE).sum()),
        "presses": int(len(presses)),
        "agent_change_at_presses": int((at_press["agent_action"] == CHANGE).sum()),
        "greedy_change_at_presses": int((at_press["greedy_action"] == CHANGE).sum()),
        "agent_greedy_agree_ok_steps": int((dec.loc[ok, "agent_action"] == dec.loc[ok, "greedy_action"]).sum()),
    }


def resolve_recording(workspace: Workspace, key: str) -> str:
    """A recording id from its id, a unique prefix of it, or its session id."""
    cat = workspace.recordings()
    ids = cat["recording_id"].astype(str)
    for hits in (ids[ids == key], ids[cat["session_id"].astype(str) == key], ids[ids.str.startswith(key)]):
        if len(hits) == 1:
            return str(hits.iloc[0])
        if len(hits) > 1:
            raise UserError(f"recording {key!r} is ambiguous: {', '.join(hits.head(5))}; give the full id")
    raise UserError(f"no recording {key!r} in {workspace.root} (ids and sessions: `laneprint ingest` lists them)")


def annotate_recording(
    workspace: Workspace, run_id: str, recording: str, out: Path, progress: ProgressFn | None = None
) -> dict[str, Any]:
    """Write `recording` again to `out` with the run's, the greedy benchmark's and the driver's decisions."""
    out = Path(out)
    if out.suffix != ".mcap":
        raise SettingError(f"{{0}} {out}: give a file name ending in .mcap", "out")
    if out.is_dir():
        raise SettingError(f"{{0}} {out} is a folder: give a file name ending in .mcap", "out")
    net = load_weights(workspace, run_id)
    config = json.loads((run_dir(workspace, run_id) / "config.json").read_text())
    cfg = EnvConfig.from_dict(config["env"])
    rid = resolve_recording(workspace, recording)
    meta, ego, traffic = workspace.load_recording(rid)
    if len(ego) == 0:
        raise UserError(f"recording {rid} has no ego samples")
    report(progress, 0, 3, "reading the scenes")
    steps, scene = decision_steps(ego, traffic, cfg)
    report(progress, 1, 3, "deciding")
    dec = decide(net, cfg, steps, scene)
    presses = driver_presses(ego, steps, cfg.dt_s)
    msgs = messages(steps, dec, presses)
    stamps = np.round(steps["t_s"].to_numpy() * NS_PER_S).astype(np.int64).tolist()
    extra = [ExtraChannel(topic, name, schema, stamps, msgs[topic]) for topic, (name, schema) in SCHEMAS.items()]
    info = {
        "run_id": run_id,
        "recording_id": rid,
        "target": f"{config['target']['kind']} {config['target']['name']}",
        "reward": str(config.get("reward")),
        "dt_s": f"{cfg.dt_s:g}",
        "topics": ",".join(SCHEMAS),
        "target_lane_rule": "lane + 1 when the recording has it, else lane - 1",
        "undefined_rule": "; ".join(f"{k}: {v}" for k, v in STATUS.items() if k != "ok"),
    }
    report(progress, 2, 3, "writing")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_mcap(out, meta, ego, traffic, extra=extra, extra_metadata={METADATA_NAME: info})
    report(progress, 3, 3, "done")
    return {
        "run_id": run_id,
        "recording_id": rid,
        "session_id": str(meta.get("session_id")),
        "out": str(out.resolve()),
        "dt_s": cfg.dt_s,
        "topics": list(SCHEMAS),
        **summarise(steps, dec, presses),
    }
