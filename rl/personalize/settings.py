"""How a driver's agent is made from a base agent and its first K decisions (`laneprint personalize`)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

from laneprint.errors import UserError

BASES: tuple[str, ...] = ("style", "population", "auto", "fit", "blend")
#: How a blend weighs its candidates before their agreement: the style's bootstrap shares, or all alike.
BLEND_PRIORS: tuple[str, ...] = ("share", "equal")
METHODS: tuple[str, ...] = ("finetune", "mix", "own", "none", "unsure")


@dataclass(frozen=True)
class PersonalizeSettings:
    """How a driver's agent is made from the base agent and its first K decisions."""

    base: str = "blend"  # whose agent is the prior: 'style' (the assigned style's members), 'population'
    # (every other driver), 'auto' (the style's when its confidence is at least `min_confidence`, else the
    # population's), 'fit' (the style's when its confidence is at least `min_confidence`, else, of every style's
    # agent and the population's, the one that agrees best with the K decisions) or 'blend' (every style's agent and
    # the population's together: the policy acts on the weighted mean of their normalised advantages, `blend_weights`)
    min_confidence: float = 0.8  # 'auto', 'fit', method 'unsure': the bootstrap share of the assigned style that
    # trusts it (above 1: 'fit' always chooses by agreement, 'unsure' always fine-tunes)
    method: str = "none"  # 'finetune': base weights, then the mix replayed; 'mix': the mix from scratch;
    # 'own': base weights, then the driver's approaches alone; 'none': the base agent as it is;
    # 'unsure': 'finetune' when the style's confidence is below `min_confidence`, else 'none'
    driver_share: float = 0.5  # share of the replayed states that are the driver's (finetune, mix)
    episodes_per_decision: float = 60.0  # fine-tuning episodes per decision of the driver ...
    min_episodes: int = 600  # ... within [min_episodes, max_episodes]
    max_episodes: int = 3000  # ... the most fine-tuning episodes
    learning_rate: float = 0.001  # Adam's step at the start of fine-tuning (falls linearly to a tenth)
    eps_start: float = 0.2  # exploration at the start of fine-tuning (falls to DQNSettings.eps_end)
    learning_starts: int = 500  # transitions before the first fine-tuning update
    n_bootstrap: int = 200  # resamples of the K decisions for the style's confidence
    blend_prior: str = "share"  # 'blend': a style's prior weight is its bootstrap share (times 1 - blend_population),
    # or 'equal': every candidate alike
    blend_population: float = 0.4  # 'blend', prior 'share': the population agent's prior weight (chosen on
    # development studies among 0.2 and other variants, judged on others)
    blend_fit_power: float = 1.0  # 'blend': each prior weight times the candidate's agreement with the K
    # approaches to this power (0: the prior alone)

    def __post_init__(self) -> None:
        if self.base not in BASES:
            raise UserError(f"unknown --from {self.base!r}: choose one of {', '.join(BASES)}")
        if self.method not in METHODS:
            raise UserError(f"unknown method {self.method!r}: choose one of {', '.join(METHODS)}")
        if self.blend_prior not in BLEND_PRIORS:
            raise UserError(f"unknown blend prior {self.blend_prior!r}: choose one of {', '.join(BLEND_PRIORS)}")
        if not 0.0 <= self.blend_population <= 1.0 or self.blend_fit_power < 0:
            raise UserError("blend_population must be in [0, 1] and blend_fit_power at least 0")
        if not 0.0 < self.driver_share <= 1.0:
            raise UserError(f"driver_share must be in (0, 1], got {self.driver_share}")

    def base_for(self, confidence: float) -> str:
        """'style', 'population', 'fit' (choose by agreement) or 'blend': the base for a style assigned with
        `confidence`."""
        if self.base not in ("auto", "fit"):
            return self.base
        if confidence >= self.min_confidence:
            return "style"
        return "population" if self.base == "auto" else "fit"

    def method_for(self, confidence: float) -> str:
        """The method for a style assigned with `confidence` ('unsure' resolves to 'finetune' or 'none')."""
        if self.method != "unsure":
            return self.method
        return "none" if confidence >= self.min_confidence else "finetune"

    def resolved(self, confidence: float) -> PersonalizeSettings:
        """These settings with the method for a style assigned with `confidence`."""
        return replace(self, method=self.method_for(confidence))

    def finetune_episodes(self, k: int) -> int:
        return int(min(self.max_episodes, max(self.min_episodes, round(self.episodes_per_decision * k))))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
