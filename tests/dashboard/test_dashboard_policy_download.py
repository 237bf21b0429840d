"""The deployable policy from the default install (issue 48): the Results page exports it, the zip's
policy.onnx runs in onnxruntime, and a failing export or a missing onnx says why on the page."""

import io
import json
import shutil
import zipfile

import numpy as np
import pytest
from streamlit.testing.v1 import AppTest

from dashboard import jobs
from dashboard_support import page_path
from laneprint.workspace import Workspace


def results_page() -> AppTest:
    at = AppTest.from_file(page_path("results"), default_timeout=120).run()
    assert not at.exception, [e.value for e in at.exception]
    return at


def test_onnx_is_a_base_dependency():
    import tomllib

    from dashboard_support import ROOT

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    assert {d.split(">")[0] for d in deps} >= {"onnx", "onnxruntime"}
    assert jobs.onnx_missing() is None


@pytest.mark.slow
def test_the_exported_zip_runs_in_onnxruntime(sample_ws, tmp_path, monkeypatch):
    import onnxruntime as ort

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    at = results_page()
    run_id = at.selectbox(key="result_run").value
    assert not jobs.policy_is_current(ws, run_id)
    at.button(key=f"export_onnx_{run_id}").click().run()
    assert not at.exception and not at.error, [e.value for e in at.error]
    assert jobs.policy_is_current(ws, run_id)
    zf = zipfile.ZipFile(io.BytesIO(jobs.policy_zip(ws, run_id)))
    spec = json.loads(zf.read(f"{run_id}/policy.json"))
    sess = ort.InferenceSession(zf.read(f"{run_id}/policy.onnx"), providers=["CPUExecutionProvider"])
    obs = np.zeros((3, len(spec["inputs"])), dtype=np.float32)
    q, action = sess.run(["q_values", "action"], {spec["input"]["name"]: obs})
    assert q.shape[0] == 3 and np.isfinite(q).all() and set(action.tolist()) <= {0, 1}


def test_a_failing_export_says_why_on_the_page(sample_ws, tmp_path, monkeypatch):
    from laneprint.errors import UserError

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))

    def broken(*a, **k):
        raise UserError("ONNX check failed: max |Q_onnxruntime - Q_torch| = 0.1 > 0.0001")

    monkeypatch.setattr("rl.deploy.export.export_run", broken)
    at = results_page()
    run_id = at.selectbox(key="result_run").value
    at.button(key=f"export_onnx_{run_id}").click().run()
    assert any("could not be exported: ONNX check failed" in e.value for e in at.error)

    monkeypatch.setattr(jobs, "onnx_missing", lambda: "the ONNX export needs onnx and onnxruntime")
    at = results_page()
    assert any("needs onnx and onnxruntime" in i.value for i in at.info)
    assert not any(b.key == f"export_onnx_{run_id}" for b in at.button)
