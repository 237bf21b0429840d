"""`laneprint export RUN_ID --format onnx`: a run's policy as ONNX, documented, checked.

The output folder holds

- ``policy.onnx``: input ``observation`` float32 (batch, n_inputs); outputs
  ``q_values`` float32 (batch, 2) and ``action`` int64 (batch,), the argmax
  (ties go to 0, TO CHANGE, as in laneprint);
- ``policy.json``: the inputs in order with units and scaling
  (`rl.problem.observation`), the actions, which run / target / lines it came from,
  and the check below;
- ``README.md``: the same for a reader, with a loader that needs only
  onnxruntime and numpy.

Both also carry the assistant's **held-back rule** (`rl.drive.heldback`, as `laneprint drive`
applies it by default): its patience, the acceptance lines of the target's lead gap, lag gap
and follower headway, and how a vehicle stack applies it beside the policy (`held_back_rule`
in policy.json; none when the workspace's analysis lacks the acceptance lines).

The check: onnxruntime's Q-values against torch's on the run's evaluation states
(the target's recorded not-yet and press states, `rl.runs.recorded_approaches`)
and on seeded synthetic scenes; the export fails (and writes nothing) when the
largest absolute difference exceeds `TOLERANCE`.

Exporter: torch's TorchScript-based exporter (``dynamo=False``) needs only the
``onnx`` package, where the dynamo exporter also needs ``onnxscript`` and its
dependencies; for a 3-layer MLP both give the same graph of Gemm and Relu.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import uuid
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from laneprint.errors import SettingError, UserError
from laneprint.progress import ProgressFn, report
from laneprint.workspace import Workspace, atomic_write_bytes, atomic_write_json
from rl.drive.heldback import ACCEPT_INDICATORS, by_side_text, rule_from_analysis
from rl.drive.pace import pace_threshold
from rl.problem.env import EnvConfig, observation, sample_scenes
from rl.problem.observation import ACTIONS, ROLES, constants, observation_spec
from rl.runs import Target, load_weights, recorded_approaches, run_dir, target_drivers
from rl.problem.scene import Scene

FORMATS = ("onnx",)
OPSET = 17
TOLERANCE = 1e-4  # largest |Q_onnxruntime - Q_torch| accepted [units of Q]
SYNTHETIC_STATES = 2000  # seeded scenes checked besides the recorded ones
INPUT, OUTPUTS = "observation", ("q_values", "action")


class _Policy(torch.nn.Module):
    """Q-network plus its greedy action, the two outputs of the exported graph."""

    def __init__(self, net: torch.nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        q = self.net(obs)
        return q, torch.argmax(q, dim=1)


#: What to install when onnx or onnxruntime is missing (both are base dependencies of laneprint).
ONNX_HINT = (
    "the ONNX export needs onnx and onnxruntime, which `pip install -e .` installs (base dependencies); "
    "into this environment: pip install 'onnx>=1.17' 'onnxruntime>=1.20'"
)


def onnx_missing() -> str | None:
    """`ONNX_HINT` when onnx or onnxruntime cannot be imported here, else None (checked without importing them)."""
    from importlib.util import find_spec

    return None if find_spec("onnx") and find_spec("onnxruntime") else ONNX_HINT


def _require_onnx() -> None:
    try:
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError:
        raise UserError(ONNX_HINT) from None


def onnx_bytes(net: torch.nn.Module, n_inputs: int, metadata: dict[str, str]) -> bytes:
    """The policy as an ONNX model (dynamic batch), with `metadata` as the model's metadata_props."""
    import onnx

    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
        torch.onnx.export(
            _Policy(net).eval(),
            (torch.zeros(1, n_inputs),),
            buf,  # type: ignore[arg-type]  # torch annotates a path only; the TorchScript exporter writes to files too
            input_names=[INPUT],
            output_names=list(OUTPUTS),
            opset_version=OPSET,
            dynamo=False,
            dynamic_axes={INPUT: {0: "batch"}, OUTPUTS[0]: {0: "batch"}, OUTPUTS[1]: {0: "batch"}},
        )
    model = onnx.load_from_string(buf.getvalue())
    for k, v in metadata.items():
        model.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(model)
    return model.SerializeToString()


def compare(model: bytes, net: torch.nn.Module, obs: np.ndarray) -> dict[str, Any]:
    """onnxruntime vs torch on `obs`: largest |dQ|, and how many greedy actions agree."""
    import onnxruntime as ort

    sess = ort.InferenceSession(model, providers=["CPUExecutionProvider"])
    q_ort, a_ort = sess.run(list(OUTPUTS), {INPUT: obs.astype(np.float32)})
    with torch.no_grad():
        q_torch = net(torch.as_tensor(obs, dtype=torch.float32)).numpy()
    diff = float(np.abs(q_ort - q_torch).max()) if len(obs) else 0.0
    return {
        "n_states": int(len(obs)),
        "max_abs_diff": diff,
        "actions_agree": int((a_ort == q_torch.argmax(axis=1)).sum()),
        "q_range": [float(q_torch.min()), float(q_torch.max())] if len(obs) else None,
    }


def check_states(workspace: Workspace, target: Target, cfg: EnvConfig, seed: int) -> dict[str, np.ndarray]:
    """Observations to check on: the run's evaluation states (when the analysis has them) and seeded
    synthetic scenes."""
    out: dict[str, np.ndarray] = {}
    try:
        approaches = recorded_approaches(workspace, target)
        out["evaluation_states"] = observation(Scene.concat([a.scene for a in approaches]), cfg)
    except UserError:
        pass  # e.g. a `--lines paper` run in a workspace without analysis: synthetic scenes only
    out["synthetic_scenes"] = observation(sample_scenes(np.random.default_rng(seed), cfg, SYNTHETIC_STATES), cfg)
    return out


HELD_BACK_HOW = (
    "Apply beside the policy, every decision step while the ego is at its lane centre: the ego is held back "
    "when its lane's leader (within range_m) is slower than the ego's desired speed (the driver's set speed) "
    "by slower_mps and the ego is too; a clock runs while it is held back without a break and stops at a "
    "lane change. When the policy keeps and the clock has reached patience_s, request the change to a "
    "neighbouring lane that is faster (no leader there within range_m, or one at least slower_mps faster than "
    "the ego's leader) and whose gaps the target accepts: lead gap >= gap_nf, and, unless the follower is "
    "absent or farther than far_follower_m, lag gap >= gap_nb and the follower's time headway (lag gap / its "
    "speed) >= thw_nb; each threshold is max(A * clip(v_e, v_lo, v_hi) + b, floor), v_e the ego's speed [m/s]. "
    "Of two such lanes take the one whose leader is faster (none: faster; a tie: the left one). Carry an "
    "overtaking through (any change to the left from behind a leader, the policy's or the rule's): while the "
    "leader it left is still ahead of the ego (centre to centre), within range_m and slower than the ego's "
    "desired speed by slower_mps, do not follow the policy back into the lane it left; once it is not (passed, "
    "out of range or no longer that slow), when the policy keeps and that lane's gaps are accepted as "
    "above (and above the floors below), request the return there. And under every change, the policy's too: none into a lead gap "
    "below gap_nf's floor or closing on the target lane's leader with a time to collision below "
    "t_nf_floor_s, or, with a follower within far_follower_m, a lag gap below gap_nb's floor, its "
    "time headway below thw_nb's floor or dv_nb (v_e - v_nb) below dv_nb_floor_mps (the smallest the target "
    "took: 5th percentile of its presses; null: no floor). Where lag_draws has a list for a side, draw one value of it at random at each of the ego's lane changes (and at the start); until the next one, the policy's own change to that side in front of a follower within far_follower_m needs that follower's time headway at least the value drawn (the headways at which the target's drivers pressed to that side). And no change at all sooner after the ego's last "
    "lane change (the moment it crossed into its lane) than dwell_s says for that pair of sides "
    "('left>right': a change to the right after one to the left; a pair missing: no wait): the policy decides "
    "state by state without memory, the drivers do not press again at once. The policy's own change is taken "
    "only when q_change - q_keep >= min_advantage (its drivers' pace: replayed along their logs, the policy "
    "then starts wanting a change no more often than they pressed); where min_advantage_by_side is given, a change "
    "to the left needs its 'left' value and one to the right its 'right' value instead (each side held to the "
    "drivers' presses to that side). When undo_check is true and the ego has no leader "
    "within range_m, the policy's own change to the left is requested only if it would not undo it at once: "
    "build the observation as if the ego were already in the target lane (same position and speed; the "
    "leader there becomes its leader, the lane it would leave becomes the target lane) and run the policy; "
    "if q_change - q_keep there reaches what a change to the right needs, keep."
)


def held_back_rule(
    workspace: Workspace, target: Target, cfg: EnvConfig, net: torch.nn.Module | None = None
) -> dict[str, Any]:
    """The held-back rule of the run's target for policy.json: its numbers and how to apply it (with
    `net`, the policy's pace, `rl.drive.pace`, as `drive` applies it)."""
    try:
        rule = rule_from_analysis(workspace, target, cfg.dt_s)
    except (ValueError, KeyError, UserError, FileNotFoundError) as exc:
        return {"available": False, "why": str(exc)}
    try:
        drivers = target_drivers(workspace, target)[0] if net is not None else None
    except UserError:
        drivers = None
    if drivers and net is not None:  # drivers are looked up only with a net
        rule = rule.with_pace(pace_threshold(workspace, drivers, net, cfg))
    return {
        "available": True,
        "how": HELD_BACK_HOW,
        "units": {
            "patience_s": "s",
            "slower_mps": "m/s",
            "gap_nf": "m",
            "gap_nb": "m",
            "thw_nb": "s",
            "far_follower_m": "m",
            "t_nf_floor_s": "s",
            "dv_nb_floor_mps": "m/s",
            "dwell_s": "s",
            "lag_draws": "s",
            "min_advantage": "Q units",
            "v_lo": "m/s",
            "v_hi": "m/s",
        },
        "desired_speed": "the driver's set speed; `laneprint drive` uses the section's limit x the ego "
        "vType's SUMO speedFactor",
        "range_m": cfg.range_m,
        **rule.to_dict(),
    }


def _describe(
    config: dict[str, Any], cfg: EnvConfig, checks: dict[str, Any], held_back: dict[str, Any] | None = None
) -> dict[str, Any]:
    return {
        "format": "onnx",
        "opset": OPSET,
        "file": "policy.onnx",
        "input": {"name": INPUT, "dtype": "float32", "shape": ["batch", len(observation_spec(cfg))]},
        "outputs": {
            "q_values": "float32 (batch, 2): Q of each action",
            "action": "int64 (batch,): argmax of q_values, ties to 0",
        },
        "inputs": observation_spec(cfg),
        "constants": constants(cfg),
        "roles": ROLES,
        "target_lane": "the lane the ego would change to (the adjacent lane the decision is about)",
        "actions": {str(k): v for k, v in ACTIONS.items()},
        "run": {
            k: config.get(k)
            for k in (
                "run_id",
                "target",
                "reward",
                "lines_source",
                "lines",
                "seed",
                "data_fingerprint",
                "code_version",
                "created_at",
            )
        }
        | {
            "observation": cfg.observation,
            "scenes": cfg.scenes,
            "learner": config.get("learner", "dqn"),
            "episodes": (config.get("dqn") or {}).get("episodes"),
        },
        "check": checks,
        "held_back_rule": held_back or {"available": False, "why": "not computed"},
    }


def _learned(run: dict[str, Any]) -> str:
    """How the policy was learnt, for the README."""
    if run.get("learner") == "trees":
        return "Q functions fitted by fitted Q iteration with boosted trees (each tree a run of Gather nodes)"
    return f"{run['episodes']} episodes of DQN"


def _readme(doc: dict[str, Any]) -> str:
    run = doc["run"]
    rows = "\n".join(
        f"| {s['index']} | `{s['name']}` | {s['quantity']} | {s['unit']} | {_formula(s)} | {_undefined(s)} |"
        for s in doc["inputs"]
    )
    checks = "\n".join(
        f"- {name}: {c['n_states']} states, max |Q_onnxruntime - Q_torch| = {c['max_abs_diff']:.2e}"
        f", greedy actions agree on {c['actions_agree']}"
        for name, c in doc["check"]["sets"].items()
    )
    lines = run["lines"] or {}
    return f"""# Lane-change policy `{run["run_id"]}` (ONNX)

Trained by laneprint for {run["target"]["kind"]} **{run["target"]["name"]}**, reward `{run["reward"]}`,
observation `{run["observation"]}`, scenes `{run["scenes"]}`, {_learned(run)}, seed {run["seed"]};
reference lines ({run["lines_source"]}: {lines.get("source", "")}): t_f = {lines.get("t_f")},
t_nf = {lines.get("t_nf")}, dv_nb = {lines.get("dv_nb")} (A, b of `I = A v_e + b`). Data fingerprint
`{run["data_fingerprint"]}`, code {(run.get("code_version") or {}).get("git_commit")}.

## Use

Every `{doc["constants"]["dt_s"]}` s, build the observation below from the ego and the three
vehicles around it, run `policy.onnx`, and act on `action`:
{chr(10).join(f"- `{k}`: {v}" for k, v in doc["actions"].items())}

The agent decides when to leave a slower leader: ask it while the ego has a leader in its lane
within {doc["constants"]["range_m"]:g} m and an adjacent lane (`laneprint annotate` asks it only then).

```python
import json, numpy as np, onnxruntime as ort
spec = json.load(open("policy.json"))
sess = ort.InferenceSession("policy.onnx", providers=["CPUExecutionProvider"])
obs = np.zeros((1, spec["input"]["shape"][1]), np.float32)  # fill as the table says
q_values, action = sess.run(["q_values", "action"], {{"observation": obs}})
```

## Inputs (`observation`, float32, in this order)

The vehicles: {"; ".join(f"{k}: {v}" for k, v in doc["roles"].items())}. The target lane is
{doc["target_lane"]}. Every value is clipped to [{doc["constants"]["obs_floor"]}, 1] after scaling.

| # | name | raw quantity | unit | value | when undefined |
|---|---|---|---|---|---|
{rows}

`policy.json` holds the same table as data (`inputs`: transform, scale, offset, cap, clip).

{_held_back_text(doc["held_back_rule"])}

## Check (tolerance {doc["check"]["tolerance"]} on Q)

{checks}
"""


def _held_back_text(rule: dict[str, Any]) -> str:
    """The README's section on the held-back rule."""
    if not rule.get("available"):
        return f"## Held-back rule\n\nNot available: {rule.get('why', '')}\n"
    rows = "\n".join(
        f"| `{k}` | {rule[k]['A']:.4g} | {rule[k]['b']:.4g} | {rule[k]['v_lo']:.3g}-"
        f"{'inf' if rule[k]['v_hi'] is None else format(rule[k]['v_hi'], '.3g')} | {rule[k]['floor']:.3g} | "
        f"{rule['units'][k]} | {rule['source'].get(k, '')} |"
        for k in ACCEPT_INDICATORS
    )
    return f"""## Held-back rule (apply beside the policy)

The policy learnt when drivers press while closing in on a leader; a leader the ego has caught up
with and follows at its speed is not such a scene, so the policy alone may follow it for ever. The
assistant therefore also applies this rule (`laneprint drive` does by default;
`policy.json` `held_back_rule`):

{rule["how"]}

- patience_s = **{rule["patience_s"]:g} s** ({rule["source"].get("patience_s", "")})
- t_nf_floor_s = {rule["t_nf_floor_s"]:.3g} s ({rule["source"].get("t_nf_floor_s", "")})
- dv_nb_floor_mps = {_num(rule.get("dv_nb_floor_mps"), " m/s")} ({rule["source"].get("dv_nb_floor_mps", "")})
- dwell_s = {", ".join(f"{k} {v:.3g} s" for k, v in rule.get("dwell_s", {}).items()) or "none"} ({rule["source"].get("dwell_s", "")})
- min_advantage = {by_side_text(rule.get("min_advantage_by_side") or {}) or format(rule.get("min_advantage", 0.0), "g")} ({rule["source"].get("min_advantage", "the policy as trained")})
- undo_check = {str(rule.get("undo_check", False)).lower()} ({rule["source"].get("undo_check", "with no leader, no change to the left the policy would at once undo")})
- slower_mps = {rule["slower_mps"]:g} m/s, far_follower_m = {rule["far_follower_m"]:g} m,
  range_m = {rule["range_m"]:g} m; desired speed: {rule["desired_speed"]}

| threshold | A | b | v_e range [m/s] | floor | unit | from |
|---|---|---|---|---|---|---|
{rows}
"""


def _num(x: Any, unit: str) -> str:
    return "none" if x is None else f"{x:.3g}{unit}"


def _formula(s: dict[str, Any]) -> str:
    if s["transform"] == "linear":
        return f"raw x {s['scale']:.6g} + {s['offset']:g}"
    if s["transform"] == "log1p_capped":
        return f"log1p(min(max(raw, 0), {s['cap']:g})) / log1p({s['cap']:g})"
    if s["transform"] == "constant":
        return f"{s['value']:g}"
    return f"1 if `{s['of']}` defined else 0"


def _undefined(s: dict[str, Any]) -> str:
    u = s.get("when_undefined")
    if not u:
        return "-"
    return (f"as `{u['same_as']}`" if "same_as" in u else f"{u['value']:g}") + f" ({u['why']})"


def _swap_in(tmp: Path, final: Path) -> None:
    """Put the finished folder `tmp` at `final`, replacing an earlier export in one rename each."""
    old = None
    if final.exists():
        old = final.with_name(f".{final.name}.old-{uuid.uuid4().hex[:8]}")
        os.rename(final, old)
    os.rename(tmp, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def export_run(
    workspace: Workspace, run_id: str, fmt: str = "onnx", out: Path | None = None, progress: ProgressFn | None = None
) -> dict[str, Any]:
    """Export a run's policy (see the module doc); returns a JSON-ready summary with the check."""
    if fmt not in FORMATS:
        raise SettingError(f"unknown {{0}} {fmt!r}: choose one of {', '.join(FORMATS)}", "format")
    _require_onnx()
    net = load_weights(workspace, run_id)
    config = json.loads((run_dir(workspace, run_id) / "config.json").read_text())
    cfg = EnvConfig.from_dict(config["env"])
    target = Target(**config["target"])
    final = Path(out) if out is not None else workspace.root / "exports" / run_id
    if final.exists() and not final.is_dir():
        raise SettingError(f"{{0}} {final} is a file: give a folder", "out")
    report(progress, 0, 3, "exporting")
    n_inputs = len(observation_spec(cfg))
    model = onnx_bytes(
        net,
        n_inputs,
        {
            "laneprint_run_id": run_id,
            "observation": ",".join(s["name"] for s in observation_spec(cfg)),
            "documentation": "policy.json",
        },
    )
    report(progress, 1, 3, "checking with onnxruntime")
    sets = {
        name: compare(model, net, obs)
        for name, obs in check_states(workspace, target, cfg, int(config.get("seed", 0))).items()
    }
    worst = max(c["max_abs_diff"] for c in sets.values())
    checks = {
        "tolerance": TOLERANCE,
        "max_abs_diff": worst,
        "passed": worst <= TOLERANCE,
        "sets": sets,
        "how": "onnxruntime (CPUExecutionProvider) vs torch on the same float32 observations",
    }
    if not checks["passed"]:
        raise UserError(
            f"ONNX check failed: max |Q_onnxruntime - Q_torch| = {worst:.3g} > {TOLERANCE:g}; nothing written"
        )
    doc = _describe(config, cfg, checks, held_back_rule(workspace, target, cfg, net))
    report(progress, 2, 3, "writing")
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = final.with_name(f".{final.name}.tmp-{uuid.uuid4().hex[:8]}")
    tmp.mkdir()
    try:
        atomic_write_bytes(tmp / "policy.onnx", model)
        atomic_write_json(tmp / "policy.json", doc)
        atomic_write_bytes(tmp / "README.md", _readme(doc).encode())
        for f in tmp.iterdir():
            f.chmod(0o644)  # a folder to hand over: readable by others, unlike the temporary files
        tmp.chmod(0o755)
        _swap_in(tmp, final)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    report(progress, 3, 3, "done")
    return {
        "run_id": run_id,
        "format": fmt,
        "folder": str(final.resolve()),
        "files": ["policy.onnx", "policy.json", "README.md"],
        "inputs": [s["name"] for s in doc["inputs"]],
        "check": checks,
    }
