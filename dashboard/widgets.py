"""Small Streamlit helpers shared by the pages."""

from __future__ import annotations

from laneprint.progress import ProgressFn


def progress_to(bar, default_text: str) -> ProgressFn:
    """A stage `progress(done, total, message)` callback drawing on an `st.progress` bar."""

    def update(done: int, total: int, message: str = "") -> None:
        bar.progress(min(1.0, done / max(total, 1)), text=message or default_text)

    return update
