"""The dashboard in headless Chromium on a study whose TTCs run into the thousands: axis ranges read
from the drawn Plotly figures, titles clear of the plots, no request to any outside host, Enter in
the Episodes field starts nothing; and `laneprint report` opened offline with every figure drawn."""

import json
import os
import shutil
import signal
import subprocess
import sys
from urllib.parse import urlparse

import numpy as np
import pytest
from playwright.sync_api import expect

from dashboard_support import ROOT, SHOT_DIR, free_port, wait_healthy
from laneprint.workspace import Workspace

pytestmark = [pytest.mark.browser, pytest.mark.slow]  # a headless Chromium: seconds to tens of seconds each

TTC_AXIS = ("t_f", "t_nf", "gap")


def make_heavy(ws: Workspace) -> None:
    """3 % of every TTC in the analysis and in the runs' evaluation tables set to 1,000-20,000 s."""
    from clustering.pipeline import analyze_tables

    rng = np.random.default_rng(0)
    dec = ws.read_table("analysis", "decisions")
    press = dec.index[(dec["label"] == "change") & np.isfinite(dec["t_f_s"])]
    pick = rng.choice(press, size=max(2, len(press) * 3 // 100), replace=False)
    dec.loc[pick, "t_f_s"] = rng.uniform(1000, 20000, len(pick))
    meta = ws.read_meta("analysis")
    ws.write_tables("analysis", analyze_tables(dec), meta)
    for run in ws.runs_dir.iterdir():
        for name in ("eval_changes", "eval_states"):
            path = run / f"{name}.parquet"
            if path.exists():
                import pandas as pd

                t = pd.read_parquet(path)
                rows = rng.choice(len(t), size=max(2, len(t) * 3 // 100), replace=False)
                t.loc[t.index[rows], "t_f_s"] = rng.uniform(1000, 20000, len(rows))
                t.to_parquet(path)


@pytest.fixture(scope="module")
def heavy_server(browser, sample_ws, tmp_path_factory):
    from dashboard.cli import streamlit_command

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path_factory.mktemp("heavy") / "ws"))
    make_heavy(ws)
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    env = dict(os.environ, LANEPRINT_WORKSPACE=str(ws.root), LANEPRINT_DASHBOARD_EPISODES="300")
    proc = subprocess.Popen(
        streamlit_command(port, "127.0.0.1", ws.root),
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        wait_healthy(url, proc)
        yield url, ws
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=20)


def settle(page) -> None:
    page.wait_for_timeout(300)
    expect(page.locator('[data-testid="stApp"][data-test-script-state="notRunning"]')).to_be_attached(timeout=60_000)


def record_requests(page) -> list[str]:
    seen: list[str] = []
    page.on("request", lambda r: seen.append(r.url))
    page.on("console", lambda m: seen.append("console: " + m.text) if "ERR_NAME_NOT_RESOLVED" in m.text else None)
    return seen


def outside(urls: list[str]) -> list[str]:
    return [
        u
        for u in urls
        if u.startswith("console: ")
        or urlparse(u).hostname not in (None, "127.0.0.1", "localhost")
        and not u.startswith(("data:", "blob:"))
    ]


#: Every y and x axis of every Plotly figure on the page: its title, range and the values drawn on it.
AXES_JS = """() => [...document.querySelectorAll('.js-plotly-plot')].flatMap((gd, i) => {
  const fl = gd._fullLayout, out = [];
  for (const k of Object.keys(fl)) {
    if (!/^[xy]axis\\d*$/.test(k)) continue;
    const ax = fl[k], letter = k[0], id = ax._id;
    const vals = [];
    for (const tr of gd._fullData) {
      if ((tr[letter + 'axis'] || letter) !== id) continue;
      const v = tr.customdata && tr.customdata.length && typeof tr.customdata[0] === 'number' ? tr.customdata
              : tr[letter];
      if (v && tr.mode && tr.mode.includes('markers')) for (const x of v) if (typeof x === 'number') vals.push(x);
    }
    out.push({plot: i, axis: k, title: (ax.title && ax.title.text) || '', range: ax.range, values: vals,
              type: ax.type});
  }
  return out;
})"""

#: Title, plot area and axis titles of each figure, as drawn [px].
BOXES_JS = """() => [...document.querySelectorAll('.js-plotly-plot')].map(gd => {
  const box = s => { const e = gd.querySelector(s); if (!e) return null; const r = e.getBoundingClientRect();
                     return r.width ? {l: r.left, r: r.right, t: r.top, b: r.bottom} : null; };
  return {title: box('.gtitle'), plot: box('.nsewdrag'), ytitle: box('.g-ytitle'), xtitle: box('.g-xtitle')};
})"""


def check_axes(page, where: str) -> int:
    from laneprint.plotting import range_set_by_few

    checked = 0
    for ax in page.evaluate(AXES_JS):
        if not any(k in ax["title"] for k in TTC_AXIS) or not ax["values"] or ax["range"] is None:
            continue
        if ax["type"] == "log":  # a driver's dozen points with minutes among them: all on a log axis
            values = np.log10([v for v in ax["values"] if v > 0])
            assert ax["range"][0] <= values.min() and values.max() <= ax["range"][1], (where, ax["title"])
            checked += 1
            continue
        assert ax["range"][1] < 1000, (where, ax["title"], ax["range"])  # the data run to 20,000 s
        assert not range_set_by_few(ax["values"], ax["range"]), (where, ax["title"], ax["range"])
        checked += 1
    return checked


def test_heavy_tails_drawn_readable_and_offline(heavy_server, browser):
    url, ws = heavy_server
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000})
    page = ctx.new_page()
    seen = record_requests(page)
    counts = {}
    for path, title in (
        ("drivers", "Drivers"),
        ("styles", "Styles"),
        ("results", "Results"),
        ("", "Data"),
        ("training", "Training"),
    ):
        page.goto(f"{url}/{path}")
        expect(page.get_by_role("heading", name=title, exact=True).first).to_be_visible(timeout=60_000)
        settle(page)
        if path in ("drivers", "styles", "results"):
            expect(page.locator(".js-plotly-plot").first).to_be_visible(timeout=30_000)
            page.mouse.wheel(0, 20000)  # every chart on the page drawn
            page.wait_for_timeout(1500)
            settle(page)
            counts[title] = check_axes(page, title)
        if path == "drivers":
            for i, b in enumerate(page.evaluate(BOXES_JS)[:3]):
                assert b["title"] and b["plot"] and b["title"]["b"] <= b["plot"]["t"] - 4, (i, b)
                assert b["ytitle"]["r"] <= b["plot"]["l"] and not (
                    b["ytitle"]["t"] < b["title"]["b"] and b["ytitle"]["r"] > b["title"]["l"]
                ), (i, b)
            SHOT_DIR.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(SHOT_DIR / "heavy_drivers.png"))
        if path == "results":
            page.screenshot(path=str(SHOT_DIR / "heavy_results.png"), full_page=True)
    assert counts["Drivers"] >= 1 and counts["Results"] >= 2, counts  # Figs. 10 and 11 and the driver's t_f
    assert counts["Styles"] >= 0
    assert outside(seen) == [], outside(seen)[:5]
    ctx.close()


def test_enter_in_episodes_starts_nothing(heavy_server, browser):
    url, ws = heavy_server
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000})
    page = ctx.new_page()
    page.goto(f"{url}/training")
    expect(page.get_by_role("heading", name="Training", exact=True).first).to_be_visible(timeout=60_000)
    settle(page)
    field = page.get_by_label("Episodes", exact=True)
    field.fill("20000")
    field.press("Enter")
    page.wait_for_timeout(2500)
    settle(page)
    jobs = ws.root / "dashboard" / "jobs"
    assert not list(jobs.glob("*.json")) if jobs.exists() else True, "Enter started a training"
    field.fill("5")
    field.press("Tab")
    settle(page)
    expect(page.get_by_text("the agent would learn nothing", exact=False)).to_be_visible(timeout=30_000)
    expect(page.get_by_role("button", name="Start training")).to_be_disabled()
    ctx.close()


def test_report_opens_offline_with_every_figure(sample_ws, browser, tmp_path):
    out = tmp_path / "report.html"
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "laneprint.app.cli",
            "report",
            "--workspace",
            str(sample_ws.root),
            "--out",
            str(out),
            "--json",
            "--no-assets",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    n = json.loads(res.stdout)["figures"]
    ctx = browser.new_context(viewport={"width": 1300, "height": 900})
    page = ctx.new_page()
    seen = record_requests(page)
    page.goto(out.as_uri())
    page.wait_for_function(f"document.querySelectorAll('.js-plotly-plot .main-svg').length >= {n}", timeout=60_000)
    drawn = page.evaluate("[...document.querySelectorAll('.js-plotly-plot')].filter(g => g._fullLayout).length")
    assert drawn == n
    assert [u for u in seen if not u.startswith(("file:", "data:", "blob:"))] == []
    ctx.close()


def test_results_downloads(heavy_server, browser, tmp_path):
    """The report, a run's results (CSV, JSON) and its ONNX policy come down from the Results page."""
    import zipfile

    url, ws = heavy_server
    ctx = browser.new_context(viewport={"width": 1400, "height": 1000}, accept_downloads=True)
    page = ctx.new_page()
    page.goto(f"{url}/results")
    expect(page.get_by_role("heading", name="Results", exact=True).first).to_be_visible(timeout=60_000)
    settle(page)
    got = {}
    page.get_by_role("button", name="Export the policy (ONNX)").click()  # exported once, then one click
    expect(page.get_by_role("button", name="Policy (ONNX + policy.json, zip)")).to_be_visible(timeout=120_000)
    for label in ("Report of the study (HTML)", "Results (CSV)", "Results (JSON)", "Policy (ONNX + policy.json, zip)"):
        with page.expect_download(timeout=120_000) as dl:
            page.get_by_role("button", name=label).click()
        path = tmp_path / dl.value.suggested_filename
        dl.value.save_as(path)
        got[label] = path
    assert 'class="plotly-graph-div"' in got["Report of the study (HTML)"].read_text()
    csv = got["Results (CSV)"].read_text().splitlines()
    assert csv[0].startswith("policy,") and any(line.startswith("agent,") for line in csv)
    assert json.loads(got["Results (JSON)"].read_text())["evaluation"]["summary"]
    names = zipfile.ZipFile(got["Policy (ONNX + policy.json, zip)"]).namelist()
    assert {n.split("/")[-1] for n in names} >= {"policy.onnx", "policy.json"}
    ctx.close()
