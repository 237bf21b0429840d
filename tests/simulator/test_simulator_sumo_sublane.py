"""`laneprint simulate --engine sumo --family sublane`: SUMO's sublane model (SL2015) as a study family.

Fast: the family in the settings and in `--help`, what SUMO is given (`--lateral-resolution`, SL2015
for every vehicle), the styles recoverable in principle (k-means on the drivers' standardised true
parameters finds them, ARI 1.0), and where the press goes on a made-up lateral trace. Slow (real
SUMO, a second or two): one driver, one section, one minute on two and on three lanes, whose presses
and lane flips are read as LOG_FORMAT says (lane 0 rightmost, the lane is the one the ego's centre
is in, a press before each lane change in the lane it leaves), and a tiny study through the CLI.
Skipped with the install hint where SUMO is missing.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.reference import STYLES
from laneprint.simulator.sumo.scenario import build_network, routes_xml, write_routes
from laneprint.simulator.sumo.section import run_section, sublane_change_starts, sumo_args
from laneprint.simulator.sumo.settings import FAMILIES, SumoSettings, family_settings
from laneprint.simulator.sumo.styles import FAMILY_STYLE_PARAMS, SUBLANE_STYLE_PARAMS, make_sumo_drivers

runner = CliRunner()
W = 3.5  # [m] lane width
STEP = 0.1  # [s]


# --- pure parts (no SUMO needed) ------------------------------------------------------


def test_sublane_family_in_settings_and_help():
    assert FAMILIES == ("ttc", "acceptance", "sublane") and FAMILY_STYLE_PARAMS["sublane"] is SUBLANE_STYLE_PARAMS
    s = family_settings("sublane")
    assert (s.lane_change_model, s.lateral_resolution_m, s.car_follow_model) == ("SL2015", 0.8, "Krauss")
    assert s.minutes == 6.0 and family_settings("sublane", 3).n_lanes == 3
    assert "middle" in family_settings("sublane", 3).ahead_streams
    assert (SumoSettings().lane_change_model, SumoSettings().lateral_resolution_m) == ("LC2013", 0.0)
    with pytest.raises(ValueError, match="SL2015 needs"):
        SumoSettings(lane_change_model="SL2015")
    with pytest.raises(ValueError, match="SL2015 needs"):
        SumoSettings(lateral_resolution_m=0.8)
    text = runner.invoke(app, ["simulate", "--help"], terminal_width=200).output
    assert "sublane" in text and "SL2015" in text


def test_sumo_gets_sublanes_and_sl2015_only_for_the_family(tmp_path):
    sub, ttc = family_settings("sublane"), family_settings("ttc")
    a = sumo_args(tmp_path / "n", tmp_path / "r", tmp_path / "lc", sub, 1)
    assert a[a.index("--lateral-resolution") + 1] == "0.8" and "--lanechange.duration" not in a
    assert a[a.index("--lanechange-output.started") + 1] == "true"
    b = sumo_args(tmp_path / "n", tmp_path / "r", tmp_path / "lc", ttc, 1)
    assert "--lateral-resolution" not in b and "--lanechange-output.started" not in b
    assert b[b.index("--lanechange.duration") + 1] == "3"
    xml = routes_xml(SUBLANE_STYLE_PARAMS["Normal"], sub)
    assert xml.count('laneChangeModel="SL2015"') == 3 and "LC2013" not in xml  # the ego and both traffic types
    assert 'lcSigma="0.1"' in xml and 'maxSpeedLat="1.2"' in xml
    assert routes_xml(FAMILY_STYLE_PARAMS["ttc"]["Normal"], ttc).count("laneChangeModel") == 1


@pytest.mark.slow
def test_styles_recoverable_from_the_true_parameters():
    """Standardised true parameters of a study's drivers, k-means with k = 3: the styles, exactly."""
    from sklearn.cluster import KMeans
    from sklearn.metrics import adjusted_rand_score

    assert set(SUBLANE_STYLE_PARAMS) == set(STYLES)
    assert len({frozenset(p) for p in SUBLANE_STYLE_PARAMS.values()}) == 1  # same parameters per style
    for n in (9, 30):
        for seed in range(10):  # the drivers of `simulate --seed seed` (study.py's SeedSequence)
            rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(0,)))
            drivers = make_sumo_drivers(n, 0.1, rng, "sublane")
            x = np.array([[d.params[k] for k in SUBLANE_STYLE_PARAMS["Normal"]] for d in drivers])
            z = (x - x.mean(axis=0)) / x.std(axis=0)
            found = KMeans(n_clusters=3, n_init=10, random_state=0).fit_predict(z)
            assert adjusted_rand_score([d.style for d in drivers], found) == 1.0, (n, seed)


def _trace(*legs: tuple[float, int], y0: float = 0.0) -> np.ndarray:
    """Lateral positions [m]: from `y0`, each leg (target y, samples) a straight move to its target."""
    y = [y0]
    for target, n in legs:
        y += list(np.linspace(y[-1], target, n + 1)[1:])
    return np.array(y)


def _lane(y: np.ndarray) -> np.ndarray:
    return np.floor(y / W + 0.5).astype(np.int64)  # the lane the centre is in


def test_press_at_the_start_sumo_reports_of_the_move_that_crossed():
    y = _trace((0.0, 20), (3.5, 30), (3.5, 30))  # at rest, then 30 samples across into lane 1
    lane, sim_t = _lane(y), np.arange(len(y)) * STEP + 0.2
    started = [("changeStarted", sim_t[20] - STEP, "speedGain", 3.5)]  # stamped with its step's start
    assert sublane_change_starts(y, lane, sim_t, started, STEP) == [(20, "left", 0)]
    # SUMO restarting the manoeuvre with another reason on the way keeps the first start
    again = started + [
        ("changeEnded", sim_t[30] - STEP, "speedGain", 0.0),
        ("changeStarted", sim_t[30] - STEP, "keepRight|sublane", 2.0),
    ]
    assert sublane_change_starts(y, lane, sim_t, again, STEP) == [(20, "left", 0)]
    # no event: where the move towards the new lane began
    assert sublane_change_starts(y, lane, sim_t, [], STEP) == [(21, "left", 0)]


def test_a_wait_at_the_lane_edge_or_a_turn_back_is_not_the_press():
    # to the lane edge (0.85 m), wait there 3 s, then across: the press is where it moves on
    y = _trace((0.0, 10), (0.85, 10), (0.85, 30), (3.5, 25), (3.5, 10))
    lane, sim_t = _lane(y), np.arange(len(y)) * STEP + 0.2
    events = [
        ("changeStarted", sim_t[10] - STEP, "speedGain", 3.5),
        ("changeStarted", sim_t[50] - STEP, "speedGain", 2.65),
    ]
    assert sublane_change_starts(y, lane, sim_t, events, STEP) == [(50, "left", 0)]
    # half way to the edge and back to the centre without resting, then across
    y = _trace((0.0, 10), (1.2, 10), (0.0, 8), (3.5, 30), (3.5, 10))
    lane, sim_t = _lane(y), np.arange(len(y)) * STEP + 0.2
    events = [("changeStarted", sim_t[10] - STEP, "speedGain", 3.5)]
    assert sublane_change_starts(y, lane, sim_t, events, STEP) == [(29, "left", 0)]


def test_a_dip_across_the_line_and_back_is_two_lane_changes():
    # right from lane 1 until the centre is just in lane 0, then straight back: two flips, two presses,
    # each pressed in the lane it leaves and released before the next press
    y = _trace((3.5, 10), (1.6, 20), (3.5, 20), (3.5, 10), y0=3.5)
    lane, sim_t = _lane(y), np.arange(len(y)) * STEP + 0.2
    starts = sublane_change_starts(y, lane, sim_t, [], STEP)
    flips = np.flatnonzero(lane[1:] != lane[:-1]) + 1
    assert [(d, f) for _, d, f in starts] == [("right", 1), ("left", 0)] and len(flips) == 2
    for (k, _, from_lane), f in zip(starts, flips):
        assert k < f and lane[k] == from_lane
    assert starts[1][0] >= starts[0][0] + 2


# --- real SUMO runs ---------------------------------------------------------------------


def _sumo_or_skip() -> None:
    from laneprint.simulator.sumo.backend import check_available

    try:
        check_available()
    except UserError as exc:
        pytest.skip(f"libsumo/traci not importable here ({exc})")


def _one_minute(tmp_path: Path, lanes: int, seed: int):
    _sumo_or_skip()
    s = family_settings("sublane", lanes, minutes=1.0)
    net = build_network(tmp_path, s, 80)
    routes = write_routes(tmp_path / "ego.rou.xml", SUBLANE_STYLE_PARAMS["Aggressive"], s)
    return s, run_section(s, net, routes, 80.0, seed + 1, np.random.default_rng(seed), tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("lanes, seed", [(2, 0), (3, 1)])
def test_one_minute_on_sublanes_presses_and_flips_as_log_format_says(tmp_path, lanes, seed):
    s, log = _one_minute(tmp_path, lanes, seed)
    ego, traffic = log.ego, log.traffic
    t, y = ego["t_s"].to_numpy(), ego["ego_y_m"].to_numpy()
    lane, btn = ego["ego_lane"].to_numpy(), ego["lc_button"].to_numpy(dtype=bool)
    assert log.n_collisions == 0 and t[-1] >= 59.9
    # the lane is the one the centre is in (lane 0 rightmost, lane k's centre at y = 3.5 k)
    assert set(lane) <= set(range(lanes)) and np.all(np.abs(y - lane * W) <= W / 2 + 1e-9)
    assert set(traffic["lane"]) <= set(range(lanes))
    assert np.all(np.abs(traffic["y_m"] - traffic["lane"] * W) <= W / 2 + 1e-9)
    # SUMO's lateral moves, not LC2013's jumps of a fixed duration: the ego is off its lane centre a lot
    assert np.mean(np.abs(y - lane * W) > 0.05) > 0.1
    presses = np.flatnonzero(btn & ~np.r_[False, btn[:-1]])
    flips = np.flatnonzero(lane[1:] != lane[:-1]) + 1
    assert len(presses) == len(flips) == len(log.lane_changes) >= 4
    directions = ego["lc_direction"].to_numpy()[presses]
    assert {"left", "right"} <= set(directions)
    if lanes == 3:
        assert 2 in set(lane)
    bounds = list(presses[1:]) + [len(t)]
    for p, nxt, f, d, change in zip(presses, bounds, flips, directions, log.lane_changes):
        # pressed in the lane it leaves, the lane flips once to the neighbour on that side before the next press
        assert p < f < nxt and lane[p] == lane[f - 1] == change["from_lane"]
        assert lane[f] == lane[p] + (1 if d == "left" else -1) == change["target_lane"]
        assert np.isclose(change["press_t_s"], t[p]) and np.isclose(change["lane_flip_t_s"], t[f])
        assert 0.0 < t[f] - t[p] < 8.0 and btn[p] and (nxt == len(t) or not btn[nxt - 1])
        assert change["sumo_reason"] in ("speedGain", "keepRight", "speedGain|sublane", "keepRight|sublane")


@pytest.mark.slow
def test_a_tiny_sublane_study_through_the_cli(tmp_path):
    _sumo_or_skip()
    out = tmp_path / "study"
    res = runner.invoke(
        app,
        [
            "simulate",
            "--engine",
            "sumo",
            "--family",
            "sublane",
            "--drivers",
            "1",
            "--minutes",
            "0.5",
            "--seed",
            "2",
            "--format",
            "csv",
            "--out",
            str(out),
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    gt = json.loads((out / "ground_truth.json").read_text())
    assert summary["family"] == gt["family"] == "sublane" and summary["recordings"] == 4
    assert gt["settings"]["lane_change_model"] == "SL2015" and gt["settings"]["lateral_resolution_m"] == 0.8
    assert gt["style_params"] == SUBLANE_STYLE_PARAMS and gt["car_follow_model"] == "Krauss"
    readme = (out / "README.md").read_text()
    assert "--family sublane" in readme and "SL2015" in readme and "--lateral-resolution 0.8" in readme
    for dec in gt["decisions"]:
        assert dec["changed"] and dec["lane_flip_t_s"] > dec["press_t_s"]
