"""Dashboard: the Streamlit app over the workspace (the only package importing streamlit)."""
