"""The agent's observations: the 'acceptance' inputs by hand, and every observation rebuilt from its spec."""

import math

import numpy as np
import pytest

from rl.problem.env import EnvConfig, observation, observation_names, sample_scenes
from rl.problem.observation import observation_spec
from rl.problem.scene import HEADWAY_CAP_S, Scene
from rl.settings import OBSERVATIONS
from tests.support.rl_workspaces import raw_measurements, spec_value


def scene(**over) -> Scene:
    cols = dict(
        v_e=25.0,
        x_e=0.0,
        f_present=True,
        v_f=20.0,
        x_f=30.0,
        hl_f=4.5,
        nf_present=True,
        v_nf=25.0,
        x_nf=50.0,
        hl_nf=4.5,
        nb_present=True,
        v_nb=30.0,
        x_nb=-40.0,
        hl_nb=4.5,
    )
    cols.update(over)
    return Scene(**{k: np.array([v]) for k, v in cols.items()})


def acceptance_inputs(s: Scene, cfg: EnvConfig) -> dict[str, float]:
    obs = observation(s, cfg)[0]
    return dict(zip(observation_names(cfg), obs.tolist()))


def test_acceptance_reads_gaps_and_headways_on_log_scales():
    cfg = EnvConfig(observation="acceptance")
    got = acceptance_inputs(scene(), cfg)
    r = cfg.range_m
    assert got["gap_f"] == pytest.approx(math.log1p(25.5) / math.log1p(r), abs=1e-6)
    assert got["thw_f"] == pytest.approx(math.log1p(25.5 / 25.0) / math.log1p(HEADWAY_CAP_S), abs=1e-6)
    assert got["gap_nf"] == pytest.approx(math.log1p(45.5) / math.log1p(r), abs=1e-6)
    assert got["gap_nb"] == pytest.approx(math.log1p(35.5) / math.log1p(r), abs=1e-6)
    assert got["thw_nb"] == pytest.approx(math.log1p(35.5 / 30.0) / math.log1p(HEADWAY_CAP_S), abs=1e-6)
    # the study's 8 values and the indicator features come first, unchanged
    base = observation(scene(), EnvConfig(observation="indicators"))[0]
    np.testing.assert_array_equal(observation(scene(), cfg)[0, : len(base)], base)


def test_acceptance_absent_vehicles_read_far_and_a_car_alongside_reads_as_no_gap():
    cfg = EnvConfig(observation="acceptance")
    got = acceptance_inputs(scene(f_present=False, nb_present=True, x_nb=-2.0), cfg)
    assert got["gap_f"] == got["thw_f"] == 1.0  # nothing within range ahead
    assert got["gap_nb"] == got["thw_nb"] == pytest.approx(1e-3)  # alongside: the floor
    far = acceptance_inputs(scene(x_nf=cfg.range_m + 10.0), cfg)
    assert far["gap_nf"] == 1.0  # beyond the range: absent
    stopped = acceptance_inputs(scene(v_nb=0.2), cfg)  # the analysis's rule: no headway below 0.5 m/s
    assert stopped["thw_nb"] == 1.0 and stopped["gap_nb"] < 1.0


@pytest.mark.parametrize("name", OBSERVATIONS)
def test_every_observation_is_rebuilt_from_its_spec_alone(name):
    cfg = EnvConfig(observation=name, nb_present_prob=0.5, nb_gap0_m=(-3.0, 200.0))
    s = sample_scenes(np.random.default_rng(3), cfg, 400)
    s.f_present[::7] = False
    spec = observation_spec(cfg)
    raws = raw_measurements(s, cfg)
    for raw, left in zip(raws, s.left):
        raw["target lane side"] = "left" if left else None  # the 'direction' flag: 1 to the left
    rebuilt = np.array([[spec_value(inp, raw) for inp in spec] for raw in raws], dtype=np.float32)
    np.testing.assert_allclose(rebuilt, observation(s, cfg), atol=1e-6)
