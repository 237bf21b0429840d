"""The repository's top level is the user's (DESIGN.md, Layout): nothing lands there by accident, such as a
workspace a test or a command wrote into the working directory."""

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: The user's layout, the two more packages DESIGN.md names, and the files every such repository keeps.
ALLOWED = {
    "pyproject.toml",
    "ingest",
    "indicators",
    "clustering",
    "rl",
    "dashboard",
    "sample_logs",
    "tests",
    "laneprint",
    "benchmarks",
    "docs",
    "README.md",
    "mkdocs.yml",
    ".ci",
    ".gitignore",
    ".git-blame-ignore-revs",
    ".pre-commit-config.yaml",
}


def test_the_top_level_holds_only_the_layout():
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    top = {line.split("/")[0] for line in tracked.splitlines() if line}
    assert top <= ALLOWED, f"not part of the layout: {sorted(top - ALLOWED)}"
