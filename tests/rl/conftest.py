"""A tiny trained run shared by the export and annotate tests (trained once per session)."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.workspace import Workspace
from tests.support.rl_workspaces import FAST_CLI as FAST, analysed_workspace


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory) -> tuple[Workspace, str]:
    """(workspace, run id): the hand-made Normal analysis and a 100-episode run trained on it."""
    root = tmp_path_factory.mktemp("trained")
    ws = analysed_workspace(root)
    res = CliRunner().invoke(
        app,
        [
            "train",
            "--style",
            "Normal",
            "--episodes",
            "100",
            "--run-id",
            "tiny",
            "--no-evaluate",
            "-w",
            str(root),
            *FAST,
        ],
    )
    assert res.exit_code == 0, res.output
    return ws, "tiny"
