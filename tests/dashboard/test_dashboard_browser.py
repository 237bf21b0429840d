"""The dashboard in headless Chromium: every page, an upload, a short training run."""

import re

import pytest
from playwright.sync_api import expect

from dashboard_support import SHOT_DIR, log_bytes

pytestmark = [pytest.mark.browser, pytest.mark.slow]  # a headless Chromium: seconds to tens of seconds each

ERRORS = '[data-testid="stException"], [data-testid="stAlertContentError"]'


def settle(page) -> None:
    """Wait until the script run is over (elements are drawn faded during a run)."""
    page.wait_for_timeout(300)
    expect(page.locator('[data-testid="stApp"][data-test-script-state="notRunning"]')).to_be_attached(timeout=60_000)


def no_errors(page) -> None:
    assert page.locator(ERRORS).count() == 0, page.locator(ERRORS).first.inner_text()


def shot(page, name: str) -> None:
    SHOT_DIR.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOT_DIR / f"{name}.png"), animations="disabled")


def open_page(page, url: str, path: str, title: str) -> None:
    page.goto(f"{url}/{path}")
    expect(page.get_by_role("heading", name=title, exact=True).first).to_be_visible(timeout=60_000)
    settle(page)


def test_every_page_renders(server, page):
    url, _ws = server
    for path, title, expect_chart in [
        ("", "Data", True),
        ("drivers", "Drivers", True),
        ("styles", "Styles", True),
        ("training", "Training", False),
        ("results", "Results", True),
    ]:
        open_page(page, url, path, title)
        if expect_chart:
            expect(page.locator('[data-testid="stPlotlyChart"] .js-plotly-plot').first).to_be_visible(timeout=30_000)
            settle(page)
        no_errors(page)
        shot(page, f"page_{title.lower()}")
        if title == "Data":  # the recording viewer alone, below the fold of the page shot
            page.locator('[data-testid="stPlotlyChart"]').first.screenshot(
                path=str(SHOT_DIR / "data_recording_viewer.png"), animations="disabled"
            )


def test_styles_say_what_sets_them_apart_and_who_is_unsure(server, page):
    """The Styles page describes every style in words with units, and has its unsure-driver section."""
    url, _ws = server
    open_page(page, url, "styles", "Styles")
    expect(page.get_by_role("heading", name="Unsure drivers").first).to_be_visible(timeout=30_000)
    members = page.locator('[data-testid="stTable"]').filter(has_text="what sets it apart").first
    expect(members).to_be_visible(timeout=30_000)
    text = members.inner_text()
    assert re.search(r"\d(\.\d+)? (s|m)\b", text), text
    no_errors(page)


def test_upload_logs(server, page, tmp_path):
    url, ws = server
    good = tmp_path / "drive_b1.mcap"
    good.write_bytes(log_bytes(tmp_path, driver_id="D42", fmt="mcap", seed=3))
    empty = tmp_path / "empty.csv"
    empty.write_bytes(b"")
    open_page(page, url, "", "Data")
    page.locator('[data-testid="stFileUploader"] input[type="file"]').set_input_files([str(good), str(empty)])
    button = page.get_by_role("button", name="Ingest 2 file(s)")
    expect(button).to_be_enabled(timeout=30_000)
    button.click()
    # the good log's lead vehicle runs into the ego for a moment: ingested with a warning (plausibility checks)
    done = re.compile(r"Last upload: (1 (ingested|warning), 1 refused|1 refused, 1 (ingested|warning))")
    expect(page.get_by_text(done)).to_be_visible(timeout=60_000)
    settle(page)
    no_errors(page)
    assert "D42" in set(ws.recordings()["driver_id"])
    expect(page.get_by_text(f"Recordings ({len(ws.recordings())})")).to_be_visible()
    shot(page, "upload_result")


def test_training_progress_moves(server, page):
    url, ws = server
    open_page(page, url, "training", "Training")
    page.get_by_role("button", name="Start training").click()
    bar = page.locator('[data-testid="stProgress"] [role="progressbar"]').first
    expect(bar).to_be_visible(timeout=60_000)
    seen = set()
    for _ in range(600):
        seen.add(bar.get_attribute("aria-valuenow"))
        if len(seen - {None, "0"}) >= 2:
            break
        page.wait_for_timeout(200)
    assert len(seen - {None, "0"}) >= 2, f"progress never moved: {seen}"
    no_errors(page)
    shot(page, "training_live")
    # a reload starts a new session: the run is found again from the workspace, not from the session
    rid = next(p.stem for p in (ws.root / "dashboard" / "jobs").glob("Defensive-*.json"))
    page.reload()
    expect(page.get_by_text(re.compile(rf"{rid}: (running|done)")).first).to_be_visible(timeout=60_000)
    # when it ends, the page redraws itself: no run left under "Running", the run listed as done
    expect(page.get_by_text("No training running.")).to_be_visible(timeout=120_000)
    settle(page)
    no_errors(page)
    shot(page, "training_done")
    from rl.runs import list_runs

    runs = list_runs(ws).set_index("run_id")
    new = [r for r in runs.index if r.startswith("Defensive-")]
    assert len(new) == 1 and runs.loc[new[0], "state"] == "done" and runs.loc[new[0], "episode"] == 3000
    expect(page.get_by_text(f"{new[0]}: done — episode 3000/3000")).to_be_visible()  # the finished run shown


def test_fleet_views(server, page):
    """A finished fleet of the six drivers x 2 seeds: its panel on the Training page, its view on Results."""
    import json

    from dashboard import jobs
    from dashboard_support import SAMPLE_DRIVERS, write_fake_fleet

    url, ws = server
    write_fake_fleet(ws, "browser-fleet", list(SAMPLE_DRIVERS), seeds=(0, 1))
    jobs.fleet_jobs_dir(ws).mkdir(parents=True, exist_ok=True)
    (jobs.fleet_jobs_dir(ws) / "browser-fleet.json").write_text(
        json.dumps(
            {
                "job_id": "browser-fleet",
                "pid": None,
                "fleet_id": "browser-fleet",
                "request": {},
                "launched_at": "2026-11-30T10:00:00+00:00",
            }
        )
    )
    open_page(page, url, "training", "Training")
    expect(page.get_by_text(re.compile(r"fleet browser-fleet: done — 12/12 agents done"))).to_be_visible(timeout=30_000)
    no_errors(page)
    open_page(page, url, "results", "Results")
    heading = page.get_by_role("heading", name="Fleets (1)")
    expect(heading).to_be_visible(timeout=30_000)
    heading.scroll_into_view_if_needed()
    chart = page.locator('[data-testid="stPlotlyChart"]').last
    expect(chart.locator(".js-plotly-plot")).to_be_visible(timeout=30_000)
    settle(page)
    no_errors(page)
    expect(page.get_by_text("10 of 12 evaluated agents meet their target", exact=False)).to_be_visible()
    chart.screenshot(path=str(SHOT_DIR / "results_fleet_agreement.png"), animations="disabled")
    shot(page, "results_fleet")
