"""The workspace's format version (`laneprint.workspace_migrations`): stamped on creation, a newer one
refused in one line, an older or missing one migrated in one place."""

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from laneprint.errors import UserError
from laneprint.workspace import Workspace, analysis_fingerprint
from laneprint.workspace_migrations import FORMAT, FORMAT_FILE, NewerWorkspace, read_format

ROOT = Path(__file__).resolve().parents[2]


def test_a_new_workspace_is_stamped_and_an_empty_folder_is_left_alone(tmp_path):
    Workspace(tmp_path / "none")  # opening a folder that is not there writes nothing
    assert not (tmp_path / "none").exists()
    ws = Workspace(tmp_path / "ws").ensure()
    assert json.loads((ws.root / FORMAT_FILE).read_text()) == {"format": FORMAT}
    assert read_format(Workspace(ws.root).root) == FORMAT


def _unversioned(root: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A workspace as laneprint wrote it before the format was versioned: no stamp, an analysis whose
    reference lines have no direction and whose meta.json has no fingerprint."""
    for d in ("recordings", "rejected", "runs", "analysis"):
        (root / d).mkdir(parents=True)
    styles = pd.DataFrame({"driver_id": ["D01", "D02"], "style": ["Normal", "Aggressive"]})
    lines = pd.DataFrame(
        {"scope": ["style"], "name": ["Normal"], "kind": ["typical"], "indicator": ["t_f"], "a": [1.0], "b": [0.1]}
    )
    styles.to_parquet(root / "analysis" / "styles.parquet", index=False)
    lines.to_parquet(root / "analysis" / "reference_lines.parquet", index=False)
    (root / "analysis" / "meta.json").write_text(json.dumps({"config": {"k": 3}}))
    return styles, lines


def test_a_workspace_without_a_version_is_migrated_and_stamped(tmp_path):
    styles, lines = _unversioned(tmp_path / "old")
    before = analysis_fingerprint({"styles": styles, "reference_lines": lines})
    ws = Workspace(tmp_path / "old")
    assert read_format(ws.root) == FORMAT
    migrated = ws.read_table("analysis", "reference_lines")
    assert migrated["direction"].tolist() == ["both"]
    assert ws.read_meta("analysis") == {"config": {"k": 3}, "analysis_fingerprint": before}
    assert ws.analysis_fingerprint() == before  # what the runs made on it recorded
    Workspace(ws.root)  # opened again: nothing left to do
    assert read_format(ws.root) == FORMAT


def test_a_newer_workspace_is_refused(tmp_path):
    ws = Workspace(tmp_path / "ws").ensure()
    (ws.root / FORMAT_FILE).write_text(json.dumps({"format": FORMAT + 1}))
    with pytest.raises(NewerWorkspace, match="written by a newer laneprint"):
        Workspace(ws.root)
    (ws.root / FORMAT_FILE).write_text("{half")
    with pytest.raises(UserError, match="not a laneprint workspace stamp"):
        Workspace(ws.root)


@pytest.mark.slow
def test_the_command_line_refuses_a_newer_workspace_in_one_line(tmp_path):
    ws = Workspace(tmp_path / "ws").ensure()
    (ws.root / FORMAT_FILE).write_text(json.dumps({"format": FORMAT + 1}))
    for args in (["runs", "--json"], ["check"], ["ingest", str(ROOT / "sample_logs" / "D01_S60.mcap")]):
        proc = subprocess.run(
            [sys.executable, "-m", "laneprint.app.cli", *args, "--workspace", str(ws.root)],
            capture_output=True,
            text=True,
            cwd=ROOT,
        )
        assert proc.returncode == 1, (args, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "written by a newer laneprint" in lines[0], (args, proc.stderr)
        assert "Traceback" not in proc.stderr
