"""The whole synthetic study: drivers, their recordings, and the ground truth.

`simulate_study(settings, seed)` is pure: the same settings and seed give identical
frames (one `numpy.random.Generator` is threaded through everything).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
import pandas as pd

from laneprint.progress import ProgressFn, report
from laneprint.simulator.config import (
    CASE_CANCELLED,
    CASE_CLEAN,
    CASE_FAR_FOLLOWER,
    CASE_NO_TARGET_LEADER,
    CASE_SLOWED,
    StudySettings,
)
from laneprint.simulator.drivers import make_drivers
from laneprint.simulator.recording import RecordingBuilder

GENERATOR = "laneprint.simulator"
GENERATOR_VERSION = 1

Recording = tuple[dict[str, Any], pd.DataFrame, pd.DataFrame]


@dataclass
class Study:
    """A generated study: `recordings` as (meta, ego, traffic) and its `ground_truth` (JSON-ready)."""

    recordings: list[Recording]
    ground_truth: dict[str, Any]
    settings: StudySettings
    seed: int

    @property
    def decisions(self) -> list[dict[str, Any]]:
        return self.ground_truth["decisions"]

    def decisions_frame(self) -> pd.DataFrame:
        """The ground-truth decisions as a flat table (nested fields joined with '.')."""
        return decisions_frame(self.ground_truth)


def decisions_frame(ground_truth: dict[str, Any]) -> pd.DataFrame:
    """Flatten `ground_truth["decisions"]` (e.g. `line.t_f`, `from_preference.dv_nb`) into a DataFrame.

    Adds each decision's driver `style` and `typical` flag.
    """
    df = pd.json_normalize(ground_truth["decisions"], sep=".")
    drivers = pd.DataFrame(
        [{"driver_id": d["driver_id"], "style": d["style"], "typical": d["typical"]} for d in ground_truth["drivers"]]
    )
    return df.merge(drivers, on="driver_id", how="left")


def session_id(driver_id: str, speed_limit_kph: float) -> str:
    """`D03_S80`: driver and section."""
    return f"{driver_id}_S{int(round(speed_limit_kph))}"


def case_plan(settings: StudySettings, rng: np.random.Generator) -> list[list[str]]:
    """Per section, the shuffled cases of one driver's decisions (exact shares, rounded)."""
    n = settings.decisions_per_driver
    counts = {
        CASE_SLOWED: round(settings.share_slowed * n),
        CASE_NO_TARGET_LEADER: round(settings.share_no_target_leader * n),
        CASE_FAR_FOLLOWER: round(settings.share_far_follower * n),
        CASE_CANCELLED: round(settings.share_cancelled * n),
    }
    while sum(counts.values()) > n:  # tiny studies: drop untidy cases before clean ones vanish
        counts[max(counts, key=counts.__getitem__)] -= 1
    counts[CASE_CLEAN] = n - sum(counts.values())
    cases = [c for c, k in counts.items() for _ in range(k)]
    cases = [cases[i] for i in rng.permutation(len(cases))]
    k = len(settings.speed_limits_kph)
    per = [n // k + (1 if i < n % k else 0) for i in range(k)]
    per = [per[i] for i in rng.permutation(k)]
    out, start = [], 0
    for m in per:
        out.append(cases[start : start + m])
        start += m
    return out


def simulate_study(
    settings: Optional[StudySettings] = None, seed: int = 0, progress: Optional[ProgressFn] = None
) -> Study:
    """Generate every recording of the study and its ground truth."""
    settings = settings or StudySettings()
    rng = np.random.default_rng(seed)
    drivers = make_drivers(settings, rng)
    simulator = f"{GENERATOR} v{GENERATOR_VERSION} (seed {seed})"
    recordings: list[Recording] = []
    decisions: list[dict[str, Any]] = []
    sessions: list[dict[str, Any]] = []
    total = len(drivers) * len(settings.speed_limits_kph)
    for driver in drivers:
        plan = case_plan(settings, rng)
        for limit, cases in zip(settings.speed_limits_kph, plan):
            sid = session_id(driver.driver_id, limit)
            report(progress, len(recordings), total, f"simulating {sid}")
            builder = RecordingBuilder(settings, rng, driver, limit, sid, simulator)
            for case in cases:
                builder.add_episode(case)
            rec = builder.finish()
            recordings.append((rec.meta, rec.ego, rec.traffic))
            decisions.extend(rec.decisions)
            sessions.append(
                {
                    "session_id": sid,
                    "driver_id": driver.driver_id,
                    "speed_limit_kph": float(limit),
                    "n_samples": len(rec.ego),
                    "duration_s": float(rec.ego["t_s"].iloc[-1]),
                    "n_decisions": len(rec.decisions),
                    "n_vehicles": int(rec.traffic["vehicle_id"].nunique()),
                }
            )
    report(progress, total, total, "simulated")
    ground_truth = {
        "generator": GENERATOR,
        "version": GENERATOR_VERSION,
        "seed": seed,
        "settings": settings.to_dict(),
        "drivers": [d.to_dict() for d in drivers],
        "sessions": sessions,
        "decisions": decisions,
    }
    return Study(recordings, ground_truth, settings, seed)
