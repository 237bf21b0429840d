"""Workspaces for the dashboard tests: empty, and a small sample one built once per session."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from laneprint.workspace import Workspace, atomic_write_json

ROOT = Path(__file__).resolve().parents[2]
APP = ROOT / "dashboard" / "app.py"
PAGES = ROOT / "dashboard" / "app_pages"


def page_path(name: str) -> str:
    return str(PAGES / f"{name}.py")


def write_fake_run(ws: Workspace, run_id: str, state: str = "done", episodes: int = 6,
                   pid: int | None = None, summary: list[dict] | None = None) -> Path:
    """A run folder as the trainer writes it (config, status, metrics, evaluation)."""
    d = ws.runs_dir / run_id
    d.mkdir(parents=True, exist_ok=True)
    atomic_write_json(d / "config.json", {"run_id": run_id, "target": {"kind": "style", "name": "Normal"},
                                          "reward": "timing", "lines_source": "paper", "seed": 0})
    atomic_write_json(d / "status.json", {
        "state": state, "pid": pid, "episode": episodes if state == "done" else 2, "episodes": episodes,
        "started_at": "2026-11-22T00:00:00+00:00", "updated_at": "2026-11-22T00:01:00+00:00", "message": ""})
    with open(d / "metrics.jsonl", "w") as fh:
        for e in range(1, episodes + 1):
            fh.write(json.dumps({"episode": e, "loss": 1.0 / e, "mean_step_reward": 1.0 + e / 10, "epsilon": 0.8,
                                 "length": 10, "changed": e % 2 == 0, "return": 5.0, "env_steps": 10 * e,
                                 "wall_s": 0.1 * e}) + "\n")
    if state == "done":
        atomic_write_json(d / "evaluation.json", {"summary": summary or [
            {"who": "agent", "recall": 0.96, "balanced_accuracy": 0.9, "timing_mae_s": 0.5},
            {"who": "greedy", "recall": 0.84, "balanced_accuracy": 0.7, "timing_mae_s": 1.5},
            {"who": "driver", "recall": 1.0, "balanced_accuracy": 1.0, "timing_mae_s": 0.0}]})
    return d


SAMPLE_LOGS = ROOT / "sample_logs"
SAMPLE_DRIVERS = ("D01", "D02", "D03", "D04", "D05", "D06")


def build_sample_workspace(root: Path) -> Workspace:
    """Six drivers' 80 km/h sections of the shipped study, ingested and analysed by the real stages."""
    from clustering.pipeline import analyze
    from ingest.pipeline import ingest_paths

    ws = Workspace(root).ensure()
    files = [p for d in SAMPLE_DRIVERS for p in sorted(SAMPLE_LOGS.glob(f"{d}_S80.*"))]
    assert len(files) == len(SAMPLE_DRIVERS), f"sample logs missing in {SAMPLE_LOGS}: run `laneprint simulate`"
    report = ingest_paths(files, ws)
    assert report.counts["rejected"] == 0, report.to_dict()
    analyze(ws)
    for seed in (0, 1):  # two short real runs, trained and evaluated in-process
        train_short_run(ws, f"Normal-seed{seed}", seed)
    return ws


def train_short_run(ws: Workspace, run_id: str, seed: int, episodes: int = 30) -> dict:
    from rl.dqn import DQNSettings
    from rl.env import EnvConfig
    from rl.rewards import RewardSettings
    from rl.runs import Target, resolve_lines, train_run

    target = Target("style", "Normal")
    env = EnvConfig(lines=resolve_lines(ws, target, "analysis"), reward=RewardSettings())
    return train_run(ws, target, env, DQNSettings(episodes=episodes, seed=seed), run_id=run_id)


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


def log_bytes(tmp_path: Path, driver_id: str | None = "D77", fmt: str = "csv", seed: int = 0) -> bytes:
    """A small valid log (one press, two traffic cars) as the bytes of a CSV or MCAP file."""
    from indicators.synthetic import make_recording
    from ingest.writers import write_csv, write_mcap

    meta, ego, traffic = make_recording(
        12.0, 10.0, 21.0 + seed, [(0, 0), (6.0, 1)], presses=[(4.0, 0.5, "left")],
        vehicles=[("lead", 35.0, 17.0, 0, 4.5), ("nb", -25.0, 19.0, 1, 4.5)],
        recording_id=f"s{seed}", driver_id=driver_id or "")
    meta = {k: v for k, v in meta.items() if k != "recording_id" and (k != "driver_id" or driver_id)}
    path = tmp_path / f"log_{seed}.{fmt}"
    (write_csv if fmt == "csv" else write_mcap)(path, meta, ego, traffic)
    return path.read_bytes()


# --- real server + headless Chromium (see ../shared/recipes/BROWSER_TESTS.md) ---------------

CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
SHOT_DIR = ROOT / "test-results" / "dashboard"


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_healthy(url: str, proc, timeout: float = 60) -> None:
    import time
    import urllib.request

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"streamlit exited early with code {proc.returncode}")
        try:
            with urllib.request.urlopen(url + "/_stcore/health", timeout=2) as r:
                if r.status == 200 and r.read().strip() == b"ok":
                    return
        except OSError:
            pass
        time.sleep(0.1)
    raise TimeoutError(f"{url}/_stcore/health not ok after {timeout}s")


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
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    env = dict(os.environ, LANEPRINT_WORKSPACE=str(ws.root), LANEPRINT_DASHBOARD_EPISODES="3000",
               LANEPRINT_DASHBOARD_POLL_S="0.5")
    log_path = tmp_path_factory.mktemp("streamlit") / "server.log"
    with open(log_path, "w+") as log:
        proc = subprocess.Popen(streamlit_command(port, "127.0.0.1", ws.root), cwd=ROOT, env=env, stdout=log,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            _wait_healthy(url, proc)
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
