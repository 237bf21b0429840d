"""Settings of the analysis stage (`laneprint analyze`), in one typed dataclass.

Decision extraction (`indicators/`), per-driver statistics and style clustering
(`clustering/`) all read the same `AnalysisSettings`; it is stored whole in
`analysis/meta.json` beside the results.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

from laneprint.reference import FAR_FOLLOWER_M, SPEED_LIMITS_KPH

#: How a driver's clustering-feature line can be fitted (`AnalysisSettings.feature_fit`).
FEATURE_FITS: tuple[str, ...] = ("huber", "theilsen", "ols", "median", "trimmed")
#: Named sets of clustering indicators (`AnalysisSettings.features`).
INDICATOR_SETS: dict[str, tuple[str, ...]] = {
    "ttc": ("t_f", "t_nf"),
    "paper": ("t_f", "t_nf", "dv_nb"),
    "headway": ("gap_f", "thw_f"),
    "acceptance": ("gap_f", "thw_f", "gap_nf", "gap_nb", "thw_nb"),
    "all": ("t_f", "t_nf", "gap_f", "thw_f", "gap_nf", "gap_nb", "thw_nb"),
    # gap_f is left out: it is thw_f times the ego speed, the same press read twice, which
    # outvoted the headway kept (README, issue 18: acceptance studies 625 and 627 at 15 min)
    "following": ("thw_follow", "thw_f"),
}
#: `AnalysisSettings.features` values for which the data chooses the reading (`clustering.choice`).
CHOSEN_BY_DATA: tuple[str, ...] = ("auto", "separated", "consensus", "reliable", "heldout", "behaviour")
#: The sets 'auto' chooses from. 'following' holds the headway accepted at the press and the
#: headway kept over the whole drive; where a study has no steady following, its thw_follow is
#: imputed alike for every driver and it reads as thw_f, so 'headway' is not a candidate.
AUTO_CANDIDATES: tuple[str, ...] = ("ttc", "following", "acceptance", "all")
#: How a driver's indicator line is fitted (`AnalysisSettings.driver_lines`).
DRIVER_LINES: tuple[str, ...] = ("ols", "mixed")
#: What a flagged line becomes in the reference lines (`AnalysisSettings.flagged_lines`).
FLAGGED_LINES: tuple[str, ...] = ("level", "ols")


@dataclass(frozen=True)
class AnalysisSettings:
    """Everything that changes what `analyze` computes. Units in brackets."""

    # --- decision points ---------------------------------------------------
    step_s: float = 0.5
    """Spacing of the 'not yet' (keep) states before each press [s]."""
    max_approach_s: float = 15.0
    """Keep states go back at most this far before the press [s]."""
    settled_lateral_mps: float = 0.1
    """A lane change has ended when the ego's lateral speed (from ego_y) drops below
    this after the lane flip; keep states of the next press start there [m/s]."""
    max_settle_s: float = 5.0
    """If the lateral speed does not settle within this after the flip, or ego_y is
    not logged, the lane change ends `settle_s` after the flip [s]."""
    settle_s: float = 1.0
    """Fallback: keep states start this long after the previous lane flip [s]."""
    same_leader_approach: bool = True
    """Keep states go back only while the ego-lane leader is the one the driver faces
    at the press: the approach to that leader. Before it the driver was deciding about
    another scene (a leader since gone), so those states say nothing about waiting for
    this gap. Presses with no leader keep the time-based window."""
    lane_change_lookahead_s: float = 8.0
    """A lane change counts as following a press if the lane flips within this time
    after it (and before the next press) [s]."""
    far_follower_m: float = FAR_FOLLOWER_M
    """A target-lane follower whose gap to the ego exceeds this has no influence
    (dv_nb_status 'far') [m]; the study uses 100 m."""
    traffic_tolerance_s: float = 0.5
    """A traffic vehicle's latest sample must be at most this old at a state's time
    to count as present [s]; its position is carried forward with its speed."""

    follow_step_s: float = 0.5
    """Spacing of the states at which the whole drive is read for steady car following
    (`indicators.following`) [s]."""
    follow_dv_mps: float = 1.0
    """A state is steady following when the ego's speed is within this of its leader's [m/s]."""
    follow_min_speed_mps: float = 5.0
    """...and the ego drives at least this fast (a queue at walking pace says nothing of a
    headway kept) [m/s]."""
    follow_below_free: float = 0.95
    """...and the ego is held back: slower than this share of its free speed (the 90th
    percentile of its speed over the recording)."""
    follow_min_s: float = 2.0
    """A steady-following episode (same leader, same lane) shorter than this is dropped [s]."""

    # --- per-driver statistics -----------------------------------------------
    alpha: float = 0.05
    """Significance level of the correlation tests and the width of the
    confidence/prediction intervals (1 - alpha)."""
    min_fit_points: int = 5
    """Fewer defined points than this: no fit / no correlation, with a reason."""
    min_speed_spread_mps: float = 1.0
    """A driver's decision speeds must span at least this (max - min) for a fit [m/s]."""
    min_fit_r2: float = 0.1
    """A fitted line with R² below this is flagged: speed explains almost nothing of the
    indicator, so the line is no reference to steer by."""
    min_flag_points: int = 10
    """A fitted line on fewer points than this is flagged."""
    driver_lines: str = "ols"
    """How each driver's indicator line is fitted: 'ols' (its own presses alone, the study's way)
    or 'mixed' (a mixed model over every driver with a random intercept and slope per driver,
    `indicators.mixed`: a driver with few presses borrows strength from the others)."""
    flagged_lines: str = "level"
    """What a style's or driver's reference line is when its OLS fit is flagged: 'level'
    (A = 0, b = the median of the driver's values: the level it keeps, whatever the
    speed) or 'ols' (the fit as it is, the study's way)."""
    fit_far_followers: bool = False
    """Include dv_nb values whose follower is 'far' in the fits and correlations."""
    min_closing_mps: float = 1.0
    """A TTC whose closing speed is below this is left out of the fits and
    correlations (reason 'following'; the value stays in the table): the driver is
    following a slow leader, and gap / (tiny closing speed) gives tens or hundreds of
    seconds that say nothing about the gap the driver accepts [m/s]."""
    max_receding_mps: float | None = 1.0
    """A front gap or time headway (gap_f, thw_f) whose leader pulls away faster than this
    is left out of the fits and features (reason 'receding'; the value stays in the
    table): the driver is not held by that leader, so the gap says nothing about the gap
    it accepts (typically a return to the right, where the car ahead in the fast lane is
    whatever traffic put there). None: every defined value is used. On the acceptance
    family's development seeds (SUMO 100-105, 200-211, 220-231) the styles came out right
    on 27 of 29 with the rule and 25 of 30 without it (the median front gap and headway
    at the presses, k-means); any threshold from 0.5 to 2 m/s gave the same [m/s]."""
    fit_cancelled: bool = True
    """Include presses not followed by a lane change in the fits (the press is
    still the driver's judgement of the gap)."""

    # --- styles ----------------------------------------------------------------
    features: str = "consensus"
    """What the styles are read by: 'consensus' (the default: the styles the readings with the
    most say agree on, indicator sets and behaviour readings alike, a reading's say being how well
    separated and stable it is and how much the other parameters agree with it; chosen one world
    out on the zoo of worlds), 'separated' (the one best separated and most stable of those
    readings), 'auto' (the indicator set whose styles are best separated and most
    stable, the study's TTCs unless another is clearly better), 'reliable' (the two behaviour parameters in which the drivers differ most reliably),
    'heldout' (the reading whose styles best predict the drivers' held-out decisions and
    following headways), 'behaviour' (the drivers' critical gaps, following headway and free speed),
    'behaviour:PARAMS' (e.g. behaviour:thw_nb+thw_follow), an indicator set of
    `INDICATOR_SETS` ('ttc': the study's t_f and t_nf, 'paper': its three, 'headway',
    'acceptance', 'all', 'following'), or a comma-separated list of indicators."""
    auto_margin: float = 1.25
    """With `features='auto'`, another set replaces the study's TTCs only when its score
    (silhouette x stability) is at least this many times theirs (`clustering.selection`)."""
    k: int = 3
    """Number of styles when `choose_k` is None."""
    choose_k: str | None = None
    """None (use `k`), 'silhouette' or 'bic': choose k in `k_range`."""
    k_range: tuple[int, int] = (2, 6)
    """Smallest and largest k tried when choosing k (capped by the number of drivers - 1)."""
    feature_indicators: tuple[str, ...] = ("t_f", "t_nf")
    """Indicators whose per-driver lines make the clustering features, as resolved from
    `features` by the pipeline. In the 'ttc' set dv_nb is left out: its lines are set by
    the traffic (slope ~1 for every style in Table 1) and carry no style information."""
    feature_speeds_kph: tuple[float, ...] = tuple(float(v) for v in SPEED_LIMITS_KPH)
    """Speeds at which each driver's line is evaluated to make the features [km/h]."""
    feature_fit: str = "huber"
    """How a driver's line is fitted for the features: 'huber' (Huber M-estimator, as
    statsmodels RLM; default), 'theilsen', 'ols' or 'median' (a flat line at the
    median: the driver's level, no speed dependence). On harder synthetic studies
    (benchmarks/analysis.py --messy) Huber on log TTC recovered the styles most often
    (10 of 11 seeds, median 9 of 11). On SUMO studies (seeds 1-23 and 30-39) Huber
    recovered 33 of 34 and median all 34: seed 22's Defensive driver has a steep t_nf
    line on 13 presses that reads like a Normal driver's at 60 km/h."""
    acceptance_fit: str = "trimmed"
    """How a driver's gap, headway and relative-speed features are read: 'trimmed' (its
    level: the mean after cutting a fifth of its values at each end, on the log scale; the
    gap or headway it keeps whatever the speed; default), 'median' (the level as a median)
    or a line as `feature_fit`. On the acceptance family's development seeds (SUMO 100-105,
    200-211, 220-231; front gap and headway, leaders pulling away left out) k-means on the
    trimmed means recovered the styles on 29 of 29 studies, on the medians on 27 (a median of
    4-8 presses, as Defensive drivers make, moves more than a trimmed mean); Huber lines
    recovered two of six tuning seeds."""
    feature_log: bool = True
    """Fit the feature lines on log(TTC), log(headway) and log(gap): heavy tails (tens of
    seconds behind a slow leader, gaps of hundreds of metres) then pull far less.
    Features are reported back in the indicators' units."""
    feature_extrapolate: bool = False
    """Read a driver's feature line at every `feature_speeds_kph` even outside the
    speeds of its presses. Off (default): outside them, the line's value at the
    nearest end. On a SUMO study (seed 21) one Defensive driver's t_nf line, fitted
    on 7 presses at 68-87 km/h, extrapolated to 60 km/h read like a Normal driver's,
    and k-means split the Defensive style in two (ARI 0.35; 1.0 without extrapolation)."""
    min_cluster_decisions: int = 8
    """Drivers with fewer usable presses are not used to place the cluster centres;
    they are assigned to the nearest centre afterwards, with a note."""
    min_typical_decisions: int = 15
    """A typical driver needs at least this many presses (else the best available)."""
    n_init: int = 50
    """K-means restarts."""
    n_bootstrap: int = 100
    """Bootstrap resamples of each driver's presses for the 'stability' column, which
    then is the 'confidence' (0 = off: confidence is the mixture posterior)."""
    bootstrap_max_drivers: int = 200
    """Above this many drivers the bootstrap is skipped (it costs ~n_bootstrap times
    the feature fits) and confidence is the mixture posterior."""
    random_state: int = 0
    """Seed of every random choice in clustering."""

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (tuples as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "AnalysisSettings":
        """Settings from `to_dict`'s output (as stored in analysis/meta.json); unknown keys are
        ignored and missing ones take their defaults, so older workspaces read."""
        known = cls.__dataclass_fields__
        values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items() if k in known}
        return cls(**values)

    def with_(self, **changes: Any) -> "AnalysisSettings":
        """A copy with some fields changed."""
        return replace(self, **changes)
