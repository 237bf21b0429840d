"""The human summary shows reasons and names verbatim (Rich must not eat '[...]')."""

from typer.testing import CliRunner

from laneprint.app.cli import app


def test_reason_with_brackets_is_printed_whole(tmp_path):
    log = tmp_path / "[lab] kph.csv"
    log.write_text("t,driver_id,ego_x,ego_v,ego_lane,lc_button\n0,D1,0,80,0,0\n1,D1,80,80,0,0\n2,D1,160,80,0,1\n")
    result = CliRunner().invoke(app, ["ingest", str(log), "-w", str(tmp_path / "ws")], terminal_width=200)
    assert result.exit_code == 0, result.output
    assert "[units]" in result.output
    assert "[lab] kph.csv" in result.output
