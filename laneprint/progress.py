"""Progress reporting shared by the command line and the dashboard.

Stage functions take an optional `progress` callback and call it as
`progress(done, total, message)`. The command line passes a Rich progress bar,
the dashboard an `st.progress` updater, tests nothing.
"""

from typing import Callable, Optional

ProgressFn = Callable[[int, int, str], None]


def report(progress: Optional[ProgressFn], done: int, total: int, message: str = "") -> None:
    """Call `progress` if one was given."""
    if progress is not None:
        progress(done, total, message)
