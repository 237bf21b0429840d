"""Every result records the analysis it was made from; `runs` marks those made with an earlier one."""

import json

import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.provenance import analysis_mark
from laneprint.workspace import Workspace, analysis_fingerprint
from rl.runs import list_runs
from tests.support.rl_workspaces import FAST_CLI as FAST, analysed_workspace


def reanalyse(ws: Workspace, change) -> str:
    """Store the analysis again with `change(styles, reference_lines)` applied, as `analyze` would save it."""
    tables = {n: ws.read_table("analysis", n) for n in ("decisions", "reference_lines", "styles")}
    change(tables["styles"], tables["reference_lines"])
    fp = analysis_fingerprint(tables)
    ws.write_tables("analysis", tables, {**ws.read_meta("analysis"), "analysis_fingerprint": fp})
    return fp


def runs_json(root) -> dict:
    res = CliRunner().invoke(app, ["runs", "-w", str(root), "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


def test_analysis_mark_labels():
    assert analysis_mark("a", "a")["analysis_label"] == "made with the current analysis"
    assert analysis_mark("a", "b")["analysis_label"] == "made with an earlier analysis: re-run"
    assert analysis_mark(None, "b")["analysis_label"] == "analysis unknown"
    assert analysis_mark("a", None)["analysis"] == "earlier"  # the analysis is gone


def test_fingerprint_follows_what_the_analysis_decided(tmp_path):
    ws = analysed_workspace(tmp_path)
    before = ws.analysis_fingerprint()
    assert before and len(before) == 16
    assert reanalyse(ws, lambda s, r: None) == before  # same styles and lines: the same analysis
    assert reanalyse(ws, lambda s, r: r.__setitem__("b", r["b"] + 0.5)) != before  # other lines
    assert Workspace(tmp_path).analysis_fingerprint() != before


def test_runs_marks_a_run_made_with_an_earlier_analysis(tmp_path):
    ws = analysed_workspace(tmp_path)
    res = CliRunner().invoke(
        app, ["train", "--style", "Normal", "--episodes", "60", "--run-id", "r1", "-w", str(tmp_path), "--json", *FAST]
    )
    assert res.exit_code == 0, res.output
    config = json.loads((ws.runs_dir / "r1" / "config.json").read_text())
    evaluation = json.loads((ws.runs_dir / "r1" / "evaluation.json").read_text())
    assert config["analysis_fingerprint"] == ws.analysis_fingerprint() == evaluation["analysis_fingerprint"]
    assert "median" in evaluation["fields"]["medae_t_f"] and evaluation["summary"][0]["medae_t_f"] is not None
    out = runs_json(tmp_path)
    assert out["runs"][0]["analysis"] == "current" and out["current_analysis_fingerprint"] == ws.analysis_fingerprint()

    def move_driver(styles, refs):
        styles.loc[0, "style"] = "Aggressive"  # the driver changed style

    reanalyse(ws, move_driver)
    row = runs_json(tmp_path)["runs"][0]
    assert row["analysis"] == "earlier" and row["analysis_label"] == "made with an earlier analysis: re-run"
    assert list_runs(ws).loc[0, "analysis_fingerprint"] == config["analysis_fingerprint"]
    text = CliRunner().invoke(app, ["runs", "-w", str(tmp_path)]).output
    assert "earlier analysis" in text and "re-run" in text

    del config["analysis_fingerprint"]  # a run made before runs recorded it
    (ws.runs_dir / "r1" / "config.json").write_text(json.dumps(config))
    assert runs_json(tmp_path)["runs"][0]["analysis_label"] == "analysis unknown"


@pytest.mark.slow
def test_report_marks_runs_of_an_earlier_analysis(tmp_path):
    from dashboard.report import _runs, provenance

    ws = analysed_workspace(tmp_path)
    res = CliRunner().invoke(
        app, ["train", "--style", "Normal", "--episodes", "60", "--run-id", "r1", "-w", str(tmp_path), *FAST]
    )
    assert res.exit_code == 0, res.output
    texts = lambda: [t for s in _runs(ws) for k, t in s.items if k in ("p", "warn")]  # noqa: E731
    assert any("made with the current analysis" in t for t in texts())
    reanalyse(ws, lambda s, r: r.__setitem__("b", r["b"] + 0.5))
    warned = [t for s in _runs(ws) for k, t in s.items if k == "warn"]
    assert any("made with an earlier analysis: re-run" in t for t in warned)
    assert any("1 of 1 runs were made with an earlier analysis" in t for t in warned)
    assert provenance(ws)["analysis_fingerprint"] == ws.analysis_fingerprint()


def test_indicator_errors_are_medians_robust_to_minutes_long_ttcs():
    import pandas as pd

    from rl.evaluation.evaluate import FIELDS, _mae

    rows = pd.DataFrame(
        {
            "t_f_s": [2.0, 3.0, 4.0, 600.0],
            "t_f_ref": [2.5, 2.5, 2.5, 2.5],
            "t_nf_s": [None] * 4,
            "t_nf_ref": [1.0] * 4,
            "dv_nb_mps": [1.0] * 4,
            "dv_nb_ref": [0.0] * 4,
        }
    )
    out = _mae(rows)
    assert out["medae_t_f"] == 1.0 and out["mae_t_f"] > 100  # one slow leader sets the mean, not the median
    assert out["medae_t_nf"] is None and out["medae_dv_nb"] == 1.0
    assert "median" in FIELDS["medae_t_f"] and "[s]" in FIELDS["medae_t_f"]
