"""A whole SUMO study: drivers, one SUMO run per driver and section, the ground truth.

`simulate_sumo_study(settings, seed)` is deterministic: driver perturbations come
from `SeedSequence(seed, spawn_key=(0,))`, each run's traffic and SUMO `--seed` from
`SeedSequence(seed, spawn_key=(1, driver, section))`, so a run does not depend on
the others (nor on `jobs`).
"""

from __future__ import annotations

import tempfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Optional

import numpy as np
import pandas as pd

from laneprint.progress import ProgressFn, report
from laneprint.simulator.study import GENERATOR, session_id
from laneprint.simulator.sumo.scenario import build_network, write_routes
from laneprint.simulator.sumo.section import SectionLog, run_section
from laneprint.simulator.sumo.settings import SumoSettings, simulator_text
from laneprint.simulator.sumo.styles import FAMILY_STYLE_PARAMS, SumoDriver, make_sumo_drivers

ENGINE = "sumo"
ENGINE_VERSION = 1

Recording = tuple[dict[str, Any], pd.DataFrame, pd.DataFrame]


@dataclass
class SumoStudy:
    """A generated study: `recordings` as (meta, ego, traffic) and its `ground_truth` (JSON-ready)."""

    recordings: list[Recording]
    ground_truth: dict[str, Any]
    settings: SumoSettings
    seed: int

    @property
    def decisions(self) -> list[dict[str, Any]]:
        return self.ground_truth["decisions"]


def run_seed(seed: int, driver_index: int, section_index: int) -> tuple[np.random.Generator, int]:
    """The traffic generator and SUMO's `--seed` of one run."""
    ss = np.random.SeedSequence(seed, spawn_key=(1, driver_index, section_index))
    sumo_seed = int(ss.generate_state(1)[0] % (2**31 - 1))
    return np.random.default_rng(ss), sumo_seed


def _run_one(
    settings: SumoSettings, driver: SumoDriver, limit: float, seed: int, i: int, j: int, workdir: str
) -> SectionLog:
    """One (driver, section) run in its own scratch folder (also the entry point of a worker process)."""
    folder = Path(workdir) / f"{driver.driver_id}_{j}"
    folder.mkdir()
    net = build_network(folder, settings, limit)
    routes = write_routes(folder / "ego.rou.xml", driver.params, settings)
    rng, sumo_seed = run_seed(seed, i, j)
    return run_section(settings, net, routes, limit, sumo_seed, rng, folder)


def simulate_sumo_study(
    settings: Optional[SumoSettings] = None, seed: int = 0, progress: Optional[ProgressFn] = None, jobs: int = 1
) -> SumoStudy:
    """Run every (driver, section) in SUMO and collect the recordings and the ground truth."""
    settings = settings or SumoSettings()
    drivers = make_sumo_drivers(
        settings.n_drivers,
        settings.perturbation_sd,
        np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,))),
        settings.family,
        settings.style_shares,
    )
    tasks = [(i, j, d, float(lim)) for i, d in enumerate(drivers) for j, lim in enumerate(settings.speed_limits_kph)]
    logs: dict[tuple[int, int], SectionLog] = {}
    report(progress, 0, len(tasks), "starting SUMO")
    with tempfile.TemporaryDirectory(prefix="laneprint-sumo-") as workdir:
        if jobs <= 1:
            for i, j, d, lim in tasks:
                report(progress, len(logs), len(tasks), f"SUMO {session_id(d.driver_id, lim)}")
                logs[i, j] = _run_one(settings, d, lim, seed, i, j, workdir)
        else:
            with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
                futures = {
                    pool.submit(_run_one, settings, d, lim, seed, i, j, workdir): (i, j) for i, j, d, lim in tasks
                }
                for fut in as_completed(futures):
                    logs[futures[fut]] = fut.result()
                    report(progress, len(logs), len(tasks), "SUMO runs")
    report(progress, len(tasks), len(tasks), "simulated")
    return _collect(settings, seed, drivers, tasks, logs)


def _collect(
    settings: SumoSettings, seed: int, drivers: list[SumoDriver], tasks: list, logs: dict[tuple[int, int], SectionLog]
) -> SumoStudy:
    version = next(iter(logs.values())).sumo_version if logs else ""
    simulator = simulator_text(version, settings.family, settings.n_lanes)
    recordings: list[Recording] = []
    sessions: list[dict[str, Any]] = []
    decisions: list[dict[str, Any]] = []
    for i, j, d, lim in tasks:
        log = logs[i, j]
        sid = session_id(d.driver_id, lim)
        meta = {"driver_id": d.driver_id, "session_id": sid, "speed_limit_kph": lim, "simulator": simulator}
        recordings.append((meta, log.ego, log.traffic))
        sessions.append(
            {
                "session_id": sid,
                "driver_id": d.driver_id,
                "speed_limit_kph": lim,
                "sumo_seed": log.sumo_seed,
                "n_samples": len(log.ego),
                "duration_s": float(log.ego["t_s"].iloc[-1]),
                "n_decisions": len(log.lane_changes),
                "n_vehicles": log.n_vehicles,
                "n_collisions": log.n_collisions,
            }
        )
        for k, c in enumerate(log.lane_changes):
            decisions.append(
                {
                    "session_id": sid,
                    "driver_id": d.driver_id,
                    "index": k,
                    "press_t_s": c["press_t_s"],
                    "direction": c["direction"],
                    "from_lane": c["from_lane"],
                    "target_lane": c["target_lane"],
                    "changed": c["changed"],
                    "lane_flip_t_s": c["lane_flip_t_s"],
                    "speed_limit_kph": lim,
                    "v_e_mps": c["v_e_mps"],
                    "sumo_reason": c["sumo_reason"],
                }
            )
    apis = sorted({log.api for log in logs.values()})
    ground_truth = {
        "generator": GENERATOR,
        "engine": ENGINE,
        "version": ENGINE_VERSION,
        "sumo_version": version,
        "sumo_api": ", ".join(apis),
        "seed": seed,
        "family": settings.family,
        "n_lanes": settings.n_lanes,
        "car_follow_model": settings.car_follow_model,
        "settings": settings.to_dict(),
        "style_params": FAMILY_STYLE_PARAMS[settings.family],
        "drivers": [d.to_dict() for d in drivers],
        "sessions": sessions,
        "decisions": decisions,
    }
    return SumoStudy(recordings, ground_truth, settings, seed)
