"""Figures for a paper (issue 48): SVG, PDF and PNG at 300 dpi in one print template, with the data as CSV."""

import io
import re
import shutil
import struct
import xml.etree.ElementTree as ET

import pandas as pd
import pytest
from streamlit.testing.v1 import AppTest

from dashboard_support import page_path
from laneprint import figure_export as fx
from laneprint.workspace import Workspace
from rl.plots import indicators_at_decisions


def _changes() -> pd.DataFrame:
    rows = []
    for i in range(30):
        for who in ("agent", "driver"):
            rows.append(
                {
                    "who": who,
                    "v_e_mps": 18 + i * 0.2,
                    "t_f_s": 3 + (i % 5) + (400 if i == 0 else 0),
                    "t_nf_s": 2 + i % 3,
                    "dv_nb_mps": -1 + i % 4,
                }
            )
    return pd.DataFrame(rows)


def pdf_is_well_formed(data: bytes) -> bool:
    """A PDF parsed as far as its structure: header, trailer, and `startxref` pointing at the cross-reference."""
    if not data.startswith(b"%PDF-") or b"%%EOF" not in data[-1024:]:
        return False
    offset = int(re.findall(rb"startxref\s+(\d+)", data)[-1])
    return data[offset : offset + 4] == b"xref" or re.match(rb"\d+ \d+ obj", data[offset : offset + 20]) is not None


def test_figure_data_as_csv_with_units():
    fig = indicators_at_decisions(_changes(), {"t_f": [0.1, 1.0], "t_nf": [0.1, 1.0], "dv_nb": [0.0, 0.0]})
    data = pd.read_csv(io.StringIO(fx.figure_csv(fig)))
    assert {"trace", "x", "y", "x_axis", "y_axis"} <= set(data.columns)
    assert "t_f [s]" in set(data["y_axis"]) and "ego speed v_e [m/s]" in set(data["x_axis"])
    assert data["value"].max() >= 400  # the true value of a point drawn at the axis edge


def test_print_template_fits_a_column():
    fig = indicators_at_decisions(_changes(), {"t_f": [0.1, 1.0], "t_nf": [0.1, 1.0], "dv_nb": [0.0, 0.0]})
    pub = fx.publication_figure(fig)
    assert pub.layout.width == fx.PAGE_PX and pub.layout.font.size == 9 and not pub.layout.title.text
    import plotly.graph_objects as go

    assert fx.publication_figure(go.Figure(go.Scatter(x=[1], y=[1]))).layout.width == fx.COLUMN_PX


@pytest.mark.slow
def test_svg_pdf_png_open_and_carry_units():
    if fx.kaleido_missing():
        pytest.skip(fx.kaleido_missing())
    if not shutil.which("chromium") and not shutil.which("google-chrome"):
        pytest.skip("no Chromium for kaleido")
    fig = indicators_at_decisions(_changes(), {"t_f": [0.1, 1.0], "t_nf": [0.1, 1.0], "dv_nb": [0.0, 0.0]})
    files = fx.figure_images(fig)
    svg = ET.fromstring(files["svg"])
    text = " ".join(t for t in svg.itertext())
    assert "t_f [s]" in text and "[m/s]" in text
    assert pdf_is_well_formed(files["pdf"])
    png = files["png"]
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    width = struct.unpack(">I", png[16:20])[0]
    assert width == round(fx.PAGE_PX * fx.PNG_DPI / 96)  # 7.16 in at 300 dpi


def test_results_page_offers_the_figure_files(sample_ws, tmp_path, monkeypatch):
    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    at = AppTest.from_file(page_path("results"), default_timeout=120).run()
    run_id = at.selectbox(key="result_run").value
    at.expander  # noqa: B018
    opener = next(e for e in at.expander if "Download this figure" in e.label and "fig10" in e.label)
    assert opener is not None
    monkeypatch.setattr(fx, "kaleido_missing", lambda: "SVG, PDF and PNG need kaleido")
    at.session_state[f"fig_dl_open_fig10_{run_id}"] = True
    at.run()
    assert not at.exception, [e.value for e in at.exception]
    assert any("need kaleido" in i.value for i in at.info)
