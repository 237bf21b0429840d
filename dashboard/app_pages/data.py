"""Data: upload logs, see what the ingest did with each, browse the recordings."""

from pathlib import Path

import streamlit as st

from dashboard import figures, loaders, uploads, views, widgets
from dashboard.context import max_upload_bytes, workspace
from dashboard.widgets import progress_to
from laneprint.errors import UserError


def ingest_uploads(ws, files, driver_id: str) -> None:
    """Save the uploads under the workspace, ingest the saved ones, keep the result for display."""
    from ingest.pipeline import ingest_paths

    updir = ws.root / "uploads"
    saved = [uploads.save_upload(f.name, f.size, f, updir, max_upload_bytes()) for f in files]
    paths = [s.path for s in saved if s.path is not None]
    report = None
    if paths:
        bar = st.progress(0.0, text="Ingesting...")
        try:
            report = ingest_paths(
                paths, ws, driver_id=driver_id.strip() or None, progress=progress_to(bar, "Ingesting...")
            ).to_dict()
        except UserError as exc:  # nothing could be done at all (e.g. a bad workspace): say why
            report = {"files": [{"source": str(p), "status": "rejected", "reason": str(exc)} for p in paths]}
        bar.empty()
        for entry in report["files"]:
            if entry.get("status") == "rejected":  # the refusal is recorded; its bytes need not stay
                uploads.discard(Path(entry["source"]), ws.root / "uploads")
    st.session_state["upload_results"] = views.upload_rows(saved, report)
    st.session_state["uploader_gen"] = st.session_state.get("uploader_gen", 0) + 1  # empties the uploader


def upload_section(ws) -> None:
    st.subheader("Upload logs")
    gen = st.session_state.get("uploader_gen", 0)
    files = st.file_uploader("MCAP or CSV logs (several at once)", accept_multiple_files=True, key=f"uploads_{gen}")
    driver_id = st.text_input("Driver id for files that do not name one", key="driver_id", placeholder="e.g. D11")
    if st.button(f"Ingest {len(files or [])} file(s)", key="ingest", disabled=not files, type="primary"):
        ingest_uploads(ws, files, driver_id)
        st.rerun()
    results = st.session_state.get("upload_results")
    if results is not None and len(results):
        counts = results["status"].value_counts().to_dict()
        summary = ", ".join(f"{n} {s}" for s, n in counts.items())
        if set(counts) <= {"ingested", "warning", "duplicate"}:
            st.success(f"Last upload: {summary}")
        else:
            st.warning(f"Last upload: {summary}. Reasons below.")
        st.dataframe(results, hide_index=True, width="stretch")
        reasons = views.reasons_markdown(results)
        if reasons:
            st.markdown(reasons)


def recordings_section(ws) -> None:
    root = str(ws.root)
    key = loaders.recordings_stamp(ws.root)
    recs = loaders.recordings(root, key)
    st.subheader(f"Recordings ({len(recs)})")
    if recs.empty:
        st.info(f"No recordings yet: upload logs above, or run `{views.cli_hint('ingest', ws.root, 'sample_logs/')}`.")
    else:
        st.dataframe(views.recordings_view(recs), hide_index=True, width="stretch")
    rej = loaders.rejected(root, key)
    if len(rej):
        if box := widgets.lazy_expander(f"Refused files ({len(rej)})", key="refused_open"):
            box.dataframe(rej[["source_name", "format", "reason", "rejected_at"]], hide_index=True, width="stretch")
    if recs.empty:
        return
    st.subheader("Recording viewer")
    labels = {views.recording_label(r): r["recording_id"] for _, r in recs.iterrows()}
    choice = st.selectbox("Recording", list(labels), key="recording")
    meta, ego, traffic = loaders.recording(root, labels[choice])
    st.caption(
        f"{meta['n_samples']} samples over {meta['duration_s']:.1f} s, {meta['n_presses']} button "
        f"presses, {meta['n_vehicles']} traffic vehicles; format {meta['format']}"
    )
    st.plotly_chart(figures.recording_timeline(ego, traffic), key="timeline")


def main() -> None:
    st.title("Data")
    widgets.page_help("data")
    ws = workspace()
    upload_section(ws)
    recordings_section(ws)
    widgets.next_step(ws, "data")


main()
