"""The documentation: reference pages generated from the app, and a site that builds --strict."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

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


@pytest.mark.slow
def test_site_builds_strict(tmp_path):
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent)) or shutil.which("mkdocs")
    assert mkdocs, "mkdocs is in the test extra"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    res = subprocess.run([mkdocs, "build", "--strict", "-q", "-d", str(tmp_path / "site")], cwd=ROOT,
                         capture_output=True, text=True, timeout=300, env=env)
    assert res.returncode == 0, res.stderr[-3000:]
    assert (tmp_path / "site" / "reference" / "cli" / "index.html").exists()


def test_a_benchmarks_result_file_of_any_layout_is_rendered(tmp_path, monkeypatch):
    """`benchmarks/results_file.write_result`'s files: the common keys in the head, figures listed, records as tables."""
    import importlib.util

    import laneprint.app.reference_docs as ref

    spec = importlib.util.spec_from_file_location("results_file", ROOT / "benchmarks" / "results_file.py")
    results_file = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(results_file)
    monkeypatch.setattr(results_file, "RESULTS", tmp_path)
    monkeypatch.setattr(ref, "RESULTS", tmp_path)
    import numpy as np

    results_file.write_result("speed", {"median_s": np.float64(1.23456), "n": np.int64(3), "by": {"csv": {"mb": 2.5}},
                                        "rows": [{"format": "csv", "what": "a|b"}, {"format": "mcap", "x": None}]},
                              ["--reps", "1"])
    page = ref.results_page()
    assert "## speed" in page and "--reps 1`" in page and results_file.machine() in page
    assert "- median_s: 1.235" in page and "- n: 3" in page and "- by.csv.mb: 2.5" in page
    assert "| format | what | x |" in page and "| csv | a\\|b |  |" in page and "| mcap |  | - |" in page
    with pytest.raises(ValueError, match="commit"):
        results_file.write_result("bad", {"commit": "x"})
