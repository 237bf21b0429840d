"""Is a process recorded in a workspace file (a run's or a fleet's `pid`) still at work?"""

from __future__ import annotations

import os
from pathlib import Path


def laneprint_process_alive(pid: int | None) -> bool:
    """True if `pid` is a live laneprint process: not gone, not a zombie, not a pid reused by another program."""
    if not pid:
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return False  # another user's process: not a run of ours
    proc_dir = Path(f"/proc/{int(pid)}")
    if not proc_dir.is_dir():  # no /proc (not Linux): trust kill(0)
        return True
    try:
        state = (proc_dir / "stat").read_text().split(") ", 1)[1][0]
        cmdline = (proc_dir / "cmdline").read_bytes()
    except (OSError, IndexError):
        return False
    # a zombie still answers kill(0); a pid reused by another program must not be signalled
    return state != "Z" and b"laneprint" in cmdline
