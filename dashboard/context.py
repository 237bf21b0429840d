"""Where the dashboard finds its workspace and its tunables (environment, argv).

`laneprint dashboard` sets `LANEPRINT_WORKSPACE` and also passes `--workspace W`
after `--` to the Streamlit script; either is enough. Tests set the environment.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from laneprint.workspace import DEFAULT_WORKSPACE, Workspace

WORKSPACE_ENV = "LANEPRINT_WORKSPACE"
#: Default episode count in the Training form and of the Personalise page's base agents (tests and
#: demos set a small one).
EPISODES_ENV = "LANEPRINT_DASHBOARD_EPISODES"
#: Seconds between refreshes of the live training view.
POLL_ENV = "LANEPRINT_DASHBOARD_POLL_S"
#: Uploads larger than this are refused with a hint to use the command line [MB].
MAX_UPLOAD_ENV = "LANEPRINT_DASHBOARD_MAX_UPLOAD_MB"
DEFAULT_MAX_UPLOAD_MB = 1024


def _argv_workspace(argv: list[str]) -> str | None:
    for i, arg in enumerate(argv):
        if arg == "--workspace" and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("--workspace="):
            return arg.split("=", 1)[1]
    return None


def workspace_root() -> Path:
    """The workspace folder: `--workspace` after `--`, else $LANEPRINT_WORKSPACE, else ./workspace."""
    root = _argv_workspace(sys.argv[1:]) or os.environ.get(WORKSPACE_ENV) or str(DEFAULT_WORKSPACE)
    return Path(root).resolve()


def workspace() -> Workspace:
    """The dashboard's workspace, created if needed."""
    return Workspace(workspace_root()).ensure()


def env_int(name: str, default: int | None) -> int | None:
    """An integer from the environment, `default` when unset or not a number."""
    try:
        return int(os.environ[name])
    except (KeyError, ValueError):
        return default


def env_float(name: str, default: float) -> float:
    """A float from the environment, `default` when unset or not a number."""
    try:
        return float(os.environ[name])
    except (KeyError, ValueError):
        return default


def poll_seconds() -> float:
    """Refresh period of live views [s]."""
    return max(0.2, env_float(POLL_ENV, 1.0))


def max_upload_bytes() -> int:
    """Largest upload the Data page accepts [bytes]."""
    return int(env_float(MAX_UPLOAD_ENV, DEFAULT_MAX_UPLOAD_MB) * 1024 * 1024)
