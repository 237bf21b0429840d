"""Locks that die with their process: `fcntl.flock` on a file or a folder.

The kernel releases a flock when the last descriptor of its holder closes, so a
process killed with SIGKILL leaves no lock behind: nothing here ever expires by
time, and "is someone still working on this?" is answered by trying the lock
(`is_locked`), not by reading a pid or a timestamp. Locks are per open file
description, so two locks of one path in the same process exclude each other too.

Used for: a run being trained (`runs/<id>/run.lock`), a session being ingested,
a stage folder being replaced, and every temporary file or folder of an atomic
write (its writer holds it until it is renamed into place or removed).
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path


class FileLock:
    """An exclusive flock on `path` (a file, created if missing, or an existing folder)."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self, blocking: bool = True) -> bool:
        """Take the lock; with `blocking=False`, False at once when another holder has it."""
        if self._fd is not None:
            return True
        if self.path.is_dir():
            fd = os.open(self.path, os.O_RDONLY)
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
        except BlockingIOError:
            os.close(fd)
            return False
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        return True

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None

    def __enter__(self) -> "FileLock":
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def lock_fd(fd: int) -> None:
    """Lock an open descriptor (e.g. a fresh temporary file) exclusively, without waiting."""
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def is_locked(path: Path | str) -> bool:
    """True while some process (this one included, through another descriptor) holds `path`'s lock.

    A missing path is not locked. Never creates anything.
    """
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False
