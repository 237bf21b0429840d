"""How `laneprint crossval` splits the sessions and scores the held-out decisions."""

from __future__ import annotations

from dataclasses import dataclass

from laneprint.errors import UserError

SPLITS: tuple[str, ...] = ("session", "section")


@dataclass(frozen=True)
class CrossvalSettings:
    """How the sessions are split and scored."""

    folds: int = 4  # K (with split='section': at most the number of sections)
    split: str = "session"  # 'session' or 'section' (see the module doc)
    seed: int = 0  # fold assignment, bootstrap, imitation classifier; agents use DQNSettings.seed + fold
    n_bootstrap: int = 1000  # resamples of the decisions for the intervals
    lines_from: str = "typical"  # style targets: refit the 'typical' driver's lines, or 'pooled' over members

    def __post_init__(self) -> None:
        if self.split not in SPLITS:
            raise UserError(f"unknown split {self.split!r}: choose one of {', '.join(SPLITS)}")
        if self.folds < 2:
            raise UserError(f"--folds must be at least 2, got {self.folds}")
        if self.lines_from not in ("typical", "pooled"):
            raise UserError(f"lines_from must be 'typical' or 'pooled', got {self.lines_from!r}")
