"""Rewards of the decision problem from reference lines ``I = A * v_e + b``.

Two formulations, both built from the study's per-indicator closeness score
(eqs. 10 and 12): with ``e = |i_actual - i_reference(v_e)|``::

    score(e) = 1                   for e <= m
               (n - e) / (n - m)   for m < e < n
               0                   for e >= n

``m, n = 0.2, 2`` [s] for t_f and t_nf, ``0.5, 5`` [m/s] for dv_nb.

- ``paper`` (eqs. 10-13, with the eq. 11 typo fixed): every step, TO CHANGE earns
  ``sum_i score_i`` and NOT TO CHANGE earns ``sum_i (1 - score_i)``, so the two
  always sum to 3. Named terms ``r_f, r_nf, r_nb`` (of the action taken).
- ``timing`` (ours): TO CHANGE earns ``sum_i score_i - change_baseline`` once, as
  the episode ends: the advantage of changing, as in the paper's greedy
  comparison (its ``r_change - r_keep = 2 sum_i score_i - 3``), but paid once
  instead of every step. NOT TO CHANGE earns 0, or ``-pass_penalty`` when a
  change would have earned a positive reward (a gap the driver would take,
  passed up; it widens the margin between the two actions, which otherwise is
  only the discount), and optionally ``-late_penalty_per_s * dt`` once t_f is
  below its reference. The closeness is tolerant (``m`` = 1 s, 2 m/s: about
  the drivers' own spread around their lines), so the agent changes at the
  first moment the whole scene is within the driver's tolerance. The paper's
  constant-sum keep reward instead pays for waiting: with gamma 0.98 keeping
  earns up to 1.5 / (1 - gamma) = 75, more than any change (at most 3).
  Named terms ``r_f, r_nf, r_nb, base`` (on a change), ``pass, late`` (on a keep).
- ``decisions`` (fitted to the drivers): no reference lines at all. It needs
  recorded scenes (``EnvConfig.scenes = 'recorded'``): each episode replays an
  approach the target drove, and TO CHANGE earns ``1 - |t - t_press| /
  press_scale_s`` (floored at -1) once, where ``t_press`` is the driver's own
  press; NOT TO CHANGE earns 0 before the press and ``-pass_penalty`` at and
  after it (the driver's moment, passed up). Its optimal policy on a recorded
  approach is the driver's (keeping 0.5 s before the press is worth ``gamma`` >
  ``1 - 0.5 / press_scale_s``), and on a new approach the agent changes where, in
  the training approaches, similar scenes were the driver's moment; the pass
  penalty tilts scenes that may be either towards changing, as the balanced
  accuracy (one press against 10-30 not-yet states) asks. Named terms ``press``
  (on a change) and ``pass`` (on a keep).

Undefined indicators: without a target-lane leader closing in, or a follower
within `FAR_FOLLOWER_M`, nothing in that lane constrains the change, so t_nf's
or dv_nb's change score is `undefined_score` (default 1, "no objection");
without a closing ego-lane leader there is nothing to pass, so t_f's change
score is `undefined_t_f_score` (default 0, "no reason"). Keep scores are the
complements. This is a rule on the score, not a sentinel
value of the indicator: the indicator itself stays undefined.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import cast

import numpy as np
import pandas as pd

from laneprint.errors import SettingError, UserError
from laneprint.reference import INDICATORS, PAPER_TABLE1
from rl.problem.scene import Indicators

REWARDS: tuple[str, ...] = ("paper", "timing", "decisions")
TERMS: tuple[str, ...] = ("r_f", "r_nf", "r_nb", "base", "pass", "late", "press")

CHANGE, KEEP = 0, 1  # action indices: 0 = TO CHANGE, 1 = NOT TO CHANGE


@dataclass(frozen=True)
class ReferenceLines:
    """The three reference lines of one style or driver: indicator -> (A, b)."""

    t_f: tuple[float, float]  # A [s per m/s], b [s]
    t_nf: tuple[float, float]  # A [s per m/s], b [s]
    dv_nb: tuple[float, float]  # A [1], b [m/s]
    source: str = ""  # provenance, e.g. "Table 1 (Normal)"

    def at(self, v_e: np.ndarray | float) -> dict[str, np.ndarray]:
        """Reference value of each indicator at ego speed(s) `v_e` [m/s]."""
        v = np.asarray(v_e, dtype=float)
        return {k: getattr(self, k)[0] * v + getattr(self, k)[1] for k in INDICATORS}

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> "ReferenceLines":
        return ReferenceLines(tuple(d["t_f"]), tuple(d["t_nf"]), tuple(d["dv_nb"]), d.get("source", ""))

    @staticmethod
    def paper(style: str) -> "ReferenceLines":
        """Table 1 of the study for `style` (Defensive, Normal, Aggressive)."""
        key = style.capitalize()
        if key not in PAPER_TABLE1:
            raise UserError(f"unknown style {style!r}: Table 1 has {', '.join(PAPER_TABLE1)}")
        t = PAPER_TABLE1[key]
        return ReferenceLines(t["t_f"], t["t_nf"], t["dv_nb"], f"Table 1 ({key})")

    @staticmethod
    def from_table(lines: pd.DataFrame, *, style: str | None = None, driver: str | None = None) -> "ReferenceLines":
        """Lines of a style (scope='style', kind='typical') or a driver (scope='driver') from REFERENCE_LINES."""
        if (style is None) == (driver is None):
            raise SettingError("give exactly one of {0} or {1}", "style", "driver")
        if "direction" in lines:  # lines of one direction are the analysis's detail; the agents read both
            lines = lines[lines["direction"].astype(str) == "both"]
        if style is not None:
            sel = lines[
                (lines["scope"] == "style")
                & (lines["name"].str.lower() == style.lower())
                & (lines["kind"] == "typical")
            ]
            what = f"style {style!r}"
        else:
            sel = lines[(lines["scope"] == "driver") & (lines["name"].astype(str) == str(driver))]
            what = f"driver {driver!r}"
        if sel.empty:
            known = sorted(lines.loc[lines["scope"] == ("style" if style else "driver"), "name"].astype(str).unique())
            raise UserError(f"no reference lines for {what} in the analysis (known: {', '.join(known) or 'none'})")
        got = {r["indicator"]: (float(r["A"]), float(r["b"])) for _, r in sel.iterrows()}
        missing = [k for k in INDICATORS if k not in got]
        if missing:
            raise UserError(f"reference lines for {what} lack indicator(s) {', '.join(missing)}")
        source = "; ".join(sorted(set(sel["source"].astype(str))))
        return ReferenceLines(got["t_f"], got["t_nf"], got["dv_nb"], source)


@dataclass(frozen=True)
class RewardSettings:
    """Which reward and its parameters."""

    name: str = "timing"  # 'paper' (eqs. 10-13) or 'timing' (ours, see module doc)
    m_ttc_s: float | None = None  # maximum acceptable error of t_f, t_nf [s]; None: 0.2 paper, 1.0 timing
    n_ttc_s: float = 2.0  # maximum effective error of t_f, t_nf [s]
    m_dv_mps: float | None = None  # maximum acceptable error of dv_nb [m/s]; None: 0.5 paper, 2.0 timing
    n_dv_mps: float = 5.0  # maximum effective error of dv_nb [m/s]
    undefined_score: float = 1.0  # change score of an undefined t_nf or dv_nb: no objection [0-1]
    undefined_t_f_score: float = 0.0  # change score of an undefined t_f: no leader to pass, no reason [0-1]
    change_baseline: float = 2.6  # timing: subtracted from the closeness sum on a change [0-3]
    pass_penalty: float | None = (
        None  # cost of keeping: timing, when a change would pay (0.5); decisions, at/after the press (1.0) [1]
    )
    late_penalty_per_s: float = 0.0  # timing: keep reward once past the reference t_f, negated [1/s]
    press_scale_s: float = 2.0  # decisions: a change's reward falls by 1 per this many s off the press [s]

    def __post_init__(self) -> None:
        if self.name not in REWARDS:
            raise UserError(f"unknown reward {self.name!r}: choose one of {', '.join(REWARDS)}")
        if self.press_scale_s <= 0:
            raise UserError(f"press_scale_s must be positive, got {self.press_scale_s}")
        if self.pass_penalty is None:
            object.__setattr__(self, "pass_penalty", 1.0 if self.name == "decisions" else 0.5)
        if self.m_ttc_s is None:
            object.__setattr__(self, "m_ttc_s", 0.2 if self.name == "paper" else 1.0)
        if self.m_dv_mps is None:
            object.__setattr__(self, "m_dv_mps", 0.5 if self.name == "paper" else 2.0)


def closeness(error: np.ndarray, m: float, n: float) -> np.ndarray:
    """Eq. 10: 1 for e <= m, (n - e) / (n - m) between, 0 for e >= n."""
    return np.clip((n - error) / (n - m), 0.0, 1.0)


def change_scores(ind: Indicators, lines: ReferenceLines, settings: RewardSettings) -> dict[str, np.ndarray]:
    """Per-indicator change score in [0, 1] (the `undefined_*` scores where undefined)."""
    ref = lines.at(ind.v_e)
    m_ttc_s, m_dv_mps = settings.m_ttc_s, settings.m_dv_mps
    assert m_ttc_s is not None and m_dv_mps is not None  # defaults resolved by RewardSettings.__post_init__
    out = {}
    for key, term, ok, m, n, undefined in (
        ("t_f", "r_f", ind.t_f_ok, m_ttc_s, settings.n_ttc_s, settings.undefined_t_f_score),
        ("t_nf", "r_nf", ind.t_nf_ok, m_ttc_s, settings.n_ttc_s, settings.undefined_score),
        ("dv_nb", "r_nb", ind.dv_nb_ok, m_dv_mps, settings.n_dv_mps, settings.undefined_score),
    ):
        err = np.abs(np.where(ok, getattr(ind, key), 0.0) - ref[key])
        out[term] = np.where(ok, closeness(err, m, n), undefined)
    return out


def past_reference(ind: Indicators, lines: ReferenceLines) -> np.ndarray:
    """True where the ego-lane leader is closer (in time) than the reference t_f."""
    ref = lines.at(ind.v_e)["t_f"]
    return ind.t_f_ok & (np.where(ind.t_f_ok, ind.t_f, np.inf) < ref)


def press_reward(t_from_press_s: np.ndarray, settings: RewardSettings) -> np.ndarray:
    """`decisions` reward of TO CHANGE at `t_from_press_s` = t - t_press [s]: 1 at the press, -1 floor."""
    return np.maximum(1.0 - np.abs(t_from_press_s) / settings.press_scale_s, -1.0)


def decisions_step_reward(
    t_from_press_s: np.ndarray, actions: np.ndarray, settings: RewardSettings
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Reward of the actions taken under `decisions` (0 on a keep) and its named terms."""
    is_change = np.asarray(actions) == CHANGE
    t = np.asarray(t_from_press_s, float)
    zero = np.zeros(len(is_change))
    terms = {k: zero for k in TERMS}
    pass_penalty = settings.pass_penalty
    assert pass_penalty is not None  # default resolved by RewardSettings.__post_init__
    terms["press"] = np.where(is_change, press_reward(t, settings), 0.0)
    terms["pass"] = np.where(~is_change & (t >= 0), -pass_penalty, 0.0)
    return terms["press"] + terms["pass"], terms


def action_terms(
    ind: Indicators, lines: ReferenceLines, settings: RewardSettings, dt: float
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Named reward terms of TO CHANGE and of NOT TO CHANGE for every scene."""
    c = change_scores(ind, lines, settings)
    zero = np.zeros_like(ind.v_e, dtype=float)
    change = {**c, "base": zero, "pass": zero, "late": zero, "press": zero}
    if settings.name == "decisions":
        raise ValueError("the 'decisions' reward is paid by recorded presses: use decisions_step_reward")
    if settings.name == "paper":
        keep = {k: 1.0 - v for k, v in c.items()} | {"base": zero, "pass": zero, "late": zero, "press": zero}
    else:
        pass_penalty = settings.pass_penalty
        assert pass_penalty is not None  # default resolved by RewardSettings.__post_init__
        change["base"] = np.full_like(zero, -settings.change_baseline)
        acceptable = sum(c.values()) > settings.change_baseline
        keep = {
            "r_f": zero,
            "r_nf": zero,
            "r_nb": zero,
            "base": zero,
            "pass": np.where(acceptable, -pass_penalty, 0.0),
            "late": np.where(past_reference(ind, lines), -settings.late_penalty_per_s * dt, 0.0),
            "press": zero,
        }
    return change, keep


def action_rewards(
    ind: Indicators, lines: ReferenceLines, settings: RewardSettings, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Total reward of TO CHANGE and of NOT TO CHANGE for every scene."""
    change, keep = action_terms(ind, lines, settings, dt)
    return _total(change), _total(keep)


def _total(terms: dict[str, np.ndarray]) -> np.ndarray:
    """The sum of named reward terms (never none: typeshed's `sum` allows the 0 of an empty sum)."""
    return cast(np.ndarray, sum(terms.values()))


def step_reward(
    ind: Indicators, actions: np.ndarray, lines: ReferenceLines, settings: RewardSettings, dt: float
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Reward of the actions taken (0 = change, 1 = keep) and its named terms."""
    change, keep = action_terms(ind, lines, settings, dt)
    is_change = np.asarray(actions) == CHANGE
    terms = {k: np.where(is_change, change[k], keep[k]) for k in TERMS}
    return _total(terms), terms
