"""The application: the `laneprint` command line, the end-to-end run, the workspace check and the
reference pages' generator. It sits above every stage (ingest, indicators, clustering, rl,
dashboard) and is the only place that wires them together; nothing below imports it
(`tests/laneprint/test_layers.py`).
"""
