"""Fixtures of the dashboard tests: workspaces, a Streamlit server and headless Chromium."""

from __future__ import annotations

import os

import pytest

from dashboard_support import CHROMIUM, CHROMIUM_ARGS, ROOT, build_sample_workspace, free_port, wait_healthy
from laneprint.workspace import Workspace


@pytest.fixture(scope="session")
def sample_ws(tmp_path_factory) -> Workspace:
    return build_sample_workspace(tmp_path_factory.mktemp("sample_ws"))


@pytest.fixture
def empty_ws(tmp_path, monkeypatch) -> Workspace:
    ws = Workspace(tmp_path / "ws")
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(ws.root))
    return ws


@pytest.fixture
def use_sample(sample_ws, monkeypatch) -> Workspace:
    monkeypatch.setenv("LANEPRINT_WORKSPACE", str(sample_ws.root))
    return sample_ws


@pytest.fixture(scope="session")
def browser():
    if not os.path.exists(CHROMIUM):
        if os.environ.get("LANEPRINT_REQUIRE_BROWSER"):
            pytest.fail(f"{CHROMIUM} missing: apt-get install -y chromium")
        pytest.skip(f"{CHROMIUM} missing: apt-get update && apt-get install -y chromium")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="session")
def server(browser, sample_ws, tmp_path_factory):
    """`laneprint dashboard`'s streamlit command on a free port over a copy of the sample workspace."""
    import shutil
    import signal
    import subprocess

    from dashboard.cli import streamlit_command

    ws = Workspace(shutil.copytree(sample_ws.root, tmp_path_factory.mktemp("browser") / "ws"))
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    env = dict(
        os.environ,
        LANEPRINT_WORKSPACE=str(ws.root),
        LANEPRINT_DASHBOARD_EPISODES="3000",
        LANEPRINT_DASHBOARD_POLL_S="0.5",
    )
    log_path = tmp_path_factory.mktemp("streamlit") / "server.log"
    with open(log_path, "w+") as log:
        proc = subprocess.Popen(
            streamlit_command(port, "127.0.0.1", ws.root),
            cwd=ROOT,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,
        )
        try:
            wait_healthy(url, proc)
            yield url, ws
        finally:
            os.killpg(proc.pid, signal.SIGTERM)  # also ends training runs that outlived the test
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            log.seek(0)
            tail = log.read()[-3000:]
            if tail.strip():
                print("\n--- streamlit log (tail) ---\n" + tail)


@pytest.fixture
def page(browser):
    ctx = browser.new_context(viewport={"width": 1400, "height": 1500})
    pg = ctx.new_page()
    yield pg
    ctx.close()
