"""Helpers of the dashboard tests (a uniquely named module: every test folder has its own conftest)."""

from __future__ import annotations

import json
import os
import socket
import time
import urllib.request
from pathlib import Path

from laneprint.workspace import Workspace, atomic_write_json

ROOT = Path(__file__).resolve().parents[2]
APP = ROOT / "dashboard" / "app.py"
PAGES = ROOT / "dashboard" / "app_pages"


def page_path(name: str) -> str:
    return str(PAGES / f"{name}.py")


def write_fake_run(
    ws: Workspace,
    run_id: str,
    state: str = "done",
    episodes: int = 6,
    pid: int | None = None,
    summary: list[dict] | None = None,
) -> Path:
    """A run folder as the trainer writes it (config, status, metrics, evaluation)."""
    d = ws.runs_dir / run_id
    d.mkdir(parents=True, exist_ok=True)
    atomic_write_json(
        d / "config.json",
        {
            "run_id": run_id,
            "target": {"kind": "style", "name": "Normal"},
            "reward": "timing",
            "lines_source": "paper",
            "seed": 0,
        },
    )
    atomic_write_json(
        d / "status.json",
        {
            "state": state,
            "pid": pid,
            "episode": episodes if state == "done" else 2,
            "episodes": episodes,
            "started_at": "2026-11-22T00:00:00+00:00",
            "updated_at": "2026-11-22T00:01:00+00:00",
            "message": "",
        },
    )
    with open(d / "metrics.jsonl", "w") as fh:
        for e in range(1, episodes + 1):
            fh.write(
                json.dumps(
                    {
                        "episode": e,
                        "loss": 1.0 / e,
                        "mean_step_reward": 1.0 + e / 10,
                        "epsilon": 0.8,
                        "length": 10,
                        "changed": e % 2 == 0,
                        "return": 5.0,
                        "env_steps": 10 * e,
                        "wall_s": 0.1 * e,
                    }
                )
                + "\n"
            )
    if state == "done":
        atomic_write_json(
            d / "evaluation.json",
            {
                "summary": summary
                or [
                    {"who": "agent", "recall": 0.96, "balanced_accuracy": 0.9, "timing_mae_s": 0.5},
                    {"who": "greedy", "recall": 0.84, "balanced_accuracy": 0.7, "timing_mae_s": 1.5},
                    {"who": "driver", "recall": 1.0, "balanced_accuracy": 1.0, "timing_mae_s": 0.0},
                ]
            },
        )
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
    from rl.learners.dqn import DQNSettings
    from rl.problem.env import EnvConfig
    from rl.problem.rewards import RewardSettings
    from rl.runs import Target, resolve_lines, train_run

    target = Target("style", "Normal")
    env = EnvConfig(lines=resolve_lines(ws, target, "analysis"), reward=RewardSettings())
    return train_run(ws, target, env, DQNSettings(episodes=episodes, seed=seed), run_id=run_id)


def log_bytes(tmp_path: Path, driver_id: str | None = "D77", fmt: str = "csv", seed: int = 0) -> bytes:
    """A small valid log (one press, two traffic cars) as the bytes of a CSV or MCAP file."""
    from tests.support.synthetic_decisions import make_recording
    from ingest.writers import write_csv, write_mcap

    meta, ego, traffic = make_recording(
        12.0,
        10.0,
        21.0 + seed,
        [(0, 0), (6.0, 1)],
        presses=[(4.0, 0.5, "left")],
        vehicles=[("lead", 35.0, 17.0, 0, 4.5), ("nb", -25.0, 19.0, 1, 4.5)],
        recording_id=f"s{seed}",
        driver_id=driver_id or "",
    )
    meta = {k: v for k, v in meta.items() if k != "recording_id" and (k != "driver_id" or driver_id)}
    path = tmp_path / f"log_{seed}.{fmt}"
    (write_csv if fmt == "csv" else write_mcap)(path, meta, ego, traffic)
    return path.read_bytes()


# --- real server + headless Chromium (see ../shared/recipes/BROWSER_TESTS.md) ---------------

CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
SHOT_DIR = ROOT / "test-results" / "dashboard"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_healthy(url: str, proc, timeout: float = 60) -> None:
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


# --- cross-validation results as `laneprint crossval` stores them -------------------------

CROSSVAL_ID = "20261130-120000-000000-normal-timing-s0"


def crossval_result(
    run_id: str | None = "Normal-seed0",
    crossval_id: str = CROSSVAL_ID,
    target: tuple[str, str] = ("style", "Normal"),
    episodes: int = 30,
) -> dict:
    """A hand-made `result.json` of `laneprint crossval` (the fields the dashboard reads)."""
    return {
        "crossval_id": crossval_id,
        "target": {"kind": target[0], "name": target[1]},
        "run_id": run_id,
        "lines_source": "analysis",
        "created_at": "2026-11-30T12:00:00+00:00",
        "drivers": ["D01", "D02"],
        "line_drivers": ["D01"],
        "folds": 2,
        "settings": {"folds": 2, "split": "session", "seed": 0, "n_bootstrap": 200, "lines_from": "typical"},
        "env": {"scenes": "random", "observation": "positions", "reward": {"name": "timing"}},
        "dqn": {"episodes": episodes, "seed": 0},
        "summary": [
            {
                "who": "agent",
                "balanced_accuracy": 0.8,
                "balanced_accuracy_ci": [0.75, 0.9],
                "recall": 0.7,
                "specificity": 0.9,
                "timing_mae_s": 1.5,
                "timing_mae_ci": [1.0, 2.25],
                "never_rate": 0.1,
                "n_decisions": 40,
                "n_states": 600,
            },
            {
                "who": "greedy",
                "balanced_accuracy": 0.6,
                "balanced_accuracy_ci": [0.55, 0.62],
                "recall": 1.0,
                "specificity": 0.2,
                "timing_mae_s": 4.0,
                "timing_mae_ci": [3.5, 4.5],
                "never_rate": 0.0,
                "n_decisions": 40,
                "n_states": 600,
            },
            {
                "who": "imitation",
                "balanced_accuracy": 0.85,
                "balanced_accuracy_ci": [0.8, 0.88],
                "recall": 0.8,
                "specificity": 0.9,
                "timing_mae_s": None,
                "timing_mae_ci": None,
                "never_rate": 0.05,
                "n_decisions": 40,
                "n_states": 600,
            },
        ],
        "per_fold": [
            {
                "fold": 0,
                "sessions": ["a"],
                "n_train_decisions": 20,
                "n_decisions": 21,
                "agent_balanced_accuracy": 0.78,
                "greedy_balanced_accuracy": 0.61,
                "imitation_balanced_accuracy": 0.84,
            },
            {
                "fold": 1,
                "sessions": ["b"],
                "n_train_decisions": 21,
                "n_decisions": 19,
                "agent_balanced_accuracy": 0.82,
                "greedy_balanced_accuracy": 0.59,
                "imitation_balanced_accuracy": 0.86,
            },
        ],
        "n_decisions_total": 50,
        "n_decisions_scored": 40,
        "scored_share": 0.8,
        "unscored": {"no_press": 7, "following": 3},
        "notes": ["fold 0: t_nf: too few presses; the full analysis's line used"],
    }


def write_fake_crossval(ws: Workspace, result: dict, of_run: bool = True) -> Path:
    """`crossval/<id>/result.json`, and `runs/<run_id>/crossval.json` when `of_run` (as `--run` leaves it)."""
    folder = ws.root / "crossval" / result["crossval_id"]
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_json(folder / "result.json", result)
    if of_run and result.get("run_id"):
        atomic_write_json(ws.runs_dir / result["run_id"] / "crossval.json", result)
    return folder


# --- fleets as `laneprint train --drivers all` leaves them (see rl/fleet/store.py) ----------------


def write_fake_fleet(
    ws: Workspace,
    fleet_id: str,
    drivers: list[str],
    seeds: tuple[int, ...] = (0,),
    state: str = "done",
    pid: int | None = None,
    evaluated: int | None = None,
) -> list[str]:
    """`fleets/<id>/fleet.json` and one run folder per (driver, seed); the first `evaluated` runs
    (all by default) are done and evaluated, the rest running at episode 10 of 50. Agent BA rises
    with the driver's index, greedy's stays at 0.6, imitation's at 0.7."""
    runs = []
    for i, driver in enumerate(drivers):
        for seed in seeds:
            run_id = f"{fleet_id}-{driver}-s{seed}"
            done = evaluated is None or len(runs) < evaluated
            d = ws.runs_dir / run_id
            d.mkdir(parents=True, exist_ok=True)
            atomic_write_json(
                d / "config.json",
                {
                    "run_id": run_id,
                    "target": {"kind": "driver", "name": driver},
                    "reward": "timing",
                    "lines_source": "analysis",
                    "seed": seed,
                    "fleet_id": fleet_id,
                    "dqn": {"episodes": 50},
                    "lines": {"t_f": [0.3, -1.0], "t_nf": [0.3, -1.5], "dv_nb": [0.1, -1.0]},
                },
            )
            atomic_write_json(
                d / "status.json",
                {
                    "state": "done" if done else "running",
                    "pid": pid,
                    "episode": 50 if done else 10,
                    "episodes": 50,
                    "started_at": "2026-11-30T10:00:00+00:00",
                    "updated_at": "2026-11-30T10:01:00+00:00",
                    "message": "",
                },
            )
            if done:
                ba = 0.62 + 0.3 * i / max(1, len(drivers) - 1)
                atomic_write_json(
                    d / "evaluation.json",
                    {
                        "summary": [
                            {"who": "agent", "recall": 0.97, "balanced_accuracy": ba, "timing_mae_s": 0.5},
                            {"who": "greedy", "recall": 1.0, "balanced_accuracy": 0.6, "timing_mae_s": 3.0},
                            {"who": "imitation", "recall": 0.8, "balanced_accuracy": 0.7, "timing_mae_s": None},
                            {"who": "driver", "recall": 1.0, "balanced_accuracy": 1.0, "timing_mae_s": 0.0},
                        ]
                    },
                )
            runs.append(run_id)
    folder = ws.root / "fleets" / fleet_id
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_json(
        folder / "fleet.json",
        {
            "fleet_id": fleet_id,
            "created_at": "2026-11-30T10:00:00+00:00",
            "targets": [{"kind": "driver", "name": d} for d in drivers],
            "seeds": list(seeds),
            "runs": runs,
            "backend": "local",
            "state": state,
            "pid": pid,
            "updated_at": "2026-11-30T10:01:00+00:00",
            "message": "",
        },
    )
    return runs
