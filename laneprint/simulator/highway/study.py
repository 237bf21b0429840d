"""A whole highway-env study: drivers, one recording per driver and section, the ground truth.

`simulate_highway_study(settings, seed)` is deterministic: driver perturbations come
from `SeedSequence(seed, spawn_key=(0,))`, the sections' traffic densities (the same
for every driver, as in a study where everyone drives the same sections) from
`SeedSequence(seed, spawn_key=(2,))`, each recording's traffic and its driver's
moment-to-moment variability from `SeedSequence(seed, spawn_key=(1, driver, section))`,
so a recording depends on neither the others nor `jobs`. highway_env is imported by
the recordings only (in the worker processes with `jobs` > 1).
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from typing import TYPE_CHECKING, Any, Optional

import numpy as np
import pandas as pd

from laneprint.progress import ProgressFn, report
from laneprint.simulator.highway.settings import HighwaySettings, simulator_text
from laneprint.simulator.highway.styles import STYLE_PARAMS, HighwayDriver, make_highway_drivers, true_parameter_ari
from laneprint.simulator.study import GENERATOR, session_id

if TYPE_CHECKING:
    from laneprint.simulator.highway.section import SectionLog

ENGINE = "highway"
ENGINE_VERSION = 1

Recording = tuple[dict[str, Any], pd.DataFrame, pd.DataFrame]


@dataclass
class HighwayStudy:
    """A generated study: `recordings` as (meta, ego, traffic) and its `ground_truth` (JSON-ready)."""

    recordings: list[Recording]
    ground_truth: dict[str, Any]
    settings: HighwaySettings
    seed: int

    @property
    def decisions(self) -> list[dict[str, Any]]:
        """Every lane-change decision, pressed or missed."""
        return self.ground_truth["decisions"]

    @property
    def presses(self) -> list[dict[str, Any]]:
        """The decisions with a button press (what the logs show)."""
        return [d for d in self.decisions if d["pressed"]]


def run_seed(seed: int, driver_index: int, section_index: int) -> np.random.SeedSequence:
    """The seed sequence of one recording (traffic, road and the driver's variability)."""
    return np.random.SeedSequence(seed, spawn_key=(1, driver_index, section_index))


def section_densities(settings: HighwaySettings, seed: int) -> list[list[float]]:
    """Per section, the vehicles per km of each traffic stream (home lane, rightmost first).

    A stream's mean spacing in seconds at the limit is drawn from `lane_spacing_s`, stratified: the range
    is cut into as many equal strata as there are sections and every section draws from a different one
    (in a random order), so every study has light and busy sections.
    """
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2,)))
    m = len(settings.speed_limits_kph)
    out = [[0.0] * settings.n_lanes for _ in range(m)]
    for k in range(settings.n_lanes):
        lo, hi = settings.by_lane(settings.lane_spacing_s, k)
        for j, stratum in enumerate(rng.permutation(m)):
            spacing_s = lo + (stratum + rng.uniform()) / m * (hi - lo)
            out[j][k] = round(float(1000.0 / (spacing_s * settings.speed_limits_kph[j] / 3.6)), 3)
    return out


def study_drivers(settings: HighwaySettings, seed: int) -> list[HighwayDriver]:
    """The study's drivers and their true parameters (no simulation)."""
    return make_highway_drivers(
        settings.n_drivers,
        settings.perturbation_sd,
        np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,))),
        settings.style_shares,
    )


def _run_one(
    settings: HighwaySettings, driver: HighwayDriver, limit: float, density: list[float], seed: int, i: int, j: int
) -> "SectionLog":
    """One (driver, section) recording (also the entry point of a worker process)."""
    from laneprint.simulator.highway.section import run_section

    return run_section(settings, driver.params, limit, density, run_seed(seed, i, j))


def check_available() -> None:
    """Raise `UserError` with the install hint when highway-env cannot be imported."""
    from laneprint.errors import SettingError

    try:
        import highway_env  # noqa: F401
    except ImportError:
        raise SettingError(
            "{0} highway needs highway-env: pip install -e '.[highway]' (highway-env==1.12.1)", "engine"
        ) from None


def simulate_highway_study(
    settings: Optional[HighwaySettings] = None, seed: int = 0, progress: Optional[ProgressFn] = None, jobs: int = 1
) -> HighwayStudy:
    """Drive every (driver, section) in highway-env and collect the recordings and the ground truth."""
    settings = settings or HighwaySettings()
    drivers = study_drivers(settings, seed)
    densities = section_densities(settings, seed)
    tasks = [(i, j, d, float(lim)) for i, d in enumerate(drivers) for j, lim in enumerate(settings.speed_limits_kph)]
    logs: dict[tuple[int, int], SectionLog] = {}
    report(progress, 0, len(tasks), "starting highway-env")
    if jobs <= 1:
        for i, j, d, lim in tasks:
            report(progress, len(logs), len(tasks), f"highway-env {session_id(d.driver_id, lim)}")
            logs[i, j] = _run_one(settings, d, lim, densities[j], seed, i, j)
    else:
        with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
            futures = {
                pool.submit(_run_one, settings, d, lim, densities[j], seed, i, j): (i, j) for i, j, d, lim in tasks
            }
            for fut in as_completed(futures):
                logs[futures[fut]] = fut.result()
                report(progress, len(logs), len(tasks), "highway-env runs")
    report(progress, len(tasks), len(tasks), "simulated")
    return _collect(settings, seed, drivers, tasks, logs)


def _collect(
    settings: HighwaySettings,
    seed: int,
    drivers: list[HighwayDriver],
    tasks: list,
    logs: dict[tuple[int, int], "SectionLog"],
) -> HighwayStudy:
    version = next(iter(logs.values())).version if logs else ""
    simulator = simulator_text(version, settings.n_lanes)
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
                "n_samples": len(log.ego),
                "duration_s": float(log.ego["t_s"].iloc[-1]),
                "n_presses": sum(dec["pressed"] for dec in log.decisions),
                "n_decisions": len(log.decisions),
                "n_vehicles": log.n_vehicles,
                "n_collisions": len(log.collision_t_s),
                "collision_t_s": log.collision_t_s,
                "n_traffic_collisions": log.n_traffic_collisions,
                "density_per_km": log.density_per_km,
            }
        )
        for k, dec in enumerate(log.decisions):
            decisions.append({"session_id": sid, "driver_id": d.driver_id, "index": k, **dec, "speed_limit_kph": lim})
    ground_truth = {
        "generator": GENERATOR,
        "engine": ENGINE,
        "version": ENGINE_VERSION,
        "highway_env_version": version,
        "seed": seed,
        "n_lanes": settings.n_lanes,
        "settings": settings.to_dict(),
        "style_params": STYLE_PARAMS,
        "true_parameter_ari": true_parameter_ari(drivers),
        "drivers": [d.to_dict() for d in drivers],
        "sessions": sessions,
        "decisions": decisions,
    }
    return HighwayStudy(recordings, ground_truth, settings, seed)
