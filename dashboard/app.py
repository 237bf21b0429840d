"""The laneprint dashboard: `streamlit run dashboard/app.py -- --workspace W` (or `laneprint dashboard`)."""

from pathlib import Path

import streamlit as st

from dashboard.context import workspace_root

PAGES = Path(__file__).parent / "app_pages"  # not pages/: Streamlit would also serve those files alone

# an emoji favicon is drawn from a data: URL; a ':material/...' one is fetched from a fonts host (offline: none)
st.set_page_config(page_title="laneprint", page_icon="🛣️", layout="wide")
nav = st.navigation(
    [
        st.Page(PAGES / "data.py", title="Data", icon=":material/upload_file:", default=True),
        st.Page(PAGES / "drivers.py", title="Drivers", icon=":material/person:"),
        st.Page(PAGES / "styles.py", title="Styles", icon=":material/scatter_plot:"),
        st.Page(PAGES / "training.py", title="Training", icon=":material/model_training:"),
        st.Page(PAGES / "results.py", title="Results", icon=":material/leaderboard:"),
        st.Page(PAGES / "personalize.py", title="Personalise", icon=":material/person_add:"),
    ]
)
st.sidebar.caption(f"Workspace: `{workspace_root()}`")
nav.run()
