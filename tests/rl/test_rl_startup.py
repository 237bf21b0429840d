"""Every command's startup stays light: importing the command line must not import torch."""

import subprocess
import sys


def test_cli_import_does_not_import_torch():
    code = "import sys, laneprint.app.cli, rl.settings; print(sorted(m for m in sys.modules if m.split('.')[0] == 'torch'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"


def test_dqn_reexports_settings():
    from rl.learners.dqn import DQNSettings as A
    from rl.settings import DQNSettings as B

    assert A is B
