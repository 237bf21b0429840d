"""Figures for a paper: any of the stages' Plotly figures as SVG, PDF and PNG (300 dpi) in one
template and a journal's column width, and the data behind it as CSV. Pure functions (figure in,
bytes or text out); the dashboard's download buttons call them.

The images are drawn by kaleido (`pip install -e '.[report]'`) in a local Chrome/Chromium,
offline (MathJax off, nothing fetched); `kaleido_missing` says what is missing instead.
"""

from __future__ import annotations

import copy
import io

import numpy as np
import pandas as pd
import plotly.graph_objects as go

from laneprint.errors import UserError

#: Widths [px at 96 px per inch] of a journal's single column (3.5 in) and full page width (7.16 in).
COLUMN_PX = 336
PAGE_PX = 688
#: PNG resolution [dots per inch]; Plotly lays out at 96 px per inch.
PNG_DPI = 300
FORMATS = ("svg", "pdf", "png")
FONT = {"family": "Arial, Helvetica, sans-serif", "size": 9, "color": "black"}


def kaleido_missing() -> str | None:
    """Why figures cannot be drawn as SVG/PDF/PNG here (kaleido missing), else None; found without importing it."""
    from importlib.util import find_spec

    if find_spec("kaleido") is None:
        return "SVG, PDF and PNG need kaleido (and a Chrome or Chromium on this machine): pip install -e '.[report]'"
    return None


def _subplot_columns(fig: go.Figure) -> int:
    layout = fig.to_plotly_json().get("layout", {})
    xs = [k for k in layout if k.startswith("xaxis")]
    return max(1, len(xs))


def publication_figure(fig: go.Figure, width_px: int | None = None, height_px: int | None = None) -> go.Figure:
    """A copy of `fig` in one template for print: white background, 9 pt Arial, thin black axes with
    ticks outside, legend below; one column wide (`COLUMN_PX`), or the page's width (`PAGE_PX`) for a
    figure of several panels. Without its title (a paper's caption says it, and a screen title is wider
    than a column); the axis titles carry the units."""
    out = go.Figure(copy.deepcopy(fig.to_plotly_json()))
    panels = _subplot_columns(out)
    width = width_px or (PAGE_PX if panels > 1 else COLUMN_PX)
    height = height_px or (int(width * 0.42) if panels > 1 else int(width * 0.8))
    out.update_layout(
        template="simple_white",
        font=FONT,
        width=width,
        height=height,
        margin={"l": 48, "r": 12, "t": 24, "b": 44},
        paper_bgcolor="white",
        plot_bgcolor="white",
        legend={"orientation": "h", "yanchor": "top", "y": -0.22, "x": 0, "font": {"size": 8}},
        title={"text": ""},
    )
    out.update_xaxes(
        showline=True, linecolor="black", linewidth=0.8, ticks="outside", mirror=False, title_font={"size": 9}
    )
    out.update_yaxes(
        showline=True, linecolor="black", linewidth=0.8, ticks="outside", mirror=False, title_font={"size": 9}
    )
    return out


def figure_images(
    fig: go.Figure, formats: tuple[str, ...] = FORMATS, width_px: int | None = None, height_px: int | None = None
) -> dict[str, bytes]:
    """`fig` in the print template as bytes per format ('svg', 'pdf', 'png' at `PNG_DPI`), drawn in one
    kaleido session. A `UserError` saying why when kaleido or a browser is missing or the drawing fails."""
    if (why := kaleido_missing()) is not None:
        raise UserError(why)
    import plotly.io as pio

    pub = publication_figure(fig, width_px, height_px)
    out = {}
    try:
        for fmt in formats:
            scale = PNG_DPI / 96 if fmt == "png" else 1
            out[fmt] = pio.to_image(pub, format=fmt, width=pub.layout.width, height=pub.layout.height, scale=scale)
    except Exception as exc:  # noqa: BLE001 - kaleido finds no Chrome/Chromium, or it fails to start
        first = (str(exc).splitlines() or [""])[0][:300]
        raise UserError(
            f"the figure could not be drawn as {fmt.upper()}: {type(exc).__name__}: {first} "
            "(kaleido needs Chrome or Chromium: `kaleido_get_chrome`, or apt-get install chromium)"
        ) from None
    return out


def _axis_title(fig: go.Figure, axis: str) -> str:
    try:
        return str(fig.layout[axis].title.text or "")
    except (KeyError, ValueError, AttributeError):
        return ""


def figure_data(fig: go.Figure) -> pd.DataFrame:
    """The data behind a figure, one row per point: trace, x, y, the true value of a point drawn at an
    axis edge (`value`, from the hover data), with the axes' titles (their units) beside them."""
    frames = []
    for i, tr in enumerate(fig.data):
        x, y = getattr(tr, "x", None), getattr(tr, "y", None)
        values = x if x is not None else y
        if values is None:
            continue
        n = len(values)
        xa = "xaxis" + ((getattr(tr, "xaxis", None) or "x")[1:])
        ya = "yaxis" + ((getattr(tr, "yaxis", None) or "y")[1:])
        df = pd.DataFrame(
            {
                "trace": tr.name or f"trace {i}",
                "type": tr.type,
                "x_axis": _axis_title(fig, xa),
                "x": list(x) if x is not None else [None] * n,
                "y_axis": _axis_title(fig, ya),
                "y": list(y) if y is not None else [None] * n,
            }
        )
        custom = getattr(tr, "customdata", None)
        if custom is not None:
            arr = np.asarray(custom, dtype=object)
            if arr.ndim == 1 and len(arr) == n:
                df["value"] = arr
        frames.append(df)
    return (
        pd.concat(frames, ignore_index=True)
        if frames
        else pd.DataFrame(columns=["trace", "type", "x_axis", "x", "y_axis", "y"])
    )


def figure_csv(fig: go.Figure) -> str:
    """`figure_data` as CSV text."""
    buf = io.StringIO()
    figure_data(fig).to_csv(buf, index=False)
    return buf.getvalue()
