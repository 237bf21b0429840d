"""`laneprint run`: the stages chained through the real command line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app

SAMPLE = Path(__file__).resolve().parents[2] / "sample_logs"


@pytest.mark.slow
def test_run_ingests_and_analyzes_sample_logs(tmp_path):
    logs = [str(SAMPLE / "D01_S60.mcap"), str(SAMPLE / "D02_S80.csv.gz")]
    result = CliRunner().invoke(app, ["run", *logs, "--no-train", "-w", str(tmp_path / "ws"), "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    assert out["ingest"]["counts"]["ingested"] == 2
    assert set(out["analysis"]["drivers"]) == {"D01", "D02"}
    assert out["runs"] == []
    assert (tmp_path / "ws" / "analysis" / "decisions.parquet").exists()


def test_run_with_only_bad_files_is_one_line_error(tmp_path):
    bad = tmp_path / "broken.mcap"
    bad.write_bytes(b"not an mcap at all")
    result = CliRunner().invoke(app, ["run", str(bad), "-w", str(tmp_path / "ws")])
    assert result.exit_code == 1
    assert "Traceback" not in result.output
    assert "no recordings could be stored" in result.output


def test_control_characters_from_the_data_do_not_reach_the_terminal(tmp_path):
    """A file name carrying an escape sequence (clear screen, window title) prints as its escapes."""
    import shutil

    from typer.testing import CliRunner

    from laneprint.app.cli import app

    src = next(p for p in (Path(__file__).resolve().parents[2] / "sample_logs").rglob("*.csv*"))
    logs = tmp_path / "logs"
    logs.mkdir()
    shutil.copy(src, logs / ("evil\x1b[2J\x1b]0;owned\x07" + src.name))
    res = CliRunner().invoke(app, ["ingest", str(logs), "-w", str(tmp_path / "ws")], terminal_width=300)
    assert res.exit_code == 0, res.output
    assert "\x1b" not in res.output and "\x07" not in res.output
    assert "evil\\x1b[2J" in res.output
