"""The two-lane scene of the decision problem, as arrays over a batch of scenes.

Kept apart from the gymnasium environment (as HighwayEnv keeps its road model
apart) so that the single environment, the vectorised trainer environment, the
replay of recorded approaches and the evaluation all share one model of the
scene, its indicators and its observation.

Vehicles: the ego, ``f`` (leader in the ego lane), ``nf`` (leader in the target
lane) and ``nb`` (follower in the target lane); ``left`` says on which side the
target lane lies (overtaking to the left, or returning to the right). Every vehicle drives at a
constant speed; positions are centres [m], ``hl_*`` is half the summed lengths
of the ego and that vehicle [m], so ``gap = |x - x_e| - hl``.

Indicators follow LOG_FORMAT.md: ``t_f = gap_f / (v_e - v_f)`` [s] when the gap
closes, ``t_nf`` likewise, ``dv_nb = v_e - v_nb`` [m/s] when the follower is
within `far_follower_m`. An undefined indicator is NaN *and* flagged in a
``defined`` mask; the rewards read the mask, never the NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from indicators.acceptance import MIN_SPEED_MPS
from laneprint.reference import FAR_FOLLOWER_M

#: Order of the observation vector (the study's state, section 4.2).
OBS_NAMES: tuple[str, ...] = ("v_e", "x_e", "v_f", "x_f", "v_nf", "x_nf", "v_nb", "x_nb")

#: Lowest value of a normalised observation: the study normalises to (0, 1].
OBS_FLOOR: float = 1e-3


@dataclass
class Scene:
    """A batch of scenes: every field is an array of shape (n,)."""

    v_e: np.ndarray  # ego speed [m/s]
    x_e: np.ndarray  # ego position [m]
    f_present: np.ndarray  # bool: a leader in the ego lane
    v_f: np.ndarray  # [m/s]
    x_f: np.ndarray  # [m]
    hl_f: np.ndarray  # half summed lengths ego + f [m]
    nf_present: np.ndarray  # bool: a leader in the target lane
    v_nf: np.ndarray
    x_nf: np.ndarray
    hl_nf: np.ndarray
    nb_present: np.ndarray  # bool: a follower in the target lane
    v_nb: np.ndarray
    x_nb: np.ndarray
    hl_nb: np.ndarray
    left: np.ndarray | None = None  # bool: the target lane is to the ego's left (default: every scene)

    def __post_init__(self) -> None:
        if self.left is None:  # scenes without a side are the study's: overtaking to the left
            self.left = np.ones(len(self.v_e), dtype=bool)

    def __len__(self) -> int:
        return len(self.v_e)

    def copy(self) -> "Scene":
        return Scene(**{f.name: getattr(self, f.name).copy() for f in fields(self)})

    def take(self, idx: np.ndarray | slice) -> "Scene":
        """The scenes at `idx`, as a new batch."""
        return Scene(**{f.name: np.atleast_1d(getattr(self, f.name)[idx]).copy() for f in fields(self)})

    def put(self, idx: np.ndarray, other: "Scene") -> None:
        """Overwrite the scenes at `idx` with `other` (same length as idx)."""
        for f in fields(self):
            getattr(self, f.name)[idx] = getattr(other, f.name)

    def advance(self, dt: float) -> None:
        """Move every vehicle at its constant speed for `dt` [s] (in place)."""
        self.x_e += self.v_e * dt
        self.x_f += self.v_f * dt
        self.x_nf += self.v_nf * dt
        self.x_nb += self.v_nb * dt

    def as_arrays(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @staticmethod
    def concat(scenes: list["Scene"]) -> "Scene":
        return Scene(**{f.name: np.concatenate([getattr(s, f.name) for s in scenes]) for f in fields(Scene)})


@dataclass(frozen=True)
class Indicators:
    """Indicators of a batch of scenes; values are NaN where `*_ok` is False."""

    v_e: np.ndarray  # [m/s]
    t_f: np.ndarray  # [s]
    t_nf: np.ndarray  # [s]
    dv_nb: np.ndarray  # [m/s]
    t_f_ok: np.ndarray  # bool
    t_nf_ok: np.ndarray
    dv_nb_ok: np.ndarray
    gap_f: np.ndarray  # gap to the ego-lane leader [m] (NaN when absent)


def _ttc(present: np.ndarray, gap: np.ndarray, closing_speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ok = present & (closing_speed > 0) & np.isfinite(gap)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(ok, np.maximum(gap, 0.0) / np.where(ok, closing_speed, 1.0), np.nan)
    return t, ok


def seen(scene: Scene, range_m: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Presence of f, nf, nb within `range_m` of the ego (the study's logs hold no farther vehicle)."""

    def one(present: np.ndarray, x: np.ndarray) -> np.ndarray:
        return present & (np.abs(np.where(present, x, scene.x_e) - scene.x_e) <= range_m)

    return one(scene.f_present, scene.x_f), one(scene.nf_present, scene.x_nf), one(scene.nb_present, scene.x_nb)


def gaps(scene: Scene, range_m: float = np.inf) -> dict[str, np.ndarray]:
    """Gaps [m] to ``C_f``, ``C_nf``, ``C_nb`` and the time headways [s] ``thw_f`` (gap_f / v_e) and
    ``thw_nb`` (gap_nb / v_nb) of every scene, NaN where undefined: the vehicle not seen within
    `range_m`, or a headway's speed under `indicators.acceptance.MIN_SPEED_MPS` (the analysis's rules)."""
    f, nf, nb = seen(scene, range_m)
    gap_f = np.where(f, scene.x_f - scene.x_e - scene.hl_f, np.nan)
    gap_nb = np.where(nb, scene.x_e - scene.x_nb - scene.hl_nb, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        thw_f = np.where(scene.v_e >= MIN_SPEED_MPS, gap_f / scene.v_e, np.nan)
        thw_nb = np.where(scene.v_nb >= MIN_SPEED_MPS, gap_nb / scene.v_nb, np.nan)
    return {
        "gap_f": gap_f,
        "thw_f": thw_f,
        "gap_nf": np.where(nf, scene.x_nf - scene.x_e - scene.hl_nf, np.nan),
        "gap_nb": gap_nb,
        "thw_nb": thw_nb,
    }


def indicators(scene: Scene, far_follower_m: float = FAR_FOLLOWER_M, range_m: float = np.inf) -> Indicators:
    """t_f, t_nf, dv_nb of every scene, with masks saying where each is defined.

    A vehicle farther than `range_m` counts as absent (what the driver's log shows).
    """
    f, nf, nb = seen(scene, range_m)
    g = gaps(scene, range_m)
    gap_f, gap_nf, gap_nb = g["gap_f"], g["gap_nf"], g["gap_nb"]
    t_f, t_f_ok = _ttc(f, gap_f, scene.v_e - scene.v_f)
    t_nf, t_nf_ok = _ttc(nf, gap_nf, scene.v_e - scene.v_nf)
    nb_ok = nb & (np.nan_to_num(gap_nb, nan=np.inf) <= far_follower_m)
    dv_nb = np.where(nb_ok, scene.v_e - scene.v_nb, np.nan)
    return Indicators(scene.v_e, t_f, t_nf, dv_nb, t_f_ok, t_nf_ok, nb_ok, gap_f)


def observe(scene: Scene, range_m: float, v_max_mps: float) -> np.ndarray:
    """The study's 8 values per scene, normalised to (0, 1], shape (n, 8) float32.

    Speeds: ``v / v_max_mps``. Positions are ego-centred: ``(x - x_e + range_m) /
    (2 range_m)``, so the ego is always 0.5, a vehicle ``range_m`` ahead is 1 and one
    ``range_m`` behind is 0. Both are clipped to [OBS_FLOOR, 1]. An absent vehicle is
    shown as what the driver would see, nothing within range: a leader at the front
    edge (1.0), a follower at the rear edge (OBS_FLOOR), moving at the ego's speed;
    a vehicle farther than ``range_m`` is shown as absent (as the study's logs,
    which hold a vehicle only within their scene range).
    """

    def pos(x: np.ndarray) -> np.ndarray:
        return (x - scene.x_e + range_m) / (2.0 * range_m)

    v_e = scene.v_e
    f, nf, nb = seen(scene, range_m)
    cols = [
        v_e / v_max_mps,
        np.full_like(v_e, 0.5),
        np.where(f, scene.v_f, v_e) / v_max_mps,
        np.where(f, pos(scene.x_f), 1.0),
        np.where(nf, scene.v_nf, v_e) / v_max_mps,
        np.where(nf, pos(scene.x_nf), 1.0),
        np.where(nb, scene.v_nb, v_e) / v_max_mps,
        np.where(nb, pos(scene.x_nb), 0.0),
    ]
    obs = np.stack(cols, axis=1)
    return np.clip(obs, OBS_FLOOR, 1.0).astype(np.float32)


#: Names of the indicator features `observe_indicators` appends to the study's state.
INDICATOR_FEATURES: tuple[str, ...] = ("t_f", "t_nf", "dv_nb", "t_f_ok", "t_nf_ok", "dv_nb_ok")
#: Name of the side feature the 'direction' observation appends.
DIRECTION_FEATURE: str = "target_left"

TTC_CAP_S: float = 60.0  # TTCs are read on a log scale up to this [s]
DV_RANGE_MPS: float = 20.0  # dv_nb is read over +-this [m/s]


def indicator_features(scene: Scene, far_follower_m: float, range_m: float) -> np.ndarray:
    """t_f, t_nf, dv_nb and their definedness, scaled to [OBS_FLOOR, 1], shape (n, 6) float32.

    A TTC is read as ``log1p(t) / log1p(TTC_CAP_S)``: the drivers' decisions differ by
    seconds at short TTCs, not at fifty, and a log keeps the heavy tail from
    dominating. An undefined TTC (no leader, or not closing) reads as the cap, an
    undefined dv_nb (no follower within reach) as 0.5 (no relative speed); the
    three flags say which were defined, so "far" and "undefined" stay apart.
    """
    ind = indicators(scene, far_follower_m, range_m)

    def ttc(t: np.ndarray, ok: np.ndarray) -> np.ndarray:
        return np.log1p(np.where(ok, np.minimum(t, TTC_CAP_S), TTC_CAP_S)) / np.log1p(TTC_CAP_S)

    dv = np.where(ind.dv_nb_ok, (ind.dv_nb + DV_RANGE_MPS) / (2 * DV_RANGE_MPS), 0.5)
    cols = [
        ttc(ind.t_f, ind.t_f_ok),
        ttc(ind.t_nf, ind.t_nf_ok),
        dv,
        ind.t_f_ok.astype(float),
        ind.t_nf_ok.astype(float),
        ind.dv_nb_ok.astype(float),
    ]
    return np.clip(np.stack(cols, axis=1), OBS_FLOOR, 1.0).astype(np.float32)


#: Names of the gap and headway features the 'acceptance' observation appends (what a driver accepts).
ACCEPTANCE_FEATURES: tuple[str, ...] = ("gap_f", "thw_f", "gap_nf", "gap_nb", "thw_nb")
HEADWAY_CAP_S: float = 10.0  # time headways are read on a log scale up to this [s]


def _log_capped(x: np.ndarray, cap: float) -> np.ndarray:
    """``log1p(min(max(x, 0), cap)) / log1p(cap)``; undefined (NaN) reads as 1 (the cap)."""
    return np.log1p(np.clip(np.nan_to_num(x, nan=cap), 0.0, cap)) / np.log1p(cap)


def acceptance_features(scene: Scene, range_m: float) -> np.ndarray:
    """Gaps and time headways of the scene (`gaps`), scaled to [OBS_FLOOR, 1], shape (n, 5) float32.

    The front gap and time headway to ``C_f``, the lead gap to ``C_nf``, the lag gap to ``C_nb``
    and that follower's time headway, as the analysis reads them (`indicators/acceptance.py`).
    Gaps are read as ``log1p(gap) / log1p(range_m)``, headways as ``log1p(thw) /
    log1p(HEADWAY_CAP_S)``: drivers differ by metres at short gaps, not at a hundred. An
    undefined value (vehicle not seen) reads as the cap (nothing within range); a gap at or
    below 0 (a car alongside) as the floor. The positions of the study's 8 values hold the same
    information, but a small network learns a ratio such as gap / v_e slowly from few presses.
    """
    g = gaps(scene, range_m)
    caps = {"gap_f": range_m, "thw_f": HEADWAY_CAP_S, "gap_nf": range_m, "gap_nb": range_m, "thw_nb": HEADWAY_CAP_S}
    cols = [_log_capped(g[name], caps[name]) for name in ACCEPTANCE_FEATURES]
    return np.clip(np.stack(cols, axis=1), OBS_FLOOR, 1.0).astype(np.float32)


def direction_feature(scene: Scene) -> np.ndarray:
    """1 where the target lane is to the left, OBS_FLOOR where it is to the right; shape (n, 1) float32."""
    assert scene.left is not None  # `Scene.__post_init__` sets it
    return np.where(scene.left, 1.0, OBS_FLOOR).astype(np.float32)[:, None]
