"""Small Streamlit helpers shared by the pages: a stage progress callback, and the
cross-validation launcher and its live progress (Training and Results pages)."""

from __future__ import annotations

from typing import Callable

import streamlit as st

from dashboard import docs_site, jobs, views
from dashboard.context import poll_seconds
from laneprint.progress import ProgressFn


#: Streamlit draws the elements of a rerunning script or fragment faded until they are sent again; a live
#: view that reruns every second then looks greyed out half the time. This style keeps them drawn as they are.
NO_FADE_CSS = (
    "<style>[data-stale='true'], .stale-element, [data-testid='stElementContainer'][data-stale] "
    "{opacity: 1 !important; transition: none !important;}</style>"
)


def page_help(key: str) -> None:
    """A caption under a page's title linking to its page of the documentation site (none while no site is
    built: `dashboard.docs_site`)."""
    if link := docs_site.more(key):
        st.caption(link)


def lazy_expander(label: str, key: str):
    """An expander whose content runs only once it is open: returns its container when open, else None.

    A closed `st.expander` still runs and sends its charts and tables; with many drivers
    that made pages slow to draw. Opening it costs one rerun.
    """
    box = st.expander(label, key=key, on_change="rerun")
    return box if box.open else None


def progress_to(bar, default_text: str, translate: Callable[[int, int, str], str] | None = None) -> ProgressFn:
    """A stage `progress(done, total, message)` callback drawing on an `st.progress` bar; `translate`
    turns the stage's message into the text shown (`views.progress_text`)."""

    def update(done: int, total: int, message: str = "") -> None:
        text = translate(done, total, message) if translate else message
        bar.progress(min(1.0, done / max(total, 1)), text=text or default_text)

    return update


def crossval_launcher(ws, run_id: str, run_episodes: int | None) -> str | None:
    """Folds, episodes and resamples, and a button that starts `laneprint crossval --run RUN_ID`
    in the background; returns the new job id (the page reruns to show its progress)."""
    busy = jobs.active_crossvals(ws, run_id)
    c1, c2, c3, c4 = st.columns(4)
    folds = c1.number_input("Folds K", min_value=2, max_value=20, value=4, step=1, key=f"cv_folds_{run_id}")
    split = c2.selectbox(
        "Split",
        ["session", "section"],
        key=f"cv_split_{run_id}",
        help=docs_site.with_more(
            "'session': each driver's sessions dealt to the folds; 'section': whole speed sections held out", "heldout"
        ),
    )
    episodes = c3.number_input(
        "Episodes per fold's agent",
        min_value=1,
        max_value=100_000,
        step=100,
        value=int(run_episodes or 10_000),
        key=f"cv_episodes_{run_id}",
    )
    boot = c4.number_input(
        "Bootstrap resamples", min_value=10, max_value=100_000, value=1000, step=100, key=f"cv_bootstrap_{run_id}"
    )
    req = jobs.CrossvalRequest(
        run_id,
        int(folds),
        str(split),
        0,
        None if run_episodes and int(episodes) == int(run_episodes) else int(episodes),
        int(boot),
    )
    st.caption(
        f"Trains one agent per fold (about {int(folds)} times this run's training), fits the imitation "
        f"classifier per fold and scores all three on the sessions each never saw: "
        f"`{views.command_text(jobs.crossval_command(req, ws.root))}`"
    )
    clicked = st.button(
        "Cross-validate", key=f"cv_start_{run_id}", disabled=bool(busy), help="one at a time per run" if busy else None
    )
    if not clicked:
        return None
    job_id = jobs.launch_crossval(ws, req)
    st.session_state.setdefault("crossval_launched", []).append(job_id)
    st.rerun()  # redraw with the new job under way (and polling on)
    return job_id


def crossval_panel(ws, job_id: str, status: dict) -> None:
    """Progress of one cross-validation job, with Cancel while it works and the log when it failed."""
    state = status.get("state")
    st.progress(
        float(status.get("fraction") or 0.0),
        text=f"cross-validation of {status.get('run_id')}: {state} — {status.get('message', '')}",
    )
    if state in jobs.ACTIVE_STATES:
        if st.button("Cancel", key=f"cv_cancel_{job_id}"):
            jobs.cancel_crossval(ws, job_id)
    elif state == "done":
        st.caption(f"Stored as `crossval/{status.get('crossval_id')}`: the held-out figures are on the Results page.")
    elif status.get("log"):
        st.code(status["log"], language=None)


def live_panels(active: list[str], status_of: Callable[[str], dict], panel: Callable[[str, dict], None]) -> None:
    """A panel per working job, refreshed every poll until one ends; then the whole page reruns,
    so a finished result shows at once."""

    @st.fragment(run_every=poll_seconds() if active else None)
    def panels() -> None:
        still = []
        for job_id in active:
            status = status_of(job_id)
            panel(job_id, status)
            if status.get("state") in jobs.ACTIVE_STATES:
                still.append(job_id)
        if len(still) < len(active):
            st.rerun()

    panels()


def live_crossvals(ws, run_id: str | None = None) -> list[str]:
    """Every working cross-validation (of `run_id`, when given), refreshed until it ends. Call once
    per page. Returns the jobs shown."""
    active = jobs.active_crossvals(ws, run_id)
    live_panels(active, lambda j: jobs.crossval_status(ws, j), lambda j, status: crossval_panel(ws, j, status))
    return active


def smoothing_slider(key: str = "smoothing") -> float:
    """The training curves' smoothing weight (TensorBoard's slider: 0 = raw, 0.99 = very smooth)."""
    return float(
        st.slider(
            "Curve smoothing",
            min_value=0.0,
            max_value=0.99,
            value=0.95,
            step=0.01,
            key=key,
            help="Exponential moving average with debiasing, as TensorBoard draws it; the raw "
            "per-episode values stay faint behind the smoothed line.",
        )
    )


def figure_downloads(fig, name: str, key: str) -> None:
    """Under a figure: its data as CSV at once, and SVG, PDF and PNG (300 dpi) in the print template
    (`laneprint.figure_export`), drawn when asked (kaleido starts a browser: seconds). A drawing that
    fails, or kaleido missing, says why here on the page."""
    from laneprint.errors import UserError
    from laneprint import figure_export as fx

    box = lazy_expander(f"Download this figure ({name}): SVG, PDF, PNG 300 dpi, data as CSV", key=f"fig_dl_open_{key}")
    if box is None:
        return
    with box:
        made_key = f"fig_dl_{key}"
        cols = st.columns(4)
        cols[0].download_button(
            "Data (CSV)",
            data=fx.figure_csv(fig),
            file_name=f"{name}.csv",
            mime="text/csv",
            key=f"fig_csv_{key}",
            on_click="ignore",
        )
        if (why := fx.kaleido_missing()) is not None:
            cols[1].info(why)
            return
        made = st.session_state.get(made_key)
        if made is None:
            if cols[1].button(
                "Make SVG, PDF and PNG",
                key=f"fig_make_{key}",
                help="one journal column wide (page wide for several panels), 9 pt, white",
            ):
                with st.spinner("drawing with kaleido (a headless Chromium)..."):
                    try:
                        st.session_state[made_key] = fx.figure_images(fig)
                    except UserError as exc:
                        st.session_state[made_key] = {"error": str(exc)}
                st.rerun()
            return
        if "error" in made:
            st.error(f"No SVG/PDF/PNG: {made['error']}")
            if cols[1].button("Try again", key=f"fig_retry_{key}"):
                del st.session_state[made_key]
                st.rerun()
            return
        mimes = {"svg": "image/svg+xml", "pdf": "application/pdf", "png": "image/png"}
        for col, fmt in zip(cols[1:], fx.FORMATS):
            col.download_button(
                fmt.upper() + (" (300 dpi)" if fmt == "png" else ""),
                data=made[fmt],
                file_name=f"{name}.{fmt}",
                mime=mimes[fmt],
                key=f"fig_{fmt}_{key}",
                on_click="ignore",
            )


def next_step(ws, page: str) -> None:
    """At the foot of a page: what to do next, once the page's own step is done (`views.next_step`)."""
    from dashboard import loaders

    has_recordings = not loaders.recordings(str(ws.root), loaders.recordings_stamp(ws.root)).empty
    has_analysis = "styles" in loaders.analysis(str(ws.root), loaders.analysis_stamp(ws.root))
    line = views.next_step(page, has_recordings, has_analysis)
    if line:
        st.divider()
        st.markdown(line)
