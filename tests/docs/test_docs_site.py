"""The documentation: reference pages generated from the app, and a site that builds --strict."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

from laneprint.app.reference_docs import pages

ROOT = Path(__file__).resolve().parents[2]


def test_reference_pages_match_the_app():
    """Regenerate with `python -m laneprint.app.reference_docs` when a command or setting changes."""
    for name, text in pages().items():
        committed = (ROOT / "docs" / "reference" / name).read_text(encoding="utf-8")
        assert committed == text, f"docs/reference/{name} is out of date: python -m laneprint.app.reference_docs"


def test_readme_and_reference_carry_no_issue_numbers():
    for path in [ROOT / "README.md", *(ROOT / "docs" / "reference").glob("*.md")]:
        text = path.read_text(encoding="utf-8")
        assert not re.search(r"\bissue \d+", text, re.I), path
    assert len((ROOT / "README.md").read_bytes()) <= 15_000


def test_site_builds_strict(tmp_path):
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent)) or shutil.which("mkdocs")
    assert mkdocs, "mkdocs is in the test extra"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    res = subprocess.run([mkdocs, "build", "--strict", "-q", "-d", str(tmp_path / "site")], cwd=ROOT,
                         capture_output=True, text=True, timeout=300, env=env)
    assert res.returncode == 0, res.stderr[-3000:]
    assert (tmp_path / "site" / "reference" / "cli" / "index.html").exists()
