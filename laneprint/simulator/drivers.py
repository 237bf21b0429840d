"""The driver behaviour model: personal lines `I = A * v_e + b` plus human variability.

Three drivers are the paper's typical drivers (exactly Table 1, one per style); the
others belong to a style and have its line moved by a small seeded amount: the slope
scaled by `1 + N(0, driver_slope_rel_sd)` and the value at the mid speed of the
study shifted by `N(0, driver_shift_sd)` (clipped to +-2 sd), so styles stay apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from laneprint.reference import INDICATORS, PAPER_TABLE1, STYLES, kph_to_mps
from laneprint.simulator.config import StudySettings


@dataclass(frozen=True)
class Driver:
    """One simulated driver and the lines its decisions scatter around."""

    driver_id: str
    style: str  # Defensive / Normal / Aggressive
    typical: bool  # the style's typical driver (lines exactly Table 1)
    lines: dict[str, tuple[float, float]]  # indicator -> (A, b), I = A * v_e[m/s] + b

    def line_value(self, indicator: str, v_e: float) -> float:
        """The driver's noise-free preference for `indicator` at ego speed `v_e` [m/s]."""
        a, b = self.lines[indicator]
        return a * v_e + b

    def to_dict(self) -> dict:
        return {
            "driver_id": self.driver_id,
            "style": self.style,
            "typical": self.typical,
            "lines": {k: {"A": a, "b": b} for k, (a, b) in self.lines.items()},
        }


def style_counts(n_drivers: int, shares: tuple[float, float, float]) -> dict[str, int]:
    """Drivers per style: largest remainder of `shares`, at least one per style when n >= 3."""
    if n_drivers < 3:
        order = ("Normal", "Defensive", "Aggressive")
        return {s: int(s in order[:n_drivers]) for s in STYLES}
    raw = np.asarray(shares, dtype=float) / sum(shares) * n_drivers
    counts = np.maximum(np.floor(raw).astype(int), 1)
    while counts.sum() < n_drivers:
        counts[int(np.argmax(raw - counts))] += 1
    while counts.sum() > n_drivers:
        counts[int(np.argmax(np.where(counts > 1, counts - raw, -np.inf)))] -= 1
    return dict(zip(STYLES, counts.tolist()))


def style_order(n_drivers: int, shares: tuple[float, float, float]) -> list[str]:
    """Styles of drivers 1..n: round-robin over the styles, skipping those whose count is used up."""
    left = dict(style_counts(n_drivers, shares))
    out: list[str] = []
    while len(out) < n_drivers:
        for style in STYLES:
            if left[style] > 0:
                out.append(style)
                left[style] -= 1
    return out


def driver_ids(n_drivers: int) -> list[str]:
    """D01, D02, ... (wider when there are 100 drivers or more)."""
    width = max(2, len(str(n_drivers)))
    return [f"D{i:0{width}d}" for i in range(1, n_drivers + 1)]


def make_drivers(settings: StudySettings, rng: np.random.Generator) -> list[Driver]:
    """The study's drivers, styles assigned in a random order; the first of each style is typical."""
    counts = style_counts(settings.n_drivers, settings.style_shares)
    styles = [s for s in STYLES for _ in range(counts[s])]
    styles = [styles[i] for i in rng.permutation(len(styles))]
    v_mid = kph_to_mps(float(np.mean(settings.speed_limits_kph)))
    drivers: list[Driver] = []
    seen: set[str] = set()
    for did, style in zip(driver_ids(settings.n_drivers), styles):
        typical = style not in seen
        seen.add(style)
        table = PAPER_TABLE1[style]
        if typical:
            lines = {k: (float(table[k][0]), float(table[k][1])) for k in INDICATORS}
        else:
            lines = {}
            for k, sd in zip(INDICATORS, settings.driver_shift_sd):
                a0, b0 = table[k]
                a = a0 * (
                    1.0
                    + float(
                        np.clip(
                            rng.normal(0.0, settings.driver_slope_rel_sd),
                            -2 * settings.driver_slope_rel_sd,
                            2 * settings.driver_slope_rel_sd,
                        )
                    )
                )
                shift = float(np.clip(rng.normal(0.0, sd), -2 * sd, 2 * sd))
                b = a0 * v_mid + b0 + shift - a * v_mid
                lines[k] = (round(a, 4), round(b, 4))
        drivers.append(Driver(did, style, typical, lines))
    return drivers
