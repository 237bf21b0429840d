"""`laneprint export`: ONNX that gives torch's Q-values, loadable and fed without laneprint."""

import inspect
import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from laneprint.app.cli import app
from rl.problem.env import EnvConfig, observation, observation_names, sample_scenes
from rl.deploy.export import TOLERANCE
from rl.runs import Target, load_weights, recorded_approaches, run_dir
from rl.problem.scene import Scene, indicators, seen
from tests.support.rl_workspaces import raw_measurements, spec_value

# Runs in a fresh interpreter where laneprint, rl and torch cannot be imported: it builds the
# observation from raw measurements with policy.json's description alone and runs policy.onnx.
STANDALONE = r"""
import json, math, sys
for name in ("torch", "laneprint", "rl", "ingest", "indicators"):
    sys.modules[name] = None  # any import of these now fails
import numpy as np, onnxruntime as ort

folder, raw_path = sys.argv[1], sys.argv[2]
spec = json.load(open(f"{folder}/policy.json"))
raws = json.load(open(raw_path))

{spec_value}
obs = np.array([[spec_value(s, raw) for s in spec["inputs"]] for raw in raws], dtype=np.float32)
sess = ort.InferenceSession(f"{folder}/policy.onnx", providers=["CPUExecutionProvider"])
q, action = sess.run(["q_values", "action"], {spec["input"]["name"]: obs})
json.dump({"q": q.tolist(), "action": action.tolist(), "obs": obs.tolist()}, sys.stdout)
""".replace("{spec_value}", inspect.getsource(spec_value))


@pytest.mark.slow
def test_export_matches_torch_and_needs_nothing_of_laneprint(trained_run, tmp_path):
    ws, run_id = trained_run
    out = tmp_path / "policy"
    res = CliRunner().invoke(
        app, ["export", run_id, "--format", "onnx", "--out", str(out), "-w", str(ws.root), "--json"]
    )
    assert res.exit_code == 0, res.output
    got = json.loads(res.stdout)
    check = got["check"]
    cfg = EnvConfig.from_dict(json.loads((run_dir(ws, run_id) / "config.json").read_text())["env"])
    approaches = recorded_approaches(ws, Target("style", "Normal"))
    assert check["passed"] and check["tolerance"] == TOLERANCE
    evals = check["sets"]["evaluation_states"]
    assert evals["n_states"] == sum(len(a) for a in approaches) == 84  # 12 decisions x 7 states
    assert evals["max_abs_diff"] <= TOLERANCE and evals["actions_agree"] == evals["n_states"]
    assert check["sets"]["synthetic_scenes"]["n_states"] == 2000
    assert sorted(p.name for p in out.iterdir()) == ["README.md", "policy.json", "policy.onnx"]
    doc = json.loads((out / "policy.json").read_text())
    assert [s["name"] for s in doc["inputs"]] == list(observation_names(cfg)) == got["inputs"]
    assert doc["run"]["run_id"] == run_id and doc["run"]["target"] == {"kind": "style", "name": "Normal"}
    assert "t_nf" in (out / "README.md").read_text()

    # the recorded evaluation states plus synthetic ones where each vehicle is sometimes absent or out of range
    odd = sample_scenes(np.random.default_rng(1), replace(cfg, nb_present_prob=0.5, nb_gap0_m=(5.0, 200.0)), 300)
    odd.f_present[::5] = False
    scene = Scene.concat([a.scene for a in approaches] + [odd])
    ind = indicators(scene, cfg.far_follower_m, cfg.range_m)
    for defined in (*seen(scene, cfg.range_m), ind.t_f_ok, ind.t_nf_ok, ind.dv_nb_ok):
        assert 0 < defined.sum() < len(defined)  # every undefined rule of policy.json is exercised
    raw_path = tmp_path / "raw.json"
    raw_path.write_text(json.dumps(raw_measurements(scene, cfg)))
    proc = subprocess.run(
        [sys.executable, "-c", STANDALONE, str(out), str(raw_path)], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    standalone = json.loads(proc.stdout)
    obs = observation(scene, cfg)
    np.testing.assert_allclose(np.array(standalone["obs"]), obs, atol=1e-6)  # the documentation is exact
    net = load_weights(ws, run_id)
    with torch.no_grad():
        q_torch = net(torch.as_tensor(obs)).numpy()
    assert np.abs(np.array(standalone["q"]) - q_torch).max() <= TOLERANCE
    assert standalone["action"] == q_torch.argmax(axis=1).tolist()


def test_export_refuses_bad_input(trained_run, tmp_path):
    ws, run_id = trained_run
    runner = CliRunner()
    res = runner.invoke(app, ["export", run_id, "--format", "tflite", "-w", str(ws.root)])
    assert res.exit_code == 1 and "unknown --format 'tflite'" in res.output
    res = runner.invoke(app, ["export", "nope", "-w", str(ws.root)])
    assert res.exit_code == 1 and "no run 'nope'" in res.output
    (tmp_path / "file").write_text("x")
    res = runner.invoke(app, ["export", run_id, "--out", str(tmp_path / "file"), "-w", str(ws.root)])
    assert res.exit_code == 1 and "is a file" in res.output


def test_export_carries_the_held_back_rule(trained_run, tmp_path, monkeypatch):
    """policy.json holds the rule's numbers and says how to apply them; a threshold computed from the
    documentation alone equals laneprint's; without acceptance lines it says why there is none."""
    from rl.deploy import export as export_mod
    from rl.drive.heldback import HeldBackRule, Line

    ws, run_id = trained_run
    res = CliRunner().invoke(app, ["export", run_id, "--out", str(tmp_path / "none"), "-w", str(ws.root), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads((tmp_path / "none" / "policy.json").read_text())
    assert doc["held_back_rule"]["available"] is False and "gap_nf" in doc["held_back_rule"]["why"]
    assert "Not available" in (tmp_path / "none" / "README.md").read_text()

    rule = HeldBackRule(
        5.5,
        Line(5.5, -61.4, 9.0, 25.8, 8.6),
        Line(0.0, 29.4, 9.0, 25.8, 6.4),
        Line(0.0, 3.4, 9.0, 25.8, 0.75),
        source={"patience_s": "test"},
    )
    monkeypatch.setattr(export_mod, "rule_from_analysis", lambda *a, **k: rule)
    res = CliRunner().invoke(app, ["export", run_id, "--out", str(tmp_path / "rule"), "-w", str(ws.root), "--json"])
    assert res.exit_code == 0, res.output
    hb = json.loads((tmp_path / "rule" / "policy.json").read_text())["held_back_rule"]
    assert hb["available"] and hb["patience_s"] == 5.5 and "patience_s" in hb["how"]
    for k in ("gap_nf", "gap_nb", "thw_nb"):
        for v in (5.0, 15.0, 30.0):
            line = hb[k]
            documented = max(line["A"] * min(max(v, line["v_lo"]), line["v_hi"]) + line["b"], line["floor"])
            assert documented == float(getattr(rule, k).at(v))
    text = (tmp_path / "rule" / "README.md").read_text()
    assert "Held-back rule" in text and "5.5 s" in text and "`gap_nb`" in text
    # the policy's pace, as drive applies it, documented with where it came from (the shared workspace
    # holds a recording of D01 or none, depending on which tests ran before)
    why = hb["source"]["min_advantage"]
    assert hb["min_advantage"] >= 0 and ("replayed along" in why or "no recording with presses" in why)
    assert "min_advantage" in hb["how"] and "min_advantage = " in text and "min_advantage_by_side" in hb["how"]
    for side, value in hb["min_advantage_by_side"].items():  # by side: each written where the README says
        assert f"{value:g} to the {side}" in text
    if not hb["min_advantage_by_side"]:
        assert f"min_advantage = {hb['min_advantage']:g}" in text
    # the undo check on the policy's changes to the left: on, with how a vehicle stack applies it
    assert hb["undo_check"] is True and "undo_check" in hb["how"] and "undo_check = true" in text
