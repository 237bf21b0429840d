"""Hand-made DECISIONS tables for tests and benchmarks when no study is at hand.

A rule-following driver whose indicators at the press are its reference lines
plus noise; the not-yet states are the same scene earlier. Rows follow `laneprint.schemas.DECISIONS`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from indicators.acceptance import MIN_SPEED_MPS
from laneprint.schemas import DECISIONS, validate
from laneprint.workspace import Workspace
from rl.problem.env import EnvConfig, sample_scenes
from rl.problem.rewards import ReferenceLines
from rl.problem.scene import Scene, indicators, seen


#: `laneprint train` options that make a test's run train in a second or two.
FAST_CLI: list[str] = ["--num-envs", "8", "--batch-size", "64", "--learning-starts", "100"]


def _rows(scene: Scene, cfg: EnvConfig) -> dict[str, np.ndarray]:
    ind = indicators(scene, cfg.far_follower_m, cfg.range_m)

    def status(
        ok: np.ndarray, present: np.ndarray, absent_word: str = "absent", bad: str = "not_closing"
    ) -> np.ndarray:
        return np.where(ok, "ok", np.where(present, bad, absent_word))

    gap = lambda d, hl, p: np.where(p, d - hl, np.nan)  # noqa: E731
    return {
        "ego_v_mps": scene.v_e,
        "ego_x_m": scene.x_e,
        "f_present": scene.f_present,
        "f_x_m": np.where(scene.f_present, scene.x_f, np.nan),
        "f_v_mps": np.where(scene.f_present, scene.v_f, np.nan),
        "f_gap_m": gap(scene.x_f - scene.x_e, scene.hl_f, scene.f_present),
        "t_f_s": ind.t_f,
        "t_f_status": status(ind.t_f_ok, scene.f_present),
        "nf_present": scene.nf_present,
        "nf_x_m": np.where(scene.nf_present, scene.x_nf, np.nan),
        "nf_v_mps": np.where(scene.nf_present, scene.v_nf, np.nan),
        "nf_gap_m": gap(scene.x_nf - scene.x_e, scene.hl_nf, scene.nf_present),
        "t_nf_s": ind.t_nf,
        "t_nf_status": status(ind.t_nf_ok, scene.nf_present),
        "nb_present": scene.nb_present,
        "nb_x_m": np.where(scene.nb_present, scene.x_nb, np.nan),
        "nb_v_mps": np.where(scene.nb_present, scene.v_nb, np.nan),
        "nb_gap_m": gap(scene.x_e - scene.x_nb, scene.hl_nb, scene.nb_present),
        "dv_nb_mps": ind.dv_nb,
        "dv_nb_status": status(ind.dv_nb_ok, scene.nb_present, bad="far"),
    }


def rule_driver_decisions(
    lines: ReferenceLines,
    n: int,
    seed: int = 0,
    cfg: EnvConfig | None = None,
    driver_id: str = "D01",
    noise: tuple[float, float, float] = (0.3, 0.5, 1.0),
    window_s: float = 3.0,
    every_s: float = 0.5,
    with_nf: bool = True,
    nb_gap_m: tuple[float, float] = (5.0, 60.0),
) -> pd.DataFrame:
    """`n` decisions of a driver whose indicators at the press are its lines plus noise.

    Each press scene is built backwards: ego and traffic speeds as in `cfg`, the
    leaders placed so that t_f and t_nf equal the lines + Normal(0, noise) at the
    press, the follower's speed so that dv_nb does; the not-yet states are the same
    vehicles `window_s` .. `every_s` seconds earlier (constant speeds).
    """
    cfg = cfg or EnvConfig()
    rng = np.random.default_rng(seed)
    scene = sample_scenes(rng, cfg, n)
    ref = lines.at(scene.v_e)
    t_f = np.maximum(ref["t_f"] + rng.normal(0, noise[0], n), 0.5)
    t_nf = np.maximum(ref["t_nf"] + rng.normal(0, noise[1], n), 0.5)
    dv_nb = ref["dv_nb"] + rng.normal(0, noise[2], n)
    scene.x_f = scene.x_e + scene.hl_f + t_f * (scene.v_e - scene.v_f)
    scene.x_nf = scene.x_e + scene.hl_nf + t_nf * (scene.v_e - scene.v_nf)
    scene.nf_present[:] = with_nf
    scene.v_nb = scene.v_e - dv_nb
    scene.x_nb = scene.x_e - scene.hl_nb - rng.uniform(*nb_gap_m, n)
    scene.nb_present[:] = True
    offsets = np.arange(-window_s, 1e-9, every_s)
    frames = []
    for k, off in enumerate(offsets):
        s = scene.copy()
        s.advance(off)
        frames.append(
            pd.DataFrame(
                {
                    "driver_id": driver_id,
                    "recording_id": "rec0",
                    "session_id": "s0",
                    "decision_id": [f"rec0:{i:04d}" for i in range(n)],
                    "t_s": 100.0 * np.arange(n) + off,
                    "press_t_s": 100.0 * np.arange(n),
                    "label": "change" if k == len(offsets) - 1 else "keep",
                    "speed_limit_kph": np.nan,
                    "ego_lane": 0,
                    "target_lane": 1,
                    "cancelled": False,
                    **_rows(s, cfg),
                }
            )
        )
    df = pd.concat(frames, ignore_index=True).sort_values(["decision_id", "t_s"], ignore_index=True)
    return validate(df, DECISIONS)


def analysed_workspace(root: Path | str) -> Workspace:
    """A workspace with a hand-made analysis: one Normal driver following Table 1's Normal lines."""
    ws = Workspace(root)
    lines = ReferenceLines.paper("Normal")
    dec = rule_driver_decisions(lines, 12, seed=0, cfg=EnvConfig(lines=lines), driver_id="D01")
    write_style_analysis(ws, dec, lines)
    return ws


def session_decisions(
    lines: ReferenceLines, n_sessions: int, per_session: int, driver: str = "D01", seed: int = 0
) -> pd.DataFrame:
    """Decisions of a rule driver over several sessions (recordings ``<driver>-rec<k>``, one speed section each)."""
    parts = []
    for k in range(n_sessions):
        d = rule_driver_decisions(
            lines, per_session, seed=seed + k, cfg=EnvConfig(lines=lines), driver_id=driver, window_s=4.0
        )
        rid = f"{driver}-rec{k}"
        d["recording_id"] = rid
        d["session_id"] = rid
        d["decision_id"] = rid + ":" + d["decision_id"].str.split(":").str[1]
        d["speed_limit_kph"] = float(60 + 10 * k)
        parts.append(d)
    return pd.concat(parts, ignore_index=True)


def write_style_analysis(
    ws: Workspace, decisions: pd.DataFrame, lines: ReferenceLines, style: str = "Normal", driver: str = "D01"
) -> None:
    """An analysis in `ws` with one style whose typical driver is `driver` and whose lines are `lines`."""
    refs = pd.DataFrame(
        [
            {
                "scope": "style",
                "name": style,
                "kind": "typical",
                "indicator": k,
                "A": a,
                "b": b,
                "A_lo": None,
                "A_hi": None,
                "b_lo": None,
                "b_hi": None,
                "r2": None,
                "n": int((decisions["label"] == "change").sum()),
                "source": f"typical driver {driver}",
            }
            for k, (a, b) in (("t_f", lines.t_f), ("t_nf", lines.t_nf), ("dv_nb", lines.dv_nb))
        ]
    )
    styles = pd.DataFrame({"driver_id": [driver], "style": [style], "is_typical": [True], "cluster": [0]})
    ws.ensure().write_tables("analysis", {"decisions": decisions, "reference_lines": refs, "styles": styles}, meta={})


def raw_measurements(scene: Scene, cfg: EnvConfig) -> list[dict]:
    """What a vehicle stack measures, per scene: speeds, relative positions, TTCs (None = undefined)."""
    f, nf, nb = seen(scene, cfg.range_m)
    ind = indicators(scene, cfg.far_follower_m, cfg.range_m)
    out = []
    for i in range(len(scene.v_e)):
        raw = {"v_e": float(scene.v_e[i])}
        for role, present in (("f", f), ("nf", nf), ("nb", nb)):
            here = bool(present[i])
            raw[f"v_{role}"] = float(getattr(scene, f"v_{role}")[i]) if here else None
            raw[f"x_{role}"] = float(getattr(scene, f"x_{role}")[i] - scene.x_e[i]) if here else None
        for k in ("t_f", "t_nf", "dv_nb"):
            raw[k] = float(getattr(ind, k)[i]) if getattr(ind, f"{k}_ok")[i] else None
        hl = {role: float(getattr(scene, f"hl_{role}")[i]) for role in ("f", "nf", "nb")}
        for role, sign in (("f", 1), ("nf", 1), ("nb", -1)):
            raw[f"gap_{role}"] = None if raw[f"x_{role}"] is None else sign * raw[f"x_{role}"] - hl[role]
        raw["thw_f"] = None if raw["gap_f"] is None or raw["v_e"] < MIN_SPEED_MPS else raw["gap_f"] / raw["v_e"]
        stopped = raw["v_nb"] is None or raw["v_nb"] < MIN_SPEED_MPS
        raw["thw_nb"] = None if raw["gap_nb"] is None or stopped else raw["gap_nb"] / raw["v_nb"]
        out.append(raw)
    return out


def spec_value(s: dict, raws: dict) -> float:
    """One input of the observation from raw measurements and its `observation_spec` entry alone, as
    `rl.problem.observation`'s module doc says (self-contained: the export test runs its source where
    laneprint cannot be imported)."""
    import math

    r = raws.get(s["name"])
    if s["transform"] == "constant":
        v = s["value"]
    elif s["transform"] == "flag":
        v = 1.0 if raws.get(s["of"]) is not None else 0.0
    elif r is None:
        u = s["when_undefined"]
        v = u["value"] if "value" in u else raws[u["same_as"]] * s["scale"] + s["offset"]
    elif s["transform"] == "linear":
        v = r * s["scale"] + s["offset"]
    else:
        v = math.log1p(min(max(r, 0.0), s["cap"])) / math.log1p(s["cap"])
    lo, hi = s["clip"]
    return min(max(v, lo), hi)
