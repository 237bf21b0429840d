"""`laneprint report`'s figures as SVG beside the HTML (the `report` extra: kaleido with a local Chromium)."""

import builtins
import re

import plotly.graph_objects as go
import pandas as pd
import pytest

from dashboard.report import Section, write_assets


def sections() -> list[Section]:
    fig = go.Figure(go.Scatter(x=[1, 2, 3], y=[2, 1, 3], name="presses"))
    fig.update_layout(title="t_f against ego speed")
    return [
        Section(
            "Study",
            [
                ("table", ("fits", pd.DataFrame({"A": [0.1]}))),
                ("figure", ("driver D01 t_f", fig)),
                ("figure", ("styles", go.Figure(go.Bar(x=["a"], y=[1])))),
            ],
        )
    ]


@pytest.mark.slow
def test_svg_of_every_figure_with_kaleido(tmp_path):
    pytest.importorskip("kaleido", reason="the report extra: pip install -e '.[report]'")
    written = write_assets(sections(), tmp_path)
    assert written["svg_note"] == "" and written["svg"] == ["driver_D01_t_f.svg", "styles.svg"], written
    text = (tmp_path / "driver_D01_t_f.svg").read_text()
    assert text.startswith("<svg") and "t_f against ego speed" in text
    for name in written["svg"]:
        # nothing but the SVG namespaces points outside: the files open offline
        urls = set(re.findall(r"https?://[^\"' )]+", (tmp_path / name).read_text()))
        assert urls <= {"http://www.w3.org/2000/svg", "http://www.w3.org/1999/xlink"}, urls
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".csv", ".json", ".json", ".svg", ".svg"]


def test_without_kaleido_the_json_stays_and_the_summary_says_why(tmp_path, monkeypatch):
    real = builtins.__import__

    def no_kaleido(name, *args, **kwargs):
        if name == "kaleido":
            raise ImportError("no kaleido")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_kaleido)
    written = write_assets(sections(), tmp_path)
    assert written["svg"] == [] and "pip install -e '.[report]'" in written["svg_note"]
    assert written["figures"] == ["driver_D01_t_f.json", "styles.json"]
    assert not list(tmp_path.glob("*.svg"))


def _svg_threads():
    import threading

    return [t for t in threading.enumerate() if t.name == "laneprint-svg" and t.is_alive()]


def _fake_build(seen):
    return lambda ws: (
        seen.append(bool(_svg_threads()))
        or (sections(), {"workspace": "w", "generated_at": "now", "data_fingerprint": "f"})
    )


@pytest.mark.slow
def test_report_starts_chromium_before_building_and_stops_it(tmp_path, monkeypatch):
    """kaleido's Chromium starts before the figures are built (its 10-15 s overlap them) and is stopped after."""
    import time

    pytest.importorskip("kaleido", reason="the report extra: pip install -e '.[report]'")
    import dashboard.report as report

    seen = []
    monkeypatch.setattr(report, "build_report", _fake_build(seen))
    res = report.write_report(type("W", (), {"root": tmp_path})(), tmp_path / "r.html")
    assert seen == [True] and sorted(res["written"]["svg"]) == ["driver_D01_t_f.svg", "styles.svg"]
    assert (tmp_path / "r_files" / "styles.svg").read_text().startswith("<svg")
    deadline = time.monotonic() + 30
    while _svg_threads() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _svg_threads()


def test_a_chromium_that_does_not_start_is_said_not_waited_for(tmp_path, monkeypatch):
    kaleido = pytest.importorskip("kaleido", reason="the report extra: pip install -e '.[report]'")
    import dashboard.report as report

    class NoBrowser:
        def __init__(self, *args, **kwargs):
            pass

        async def __aenter__(self):
            raise RuntimeError("no Chrome here")

        async def __aexit__(self, *exc):
            return False

    monkeypatch.setattr(kaleido, "Kaleido", NoBrowser)
    monkeypatch.setattr(report, "build_report", _fake_build([]))
    res = report.write_report(type("W", (), {"root": tmp_path})(), tmp_path / "r.html")
    assert res["written"]["svg"] == [] and "no Chrome here" in res["written"]["svg_note"]
    assert (tmp_path / "r_files" / "styles.json").exists() and not list((tmp_path / "r_files").glob("*.svg"))


def test_table_html_reads_as_pandas_writes_it():
    from dashboard.report import _table_html

    def cells(text):
        return re.findall(r"<t([hd])(?:\s[^>]*)?>(.*?)</t\1>", text, flags=re.S)

    frame = pd.DataFrame(
        {
            "driver": ["D01", "<b>"],
            "A": [0.123456, float("nan")],
            "n": [3, 4],
            "flag": [None, "R² < 0.1"],
            "ok": [True, False],
        }
    )
    theirs = frame.to_html(index=False, na_rep="", float_format=lambda x: f"{x:.4g}", border=0, escape=True)
    assert cells(_table_html(frame)) == cells(theirs)
    assert ("d", "&lt;b&gt;") in cells(_table_html(frame)) and ("d", "0.1235") in cells(_table_html(frame))


@pytest.mark.slow
def test_a_fleet_is_one_section_with_one_figure(sample_ws, tmp_path):
    """A fleet's agents are a table and one figure in the report, not four figures each."""
    import shutil

    from dashboard_support import write_fake_fleet
    from dashboard.report import build_report
    from laneprint.workspace import Workspace

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    runs = write_fake_fleet(ws, "f1", ["D01", "D02", "D03"], seeds=(0, 1))
    sections, _ = build_report(ws)
    titles = [s.title for s in sections]
    assert "Fleet f1" in titles and not any(t == f"Run {r}" for r in runs for t in titles)
    fleet = sections[titles.index("Fleet f1")]
    assert [k for k, _ in fleet.items].count("figure") == 1
    table = next(v[1] for k, v in fleet.items if k == "table")
    assert len(table) == 6
