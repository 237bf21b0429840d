"""Time to first render of each dashboard page on a workspace of 100 drivers x 50 decisions and their fleet.

    python benchmarks/dashboard.py [--drivers 100] [--decisions 50] [--fleet 100] [--repeat 5] [--browser]
                                   [--keep DIR] [--baseline DIR|REV] [--pages training,results]

The workspace is generated in a temporary folder: one short recording per driver
(`tests.support.synthetic_decisions.make_recording`), the analysis of a synthetic decisions
table (`make_decision_table` + the real `analyze_tables`), two short real
training runs (`rl.runs.train_run`, 300 episodes, evaluated), and a fleet of
`--fleet` agents, one per driver (`fleets/<id>/fleet.json` and a run folder each,
as `laneprint train --drivers all` leaves them; synthesized for speed: each run is
a copy of the first real run's weights, metrics and evaluation tables with its
own target, fleet id and made-up agent/greedy/imitation figures). The Training
page shows that fleet as a finished fleet job (its 100-row table). Each page is rendered with Streamlit's AppTest (the
script run, not the browser's drawing): 'cold' clears Streamlit's caches first (the
first visit after the workspace changed), 'warm' is a second visit. Medians [s].

With `--browser` each page is also loaded in headless Chromium from a real server
(`laneprint dashboard`'s command): time until the page's title is shown, the script run
is over and, where the page has them, the first Plotly chart is drawn. 'browser cold'
and 'browser warm': from `goto` in a new tab of a new browser context (nothing cached:
this includes loading Streamlit's and Plotly's JavaScript, several MB, as on a first
visit); 'cold' touches the workspace folders first so the cached loaders miss. 'browser
nav': in that tab, from the click on the page's sidebar link (coming from another page
with a chart: `NAV_FROM`) -- how the pages switch once the dashboard is open; 'curves': on Results,
from the click on the "Training curves" expander to its chart drawn. 'floor': the
same fresh-tab measurement of a one-chart Streamlit page, visited in turn with the
pages: what opening any Streamlit + Plotly page costs on this machine.

`--keep DIR` keeps the workspace for the next run; `--baseline DIR|REV` times the code in
DIR, or of a git revision (exported with `git archive`), too, its pages visited in turn with this
checkout's. A small study: `--drivers 12 --fleet 0`.

The medians are written to `benchmarks/results/dashboard.json` (`--out NAME`) with the command, commit,
date and machine.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from results_file import write_result  # beside this file: imported before the folder leaves the path

# this file is named like the package it measures: keep its folder off the import path
sys.path = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout: the test tools (tests.support)

import streamlit as st  # noqa: E402
from streamlit.testing.v1 import AppTest  # noqa: E402

from laneprint.workspace import Workspace  # noqa: E402

PAGES = Path(__file__).resolve().parents[1] / "dashboard" / "app_pages"


def build(root: Path, n_drivers: int, n_decisions: int) -> Workspace:
    from clustering.pipeline import analyze_tables
    from tests.support.synthetic_decisions import make_decision_table, make_recording

    ws = Workspace(root).ensure()
    for i in range(n_drivers):
        meta, ego, traffic = make_recording(
            60.0,
            20.0,
            20.0 + (i % 7),
            [(0, 0), (30.0, 1)],
            presses=[(25.0, 0.5, "left")],
            vehicles=[("lead", 80.0, 17.0, 0, 4.5), ("nb", -40.0, 19.0, 1, 4.5)],
            recording_id=f"{i:016x}",
            driver_id=f"D{i:04d}",
        )
        meta.update(
            simulator="bench",
            source_name=f"r{i}.csv",
            source_path=f"/b/r{i}.csv",
            format="csv",
            n_samples=len(ego),
            duration_s=60.0,
            n_presses=1,
            n_vehicles=2,
            status="ok",
            warnings="",
            ingested_at="2026-01-01T00:00:00+00:00",
        )
        ws.write_recording(meta, ego, traffic)
    decisions, _ = make_decision_table(n_drivers, n_decisions, seed=0)
    ws.write_tables("analysis", analyze_tables(decisions), {"settings": {}})
    from rl.learners.dqn import DQNSettings
    from rl.problem.env import EnvConfig
    from rl.problem.rewards import RewardSettings
    from rl.runs import Target, resolve_lines, train_run

    for seed in (0, 1):  # two short real runs, evaluated against the style's members
        target = Target("style", "Normal")
        env = EnvConfig(lines=resolve_lines(ws, target, "analysis"), reward=RewardSettings())
        train_run(ws, target, env, DQNSettings(episodes=300, seed=seed), run_id=f"bench-{seed}")
    return ws


def build_fleet(ws: Workspace, n_agents: int, template: str = "bench-0", fleet_id: str = "bench-fleet") -> None:
    """A finished fleet of one agent per driver, synthesized from the template run (see the module doc)."""
    import json
    import shutil

    import numpy as np

    from laneprint.workspace import atomic_write_json

    rng = np.random.default_rng(0)
    src = ws.runs_dir / template
    config = json.loads((src / "config.json").read_text())
    status = json.loads((src / "status.json").read_text())
    evaluation = json.loads((src / "evaluation.json").read_text())
    drivers = sorted(ws.read_table("analysis", "decisions")["driver_id"].astype(str).unique())[:n_agents]
    runs = []
    for driver in drivers:
        run_id = f"{fleet_id}-{driver.lower()}-s0"
        dst = ws.runs_dir / run_id
        shutil.copytree(src, dst)
        atomic_write_json(
            dst / "config.json",
            {**config, "run_id": run_id, "fleet_id": fleet_id, "target": {"kind": "driver", "name": driver}},
        )
        greedy = float(rng.uniform(0.55, 0.7))
        figures = {
            "agent": (float(rng.uniform(0.9, 1.0)), greedy + float(rng.uniform(0.0, 0.3))),
            "greedy": (1.0, greedy),
            "imitation": (float(rng.uniform(0.6, 0.9)), float(rng.uniform(0.6, 0.9))),
        }
        summary = [
            {**row, "recall": figures[row["who"]][0], "balanced_accuracy": figures[row["who"]][1]}
            if row.get("who") in figures
            else row
            for row in evaluation["summary"]
        ]
        atomic_write_json(
            dst / "evaluation.json",
            {**evaluation, "run_id": run_id, "summary": summary, "summary_members": summary, "drivers": [driver]},
        )
        atomic_write_json(dst / "status.json", {**status, "pid": None})
        runs.append(run_id)
    now = "2026-11-30T12:00:00+00:00"
    atomic_write_json(
        ws.root / "fleets" / fleet_id / "fleet.json",
        {
            "fleet_id": fleet_id,
            "created_at": now,
            "targets": [{"kind": "driver", "name": d} for d in drivers],
            "seeds": [0],
            "runs": runs,
            "backend": "local",
            "state": "done",
            "pid": None,
            "updated_at": now,
            "message": "done",
        },
    )
    atomic_write_json(
        ws.root / "dashboard" / "fleet_jobs" / f"{fleet_id}.json",
        {"job_id": fleet_id, "pid": None, "fleet_id": fleet_id, "launched_at": now, "request": {}},
    )


PAGE_NAMES = ("data", "drivers", "styles", "training", "results")
#: (url path, title, has a Plotly chart) of each page
BROWSER_PAGES = {
    "data": ("", "Data", True),
    "drivers": ("drivers", "Drivers", True),
    "styles": ("styles", "Styles", True),
    "training": ("training", "Training", False),
    "results": ("results", "Results", True),
}


def render(page: str, cold: bool, pages: Path = PAGES) -> float:
    if cold:
        st.cache_data.clear()
    at = AppTest.from_file(str(pages / f"{page}.py"), default_timeout=300)
    t0 = time.perf_counter()
    at.run()
    dt = time.perf_counter() - t0
    if at.exception:
        raise SystemExit(f"{page}: {at.exception[0].value}")
    return dt


def script_times(
    repeat: int, pages: Path = PAGES, names: tuple[str, ...] = PAGE_NAMES
) -> dict[str, tuple[float, float]]:
    """(cold, warm) median seconds of each page's script run (AppTest); pages not in `names`: NaN."""
    for page in names:
        render(page, cold=True, pages=pages)  # imports and first compile out of the way
    return {
        page: (
            statistics.median(render(page, cold=True, pages=pages) for _ in range(repeat)),
            statistics.median(render(page, cold=False, pages=pages) for _ in range(repeat)),
        )
        if page in names
        else (float("nan"), float("nan"))
        for page in PAGE_NAMES
    }


def baseline_script_times(
    code: Path, ws: Workspace, repeat: int, names: tuple[str, ...] = PAGE_NAMES
) -> dict[str, tuple[float, float]]:
    """`script_times` of the code in `code` (its packages first on the path), in a child process."""
    import json
    import subprocess

    out = subprocess.run(
        [
            sys.executable,
            __file__,
            "--keep",
            str(ws.root),
            "--repeat",
            str(repeat),
            "--script-json",
            "--code",
            str(code),
            "--pages",
            ",".join(names),
        ],
        check=True,
        capture_output=True,
        text=True,
        cwd=code,
        env=dict(os.environ, PYTHONPATH=str(code)),
    )
    return {k: tuple(v) for k, v in json.loads(out.stdout.strip().splitlines()[-1]).items()}


def serve(code: Path, ws: Workspace):
    """`laneprint dashboard`'s streamlit command serving the app of `code` (its packages first on the path)."""
    import socket
    import subprocess

    from dashboard.cli import streamlit_command

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    cmd = streamlit_command(port, "127.0.0.1", ws.root)
    cmd[cmd.index("run") + 1] = str(code / "dashboard" / "app.py")
    proc = subprocess.Popen(
        cmd,
        cwd=code,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        env=dict(os.environ, LANEPRINT_WORKSPACE=str(ws.root), PYTHONPATH=str(code)),
    )
    return proc, f"http://127.0.0.1:{port}"


FLOOR_APP = """import plotly.graph_objects as go
import streamlit as st

st.title("Floor")
st.plotly_chart(go.Figure(go.Scatter(x=[0, 1, 2], y=[0, 1, 0])))
"""


def serve_floor(folder: Path, ws: Workspace):
    """The same streamlit command serving a one-chart page: what any Streamlit + Plotly page costs to open."""
    import socket
    import subprocess

    from dashboard.cli import streamlit_command

    (folder / "floor.py").write_text(FLOOR_APP)
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    cmd = streamlit_command(port, "127.0.0.1", ws.root)
    cmd[cmd.index("run") + 1] = str(folder / "floor.py")
    proc = subprocess.Popen(
        cmd, cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    return proc, f"http://127.0.0.1:{port}"


#: The page each page is reached from in 'browser nav' (the switches issue 23 timed: Drivers -> Training,
#: Data -> Styles, Training -> Results).
NAV_FROM = {"data": "drivers", "drivers": "data", "styles": "data", "training": "drivers", "results": "training"}
CURVES = "Training curves (Fig. 9)"


def browser_times(
    ws: Workspace, repeat: int, codes: list[Path], floor: list[float] | None = None, names: tuple[str, ...] = PAGE_NAMES
) -> list[dict[str, tuple[float, ...]]]:
    """Per code folder: (cold, warm, nav) median seconds to a drawn page in headless Chromium, the
    folders' servers visited in turn (the same load on each); and for 'results curves' the time from
    the click on the Results page's "Training curves" expander to its chart drawn."""
    import signal
    import urllib.request

    from playwright.sync_api import expect, sync_playwright

    import shutil

    servers = [serve(code, ws) for code in codes]
    floor_dir = Path(tempfile.mkdtemp(prefix="laneprint-floor-")) if floor is not None else None
    floor_server = serve_floor(floor_dir, ws) if floor_dir else None
    times = [{page: ([], [], []) for page in PAGE_NAMES} | {"curves": ([],)} for _ in codes]
    try:
        for _, url in servers + ([floor_server] if floor_server else []):
            for _ in range(600):
                try:
                    urllib.request.urlopen(url + "/_stcore/health", timeout=1)
                    break
                except OSError:
                    time.sleep(0.1)
        args = [
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
        ]
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=args)

            def drawn(page, name: str, t0: float) -> float:
                _, title, chart = BROWSER_PAGES.get(name, ("", "Floor", True))
                expect(page.get_by_role("heading", name=title, exact=True).first).to_be_visible(timeout=120_000)
                if chart:
                    expect(page.locator(".js-plotly-plot").first).to_be_visible(timeout=120_000)
                expect(page.locator('[data-testid="stApp"][data-test-script-state="notRunning"]')).to_be_attached(
                    timeout=120_000
                )
                return time.perf_counter() - t0

            def visit(url: str, name: str) -> tuple[float, float]:
                """A new tab in a new browser context (nothing cached): goto -> drawn; then, in that tab,
                another page and back to this one by the sidebar (Streamlit's own page switch) -> drawn."""
                ctx = browser.new_context(viewport={"width": 1400, "height": 1200})
                page = ctx.new_page()
                t0 = time.perf_counter()
                page.goto(f"{url}/{BROWSER_PAGES[name][0]}")
                opened = drawn(page, name, t0)
                other = NAV_FROM[name]
                page.locator('[data-testid="stSidebarNav"] a', has_text=BROWSER_PAGES[other][1]).first.click()
                drawn(page, other, time.perf_counter())
                t0 = time.perf_counter()
                page.locator('[data-testid="stSidebarNav"] a', has_text=BROWSER_PAGES[name][1]).first.click()
                nav = drawn(page, name, t0)
                curves = None
                if name == "results" and page.get_by_text(CURVES).count():
                    t0 = time.perf_counter()
                    page.get_by_text(CURVES).first.click()
                    expect(page.locator('[class*="st-key-fig9_"] .js-plotly-plot').first).to_be_visible(timeout=120_000)
                    curves = drawn(page, name, t0)
                ctx.close()
                return opened, nav, curves

            for name in names:
                for _, url in servers:
                    visit(url, name)  # imports out of the way
            for name in names:
                for _ in range(repeat):
                    for (_, url), t in zip(servers, times):
                        for sub in (
                            "recordings",
                            "analysis",
                            *(str(p.relative_to(ws.root)) for p in ws.root.glob("fleets/*/fleet.json")),
                        ):
                            os.utime(ws.root / sub)  # new cache keys: the loaders read again
                        cold, _, _ = visit(url, name)
                        warm, nav, curves = visit(url, name)
                        for series, v in zip(t[name], (cold, warm, nav)):
                            series.append(v)
                        if curves is not None:
                            t["curves"][0].append(curves)
                    if floor_server is not None:  # the floor under the same load, in turn with the pages
                        ctx = browser.new_context(viewport={"width": 1400, "height": 1200})
                        page = ctx.new_page()
                        t0 = time.perf_counter()
                        page.goto(floor_server[1])
                        floor.append(drawn(page, "floor", t0))
                        ctx.close()
            browser.close()
    finally:
        for proc, _ in servers + ([floor_server] if floor_server else []):
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait()
        if floor_dir:
            shutil.rmtree(floor_dir, ignore_errors=True)
    return [
        {name: tuple(statistics.median(v) if v else float("nan") for v in series) for name, series in t.items()}
        for t in times
    ]


def checkout(rev: str) -> Path:
    """The code of git revision `rev` of this repository in a temporary folder (`git archive`: the
    working tree and the index are left alone)."""
    import subprocess

    repo = PAGES.parents[1]
    folder = Path(tempfile.mkdtemp(prefix=f"laneprint-{rev[:12]}-"))
    archive = subprocess.run(["git", "archive", "--format=tar", rev], cwd=repo, check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive.stdout, check=True)
    return folder


def main() -> None:
    import json
    import logging

    logging.disable(logging.WARNING)  # AppTest's "missing ScriptRunContext" and cache notices
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drivers", type=int, default=100)
    ap.add_argument("--decisions", type=int, default=50)
    ap.add_argument("--fleet", type=int, default=100, help="agents in the synthesized fleet (0: none)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--browser", action="store_true", help="also time the pages in headless Chromium")
    ap.add_argument(
        "--keep",
        type=Path,
        default=None,
        help="build the workspace in this folder and keep it; reuse it when it is there already "
        "(the same workspace before and after a change)",
    )
    ap.add_argument(
        "--baseline",
        default=None,
        metavar="DIR|REV",
        help="also time the dashboard of the code in this folder, or of this git revision of the "
        "repository (e.g. HEAD~3; exported with `git archive` to a temporary folder), its pages "
        "visited in turn with this checkout's: before and after in one run",
    )
    ap.add_argument(
        "--pages",
        default=",".join(PAGE_NAMES),
        help="the pages to time, comma-separated (default: all: " + ",".join(PAGE_NAMES) + ")",
    )
    ap.add_argument("--out", default="dashboard", help="result file name under benchmarks/results/")
    ap.add_argument("--code", type=Path, default=None, help=argparse.SUPPRESS)  # the pages timed (--baseline)
    ap.add_argument("--script-json", action="store_true", help=argparse.SUPPRESS)  # script times as JSON only
    args = ap.parse_args()
    pages = (args.code / "dashboard" / "app_pages") if args.code else PAGES
    names = tuple(p.strip() for p in args.pages.split(",") if p.strip())
    if not names or set(names) - set(PAGE_NAMES):
        ap.error(f"--pages: choose among {', '.join(PAGE_NAMES)}")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        root = args.keep.resolve() if args.keep else Path(tmp) / "ws"
        if (root / "analysis").is_dir():  # a kept workspace: reused as it is (with or without its fleet)
            ws = Workspace(root)
            args.drivers = ws.read_table("analysis", "decisions")["driver_id"].nunique()
            args.fleet = len(list(root.glob("fleets/*/fleet.json"))) and len(list(ws.runs_dir.glob("*-fleet-*")))
        else:
            ws = build(root, args.drivers, args.decisions)
            if args.fleet:
                build_fleet(ws, args.fleet)
        os.environ["LANEPRINT_WORKSPACE"] = str(ws.root)
        if args.script_json:
            print(json.dumps(script_times(args.repeat, pages, names)))
            return
        print(
            f"workspace: {args.drivers} drivers x {args.decisions} decisions, "
            f"{len(ws.read_table('analysis', 'decisions'))} decision rows, a fleet of {args.fleet} agents "
            f"({len(list(ws.runs_dir.iterdir()))} runs in all), built in {time.perf_counter() - t0:.1f} s"
        )
        if args.baseline:
            args.baseline = (Path(args.baseline) if Path(args.baseline).is_dir() else checkout(args.baseline)).resolve()
        codes = [PAGES.parents[1]] + ([args.baseline] if args.baseline else [])
        labels = ["this checkout"] + ([f"baseline {args.baseline}"] if args.baseline else [])
        scripts = [script_times(args.repeat, names=names)]
        if args.baseline:
            scripts.append(baseline_script_times(args.baseline.resolve(), ws, args.repeat, names))
        floor: list[float] = []
        browsers = browser_times(ws, args.repeat, codes, floor, names) if args.browser else [None] * len(codes)
        for name, script, browser in zip(labels, scripts, browsers):
            print(f"\n{name}: medians of {args.repeat} [s]")
            head = f"{'page':<10} {'script cold':>11} {'script warm':>11}"
            if browser:
                head += f" {'browser cold':>12} {'browser warm':>12} {'browser nav':>11}  (nav from)"
            print(head)
            for page in names:
                line = f"{page:<10} {script[page][0]:>11.3f} {script[page][1]:>11.3f}"
                if browser:
                    line += (
                        f" {browser[page][0]:>12.3f} {browser[page][1]:>12.3f} {browser[page][2]:>11.3f}"
                        f"  ({NAV_FROM[page]})"
                    )
                print(line)
            if browser:
                print(f"results: '{CURVES}' opened (click to drawn chart): {browser['curves'][0]:.3f}")
        if args.baseline and browsers[0]:
            print(
                "\nthis checkout / baseline, browser nav medians: "
                + ", ".join(
                    f"{p} {browsers[0][p][2]:.2f}/{browsers[1][p][2]:.2f} (x{browsers[1][p][2] / browsers[0][p][2]:.2f})"
                    for p in names
                )
                + f", curves {browsers[0]['curves'][0]:.2f}/{browsers[1]['curves'][0]:.2f}"
            )
        rows = [
            {
                "code": label,
                "page": page,
                "script_cold_s": script[page][0],
                "script_warm_s": script[page][1],
                **(
                    {
                        "browser_cold_s": browser[page][0],
                        "browser_warm_s": browser[page][1],
                        "browser_nav_s": browser[page][2],
                        "nav_from": NAV_FROM[page],
                    }
                    if browser
                    else {}
                ),
            }
            for label, script, browser in zip(labels, scripts, browsers)
            for page in names
        ]
        figures = {
            "drivers": args.drivers,
            "decisions": args.decisions,
            "fleet": args.fleet,
            "repeat": args.repeat,
            "pages": rows,
        }
        if browsers[0]:
            figures["results_curves_s"] = {label: b["curves"][0] for label, b in zip(labels, browsers)}
        if floor:
            figures["floor_s"] = {
                "median": statistics.median(floor),
                "min": min(floor),
                "max": max(floor),
                "visits": len(floor),
            }
            print(
                f"\nfloor: a one-chart Streamlit page (title + a 3-point Plotly chart) opened in a new tab of a "
                f"new browser context, visited in turn with the pages: median {statistics.median(floor):.3f} s "
                f"(min {min(floor):.3f}, max {max(floor):.3f}, {len(floor)} visits)"
            )
        write_result(args.out, figures)


if __name__ == "__main__":
    main()
