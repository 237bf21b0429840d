"""The Results page marks runs made with an earlier analysis than the current one (issue 48)."""

import json
import shutil

import pytest
from streamlit.testing.v1 import AppTest

from dashboard_support import page_path
from laneprint.workspace import Workspace, analysis_fingerprint


def run_results() -> AppTest:
    at = AppTest.from_file(page_path("results"), default_timeout=60).run()
    assert not at.exception, [e.value for e in at.exception]
    return at


@pytest.mark.slow
def test_results_mark_a_run_of_an_earlier_analysis(sample_ws, tmp_path, monkeypatch):
    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    at = run_results()
    assert any("made with the current analysis" in c.value for c in at.caption)
    assert not any("earlier analysis" in w.value for w in at.warning)

    # a re-analysis that moves a driver to another style
    tables = {
        n: ws.read_table("analysis", n)
        for n in ("decisions", "reference_lines", "styles", "correlations", "fits", "skipped")
    }
    styles = tables["styles"]
    names = sorted(set(styles.loc[styles["cluster"] >= 0, "style"]))
    i = styles.index[styles["cluster"] >= 0][0]
    styles.loc[i, "style"] = next(n for n in names if n != styles.loc[i, "style"])
    ws.write_tables(
        "analysis", tables, {**ws.read_meta("analysis"), "analysis_fingerprint": analysis_fingerprint(tables)}
    )
    at = run_results()
    warned = [w.value for w in at.warning if "made with an earlier analysis: re-run" in w.value]
    assert warned, [w.value for w in at.warning]
    assert any("laneprint train --style Normal" in c.value for c in at.caption)

    run_id = at.selectbox(key="result_run").value
    cfg_path = ws.runs_dir / run_id / "config.json"
    cfg = json.loads(cfg_path.read_text())
    del cfg["analysis_fingerprint"]  # a run from before runs recorded their analysis
    cfg_path.write_text(json.dumps(cfg))
    at = run_results()
    assert any("analysis unknown" in i.value for i in at.info)
