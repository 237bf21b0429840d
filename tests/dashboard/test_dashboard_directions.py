"""Direction on the Drivers and Styles pages (issue 19 item 1): presses marked by the side of their
target lane, each side's line beside the pooled one, the per-direction fit table, reference lines per
direction; an analysis made before directions still draws."""

import numpy as np
import pandas as pd
import pytest

from clustering.plots import line_directions, reference_lines
from dashboard import views
from indicators.directions import fits_by_direction
from indicators.plots import DIRECTION_STYLE, indicator_vs_speed
from indicators.settings import AnalysisSettings
from indicators.stats import fit_lines


def two_sided(n_left: int = 30, n_right: int = 3) -> pd.DataFrame:
    """One driver's presses: `n_left` overtaking (t_f = 0.2 v + 1), `n_right` returning (t_f = 0.3 v - 1)."""
    from tests.support.synthetic_decisions import make_decision_table

    dec, _ = make_decision_table(1, n_left + n_right, seed=3, keep_per_press=0)
    press = dec.index[dec["label"] == "change"]
    right = press[n_left:]
    dec.loc[right, ["ego_lane", "target_lane"]] = [1, 0]
    v = dec.loc[press, "ego_v_mps"]
    rng = np.random.default_rng(0)
    dec.loc[press, "t_f_s"] = np.where(dec.loc[press].index.isin(right), 0.3 * v - 1, 0.2 * v + 1) + rng.normal(
        0, 0.05, len(press)
    )
    return dec


def test_presses_marked_by_direction_with_side_lines():
    dec = two_sided(30, 20)
    side = fits_by_direction(dec, AnalysisSettings(), ["D0000"], ("t_f",))
    fig = indicator_vs_speed(dec, fit_lines(dec), "D0000", "t_f", fits_by_direction=side)
    by_name = {t.name: t for t in fig.data}
    left, right = by_name["used, to the left (30)"], by_name["used, to the right (20)"]
    assert left.marker.symbol != right.marker.symbol and left.marker.color != right.marker.color
    assert "OLS line" in by_name  # the pooled line stays
    for name, (a, b) in (("left", (0.2, 1.0)), ("right", (0.3, -1.0))):
        line = by_name[f"line to the {name}"]
        assert line.line.dash == "dash" and line.line.color == DIRECTION_STYLE[name][0]
        x = np.asarray(line.x)
        assert np.asarray(line.y) == pytest.approx(a * x + b, abs=0.1)  # each side's own line
        assert "R²" in line.hovertemplate


def test_a_side_without_enough_presses_draws_no_line_and_says_why():
    dec = two_sided(30, 3)
    side = fits_by_direction(dec, AnalysisSettings(), ["D0000"], ("t_f",))
    fig = indicator_vs_speed(dec, fit_lines(dec), "D0000", "t_f", fits_by_direction=side)
    names = [t.name for t in fig.data]
    assert "line to the left" in names and not any(n.startswith("line to the right") for n in names)
    assert "used, to the right (3)" in names  # its presses are still drawn
    table = views.direction_fit_summary(side)
    assert table["direction"].tolist() == ["left", "right"]
    assert table.loc[0, "reason"] == "" and table.loc[0, "n"] == 30
    assert table.loc[1, "reason"].endswith("the pooled line stands") and np.isnan(table.loc[1, "A"])
    assert {"n", "A", "b", "r2", "flag", "reason"} <= set(table.columns)


def test_heavy_tails_still_set_by_the_bulk_with_directions():
    from laneprint.plotting import range_set_by_few

    dec = two_sided(40, 20)
    press = dec.index[dec["label"] == "change"]
    dec.loc[press[[0, 45]], "t_f_s"] = [2500.0, 20000.0]
    side = fits_by_direction(dec, AnalysisSettings(), ["D0000"], ("t_f",))
    fig = indicator_vs_speed(dec, fit_lines(dec), "D0000", "t_f", fits_by_direction=side)
    assert fig.layout.yaxis.range[1] < 100
    assert not range_set_by_few(dec.loc[press, "t_f_s"], fig.layout.yaxis.range)
    off = next(t for t in fig.data if t.name == "used, off the axis (2)")
    assert list(off.marker.color) == [DIRECTION_STYLE["left"][0], DIRECTION_STYLE["right"][0]]


def test_an_analysis_without_lanes_or_side_fits_draws_as_before():
    dec = two_sided(30, 0).drop(columns=["target_lane", "ego_lane"])
    fig = indicator_vs_speed(dec, fit_lines(dec), "D0000", "t_f", fits_by_direction=None)
    assert [t.name for t in fig.data if t.mode == "markers"] == ["used"]
    assert not any(t.name.startswith("line to the") for t in fig.data)
    assert views.direction_fit_summary(None).empty
    assert views.presses_by_direction_text({"summary": {}}) == ""


def test_reference_lines_per_direction():
    base = {"scope": "style", "indicator": "t_f", "A": 0.1, "b": 1.0, "source": "s", "fit": "ols", "flag": ""}
    refs = pd.DataFrame(
        [
            {**base, "name": "Normal", "kind": "typical", "direction": "both"},
            {**base, "name": "Normal", "kind": "typical", "direction": "left", "A": 0.3},
            {**base, "name": "Normal", "kind": "paper", "direction": "both", "fit": "paper"},
        ]
    )
    assert line_directions(refs) == ["both", "left"]
    assert line_directions(refs.drop(columns="direction")) == ["both"]
    pooled = reference_lines(refs, indicators=["t_f"])
    assert sorted(t.name for t in pooled.data) == ["Normal paper", "Normal typical"]  # no side line mixed in
    left = reference_lines(refs, indicators=["t_f"], direction="left")
    by_name = {t.name: t for t in left.data}
    assert set(by_name) == {"Normal typical, to the left", "Normal typical, every press", "Normal paper"}
    x = np.asarray(by_name["Normal typical, to the left"].x)
    assert np.asarray(by_name["Normal typical, to the left"].y) == pytest.approx(0.3 * x + 1.0)
    assert by_name["Normal typical, every press"].line.dash == "dash"


def test_presses_by_direction_text():
    meta = {"summary": {"presses_by_direction": {"left": 250, "right": 1}}}
    assert views.presses_by_direction_text(meta) == "250 presses to the left (overtaking), 1 to the right (returning)"


# --- the pages (AppTest) ----------------------------------------------------------------------


def _run(name: str):
    from streamlit.testing.v1 import AppTest

    from dashboard_support import page_path

    at = AppTest.from_file(page_path(name), default_timeout=60).run()
    assert not at.exception, [e.value for e in at.exception]
    return at


def _trace_names(at) -> set[str]:
    import json

    return {t.get("name") or "" for el in at.get("plotly_chart") for t in json.loads(el.proto.spec)["data"]}


def test_pages_show_directions(use_sample):
    at = _run("drivers")
    assert "to the left" in at.markdown[0].value and "to the right" in at.markdown[0].value
    table = next(d.value for d in at.dataframe if "direction" in d.value.columns)
    assert set(table["direction"]) == {"left", "right"} and "n" in table and "reason" in table
    names = _trace_names(at)
    assert {"OLS line"} <= names and any(n.startswith("used, to the left") for n in names)
    assert any(n.startswith("line to the ") for n in names)  # D01's sides have lines
    at = _run("styles")
    assert any("to the left (overtaking)" in m.value for m in at.markdown)
    radio = at.radio(key="ref_direction")
    assert radio.options[0] == "every press"
    radio.set_value("left").run()
    assert not at.exception and any(n.endswith("typical, to the left") for n in _trace_names(at))


def test_an_older_analysis_without_directions_still_draws(sample_ws, tmp_path, monkeypatch):
    import shutil

    from laneprint.workspace import Workspace

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path / "ws"))
    (ws.root / "analysis" / "fits_by_direction.parquet").unlink()
    refs = ws.read_table("analysis", "reference_lines")
    refs[refs["direction"] == "both"].drop(columns=["direction"]).to_parquet(
        ws.root / "analysis" / "reference_lines.parquet"
    )
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    at = _run("drivers")
    assert not any("direction" in d.value.columns for d in at.dataframe)
    assert not any(n.startswith("line to the ") for n in _trace_names(at))
    at = _run("styles")
    assert not at.radio and "Normal typical" in _trace_names(at)


@pytest.mark.slow
@pytest.mark.browser
def test_drivers_page_draws_directions_in_the_browser(server, page):
    from playwright.sync_api import expect

    url, _ws = server
    page.goto(f"{url}/drivers")
    expect(page.get_by_role("heading", name="Drivers", exact=True).first).to_be_visible(timeout=60_000)
    expect(page.locator(".js-plotly-plot").first).to_be_visible(timeout=60_000)
    expect(page.get_by_role("heading", name="Fits per direction")).to_be_visible(timeout=60_000)
    # Plotly draws the figures one by one: wait for what is asserted on (the three indicator figures, each
    # with its legend entry for the presses to the left), not for the first figure drawn
    page.wait_for_function(
        """() => [...document.querySelectorAll('.legendtext')]
        .filter(e => e.textContent.toLowerCase().includes('to the left')).length >= 3""",
        timeout=60_000,
    )
    drawn = page.evaluate("""() => [...document.querySelectorAll('.js-plotly-plot')].filter(g => g._fullData)
        .map(g => g._fullData.filter(t => t.visible !== false).map(t => [t.name, (t.line || {}).dash || '']))""")
    names = [name for fig in drawn for name, _ in fig]
    assert any(n.startswith("used, to the left") for n in names), names
    assert any(n.startswith("used, to the right") for n in names), names
    sides = [dash for fig in drawn for name, dash in fig if name.startswith("line to the ")]
    assert sides and set(sides) <= {"dash", "dashdot"}, drawn
    # every indicator figure shows the presses by direction and has a legend entry for them (waited for above)
    assert page.locator(".legendtext", has_text="to the left").count() >= 3
    from dashboard_support import SHOT_DIR

    SHOT_DIR.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOT_DIR / "drivers_directions.png"), full_page=True, animations="disabled")
