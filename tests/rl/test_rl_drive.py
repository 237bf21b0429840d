"""`laneprint drive RUN_ID --engine sumo`: a trained agent makes the ego's lane changes in SUMO.

The pure parts (the live scene, matching decisions to lane changes, output paths)
need nothing; the closed loop runs the real command line on a small SUMO study
(skipped with a hint where SUMO is not installed).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from laneprint.app.cli import app
from laneprint.errors import UserError
from laneprint.simulator.sumo.traffic import VehicleState
from laneprint.workspace import Workspace
from rl.drive.loop import AgentControl, Decision, choose_side, live_scene, match_presses, neighbour_lanes, target_lane
from rl.drive.calibrate import MIN_HEADWAYS
from rl.drive.heldback import lag_headways
from rl.drive.store import output_paths
from rl.problem.env import EnvConfig, observation
from rl.problem.rewards import CHANGE, KEEP
from rl.problem.scene import Scene, indicators
from rl.runs import Target, target_drivers

runner = CliRunner()


# --- pure parts ------------------------------------------------------------------------


def test_live_scene_reads_the_nearest_vehicles_as_the_analysis_does():
    ego = VehicleState(x=100.0, v=25.0, lane=0, length=4.5)
    others = {
        "far_f": VehicleState(180.0, 20.0, 0, 4.5),
        "f": VehicleState(140.0, 20.0, 0, 12.0),  # nearest ahead in the ego lane: a truck
        "behind_own": VehicleState(90.0, 30.0, 0, 4.5),  # behind in the ego lane: nobody's role
        "nf": VehicleState(130.0, 22.0, 1, 4.0),
        "nb": VehicleState(100.0, 27.0, 1, 5.0),  # alongside counts as behind (dx <= 0)
        "nb_far": VehicleState(40.0, 27.0, 1, 5.0),
    }
    scene, ids = live_scene(ego, others, target_lane(ego.lane))
    assert ids == {"f": "f", "nf": "nf", "nb": "nb"}
    ind = indicators(scene, far_follower_m=100.0, range_m=150.0)
    assert ind.t_f[0] == pytest.approx((40.0 - (4.5 + 12.0) / 2) / 5.0)
    assert ind.t_nf[0] == pytest.approx((30.0 - (4.5 + 4.0) / 2) / 3.0)
    assert ind.dv_nb[0] == pytest.approx(-2.0)


def test_a_car_changing_into_the_target_lane_from_the_far_lane_is_in_it():
    # three lanes: the ego in the left lane (2) asks about the middle one (1) while a car of the right lane
    # (0), 20 m ahead and slower, is already moving into the middle lane (SUMO drove the ego into it)
    ego = VehicleState(x=100.0, v=24.0, lane=2, length=4.5)
    merging = VehicleState(x=120.0, v=14.6, lane=0, length=4.5, lat=1.4)
    scene, ids = live_scene(ego, {"m": merging}, 1)
    assert ids["nf"] == "m" and scene.nf_present[0]
    assert indicators(scene, 100.0, 150.0).t_nf[0] == pytest.approx((20.0 - 4.5) / (24.0 - 14.6))
    keeping = VehicleState(x=120.0, v=14.6, lane=0, length=4.5, lat=0.1)  # within its lane: not entering
    away = VehicleState(x=120.0, v=14.6, lane=0, length=4.5, lat=-1.4)  # leaving to the right, not towards lane 1
    for st in (keeping, away):
        assert live_scene(ego, {"m": st}, 1)[1]["nf"] is None
    # in the ego's own lane a neighbour's car counts only once it is there (the analysis's reading)
    assert live_scene(VehicleState(100.0, 24.0, 1, 4.5), {"m": merging}, 2)[1]["f"] is None


def test_missing_vehicles_are_shown_as_in_training():
    ego = VehicleState(x=0.0, v=20.0, lane=1, length=4.5)
    scene, ids = live_scene(ego, {"ahead_right": VehicleState(60.0, 15.0, 0, 4.5)}, target_lane(1))
    assert ids == {"f": None, "nf": "ahead_right", "nb": None}
    ind = indicators(scene, 100.0, 150.0)
    assert not ind.t_f_ok[0] and ind.t_nf_ok[0] and not ind.dv_nb_ok[0]
    obs = observation(scene, EnvConfig(observation="indicators"))[0]
    # absent leader: at the front edge at the ego's speed; absent follower at the rear edge; flags 0
    assert obs[3] == 1.0 and obs[2] == obs[0] and obs[7] == pytest.approx(1e-3)
    assert obs[-3] == pytest.approx(1e-3) and obs[-2] == 1.0 and obs[-1] == pytest.approx(1e-3)


def test_study_traffic_reads_back_the_simulator_text_a_sumo_study_writes():
    from laneprint.simulator.sumo.settings import FAMILIES, LANES, simulator_text, study_traffic

    for family in FAMILIES:  # what `simulate --engine sumo` writes into every recording, read back
        for lanes in LANES:
            assert study_traffic(simulator_text("1.24.0", family, lanes)) == (family, lanes)
    assert simulator_text("1.24.0") == "Eclipse SUMO 1.24.0 (laneprint simulate --engine sumo)"
    # another simulator, the synthetic study, a drive's own logs, nothing: not a study's traffic
    for other in ("laneprint.simulator v1 (seed 0)", "Eclipse SUMO 1.24.0 (laneprint drive r1, seed 0)", None, ""):
        assert study_traffic(other) is None


def test_target_lane_is_the_other_lane():
    assert (target_lane(0), target_lane(1), target_lane(0, n_lanes=1)) == (1, 0, None)


def test_neighbour_lanes_left_first():
    assert [neighbour_lanes(k, 3) for k in range(3)] == [[1], [2, 0], [1]]
    assert [neighbour_lanes(k, 2) for k in range(2)] == [[1], [0]] and neighbour_lanes(0, 1) == []


def test_choose_side_takes_the_larger_positive_advantage_and_keeps_otherwise():
    assert choose_side({2: 0.3, 0: 0.7}) == 0
    assert choose_side({2: 0.9, 0: 0.1}) == 2
    assert choose_side({2: 0.4, 0: -2.0}) == 2
    assert choose_side({2: -0.1, 0: -0.5}) is None  # neither side is worth a change: keep
    assert choose_side({1: -1e-6}) is None and choose_side({}) is None
    assert choose_side({1: 0.0}) == 1  # a tie with keep is a change, as training's argmax (two lanes unchanged)


class _Vehicle:
    """The two calls AgentControl makes of SUMO's vehicle API, recorded."""

    def __init__(self) -> None:
        self.requests: list[tuple[str, int, float]] = []

    def setLaneChangeMode(self, vid: str, mode: int) -> None:
        pass

    def changeLane(self, vid: str, lane: int, duration: float) -> None:
        self.requests.append((vid, lane, duration))


class _Api:
    def __init__(self) -> None:
        self.vehicle = _Vehicle()


def _stub_q(adv_left: float, adv_right: float, seen: list) -> "object":
    """A stub agent: Q(keep) = 0 and Q(change) = the given advantage of the side each scene asks about."""

    def q(scene: Scene) -> np.ndarray:
        seen.append(scene.left.copy())
        out = np.zeros((len(scene), 2))
        out[:, CHANGE] = np.where(scene.left, adv_left, adv_right)
        out[:, KEEP] = 0.0
        return out

    return q


def _ask_once(q, lane: int, n_lanes: int) -> tuple[AgentControl, _Api]:
    """One decision of the ego in `lane` (the agent is asked every dt_s = 5 steps of 0.1 s)."""
    control, api = AgentControl(q, EnvConfig(observation="direction"), 0.1, n_lanes), _Api()
    control.start(api)
    ego = VehicleState(x=100.0, v=25.0, lane=lane, length=4.5)
    others = {
        "f": VehicleState(140.0, 18.0, lane, 4.5),
        "l": VehicleState(160.0, 24.0, 2, 4.5),
        "r": VehicleState(130.0, 20.0, 0, 4.5),
    }
    for i in range(5):
        control.step(api, 0.1 * i, ego, 0.0, others)
    return control, api


def test_middle_lane_asks_each_side_and_takes_the_larger_advantage():
    seen: list = []
    control, api = _ask_once(_stub_q(0.2, 0.5, seen), lane=1, n_lanes=3)
    assert [list(s) for s in seen] == [[True, False]]  # one scene per side, the left one first
    assert control.n_asked == 1 and api.vehicle.requests == [("ego", 0, 0.5)]
    (d,) = control.decisions
    assert (d.from_lane, d.target_lane) == (1, 0) and d.advantages == pytest.approx({"left": 0.2, "right": 0.5})
    assert d.ids == {"f": "f", "nf": "r", "nb": None}  # the chosen side's scene
    control, api = _ask_once(_stub_q(0.9, 0.5, []), lane=1, n_lanes=3)
    assert api.vehicle.requests == [("ego", 2, 0.5)] and control.decisions[0].ids["nf"] == "l"


def test_keeps_when_neither_side_has_a_positive_advantage():
    control, api = _ask_once(_stub_q(-0.2, -0.01, []), lane=1, n_lanes=3)
    assert control.n_asked == 1 and control.decisions == [] and api.vehicle.requests == []


def test_outer_lanes_and_two_lanes_ask_about_one_side():
    seen: list = []
    _, api = _ask_once(_stub_q(0.3, 0.3, seen), lane=2, n_lanes=3)
    assert [list(s) for s in seen] == [[False]] and api.vehicle.requests == [("ego", 1, 0.5)]
    seen.clear()
    _, api = _ask_once(_stub_q(0.3, -0.3, seen), lane=0, n_lanes=2)
    assert [list(s) for s in seen] == [[True]] and api.vehicle.requests == [("ego", 1, 0.5)]


def test_decisions_are_matched_to_the_lane_change_they_started():
    ds = [Decision(10.0, 0, 1, 20.0, None, None, None, {}), Decision(20.0, 1, 0, 20.0, None, None, None, {})]
    match_presses(ds, [{"press_t_s": 10.1, "target_lane": 1}, {"press_t_s": 21.0, "target_lane": 0}], 0.5)
    assert (ds[0].started, ds[0].press_t_s) == (True, 10.1)
    assert (ds[1].started, ds[1].press_t_s) == (False, None)  # started too late to be this decision's


def test_output_paths():
    assert output_paths(Path("d.mcap"), ["a_S80"]) == [Path("d.mcap")]
    assert output_paths(Path("x/d.mcap"), ["a_S60", "a_S90"]) == [Path("x/d_S60.mcap"), Path("x/d_S90.mcap")]
    assert output_paths(Path("out"), ["a_S60"]) == [Path("out/a_S60.mcap")]


# --- the closed loop through the command line ---------------------------------------------


def _invoke(*args: str) -> dict:
    res = runner.invoke(app, [*args, "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.stdout)


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, str]:
    """A small SUMO study (3 drivers, 1 minute a section), analysed, and a quickly trained Aggressive run."""
    from laneprint.simulator.sumo.backend import check_available

    try:
        check_available()
    except UserError as exc:
        pytest.skip(f"libsumo/traci not importable here ({exc})")
    root = tmp_path_factory.mktemp("drive")
    ws = root / "ws"
    _invoke(
        "simulate", "--engine", "sumo", "--out", str(root / "study"), "--drivers", "3", "--minutes", "1", "--seed", "3"
    )
    _invoke("ingest", str(root / "study"), "-w", str(ws))
    _invoke("analyze", "-w", str(ws))
    _invoke("train", "--style", "Aggressive", "--episodes", "800", "--run-id", "tiny", "--no-evaluate", "-w", str(ws))
    return ws, "tiny"


@pytest.mark.slow
def test_drive_writes_a_log_whose_presses_are_the_agents_lane_changes(trained, tmp_path):
    ws, run_id = trained
    out = tmp_path / "drive.mcap"
    res = _invoke(
        "drive",
        run_id,
        "--engine",
        "sumo",
        "--minutes",
        "1",
        "--section",
        "90",
        "--seed",
        "1",
        "--out",
        str(out),
        "-w",
        str(ws),
    )
    assert res["files"] == [str(out)] and out.is_file()
    assert res["ego_style"] == "Aggressive"
    # its drivers drove this traffic (the study's family and lanes, read from their logs): the drive takes
    # it by default, and its dwell is calibrated against them
    assert res["family"] == "ttc" and res["drivers_traffic"] == {"family": "ttc", "lanes": 2, "same_as_drive": True}
    assert res["dwell"].startswith("calibrated in closed loop") and res["dwell_calibration"]["seeds"] == [1001, 1002]
    tot = res["totals"]
    assert tot["collisions"] == 0
    assert tot["decisions_asked"] >= tot["change_decisions"] >= tot["lane_changes"]
    assert tot["lane_changes"] > 0, "the agent made no lane change: the test would prove nothing"
    started = sorted(d["press_t_s"] for d in res["decisions"] if d["started"])
    assert len(started) == tot["lane_changes"] == tot["agent_changes"] + tot["rule_changes"]
    who = res["who_drove"]  # each lane change is the press of the decision that asked for it: none left over
    assert list(res)[:3] == ["run_id", "target", "who_drove"] and who["total"]["unattributed"] == 0
    assert sum(who["total"].values()) == tot["lane_changes"] and who["total"]["agent"] == tot["agent_changes"]
    assert who["total"]["rule_return"] == tot["return_changes"] and who["text"].startswith("Who changed lane")
    model = res["sumo_model"]  # the comparator: SUMO's own lane changing, same sections and seeds
    assert [r["sumo_seed"] for r in model["sections"]] == [r["sumo_seed"] for r in res["sections"]]
    assert model["totals"]["lane_changes_per_km"] is not None and model["totals"]["km"] > 0
    assert res["held_back"]["on"] is False or res["held_back"]["rule"]["patience_s"] > 0
    pace = res["pace"]  # the agent's own changes no more often than its drivers pressed, replayed on their logs
    assert pace["presses"] > 0 and pace["onsets_per_km"] <= pace["presses_per_km"] + 1e-9
    assert res["held_back"]["rule"]["min_advantage"] == pace["min_advantage"] >= 0
    assert pace["by"] == "pooled" and res["held_back"]["rule"]["min_advantage_by_side"] == {}  # the default

    ingested = _invoke("ingest", str(out), "--driver", "agent", "-w", str(tmp_path / "ws2"))
    assert ingested["counts"]["ingested"] + ingested["counts"]["warning"] == 1
    ((meta, ego, _),) = Workspace(tmp_path / "ws2").iter_recordings()
    btn = ego["lc_button"].to_numpy(dtype=bool)
    t, lane = ego["t_s"].to_numpy(), ego["ego_lane"].to_numpy()
    presses = np.flatnonzero(btn & ~np.r_[False, btn[:-1]])
    assert np.allclose(t[presses], started, atol=1e-6)  # one press per lane change the agent started
    for p, d in zip(presses, [d for d in res["decisions"] if d["started"]]):
        assert 0 < t[p] - d["t_s"] <= 0.5 + 1e-6  # within one decision step of the agent's choice
        assert lane[p - 1] == d["from_lane"] and (lane[p:] == d["target_lane"]).any()


@pytest.mark.slow
def test_drive_refuses_an_unknown_run_and_section(trained):
    ws, run_id = trained
    res = runner.invoke(app, ["drive", "nope", "-w", str(ws)])
    assert res.exit_code == 1 and "no run 'nope'" in res.output
    res = runner.invoke(app, ["drive", run_id, "--section", "100", "-w", str(ws)])
    assert res.exit_code == 1 and "--section 100" in res.output
    res = runner.invoke(app, ["drive", run_id, "--engine", "carla", "-w", str(ws)])
    assert res.exit_code == 1 and "unknown --engine" in res.output
    res = runner.invoke(app, ["drive", run_id, "--pace-by", "lane", "-w", str(ws)])
    assert res.exit_code == 1 and "unknown --pace-by 'lane'" in res.output and "Traceback" not in res.output
    res = runner.invoke(app, ["drive", run_id, "--dwell-percentile", "150", "-w", str(ws)])
    assert res.exit_code == 1 and "--dwell-percentile 150" in res.output and "Traceback" not in res.output
    for bad in ("1", "7"):
        res = runner.invoke(app, ["drive", run_id, "--lanes", bad, "-w", str(ws)])
        assert res.exit_code == 1 and f"--lanes {bad}:" in res.output and "Traceback" not in res.output


@pytest.mark.slow
def test_drive_on_three_lanes(trained, tmp_path):
    ws, run_id = trained
    res = _invoke(
        "drive",
        run_id,
        "--engine",
        "sumo",
        "--lanes",
        "3",
        "--minutes",
        "1",
        "--section",
        "90",
        "--seed",
        "2",
        "--pace-by",
        "side",
        "--dwell-draw",
        "--out",
        str(tmp_path / "d3"),
        "-w",
        str(ws),
    )
    assert res["lanes"] == 3 and res["totals"]["collisions"] == 0
    draws = res["held_back"]["rule"]["dwell_draws"]  # the drivers' own times, drawn from at each change
    assert draws and all(len(v) >= 5 and min(v) > 0 for v in draws.values())
    assert res["held_back"]["rule"]["source"]["dwell_s"].startswith("drawn at each lane change")
    pace = res["pace"]  # the study's presses all carry their side: the pace is read by side
    assert pace["by"] == "side" and set(pace["min_advantage_by_side"]) == {"left", "right"}
    assert "by side" in pace["note"]
    assert res["held_back"]["rule"]["min_advantage_by_side"] == res["pace"].get("min_advantage_by_side", {})
    assert set(res["changes_by_lane"]) <= {"0>1", "1>0", "1>2", "2>1"}
    assert sum(res["changes_by_lane"].values()) == res["totals"]["lane_changes"] > 0
    for d in res["decisions"]:
        assert set(d["advantages"]) == (
            {"left", "right"} if d["from_lane"] == 1 else {"left" if d["from_lane"] == 0 else "right"}
        )
        side = "left" if d["target_lane"] > d["from_lane"] else "right"
        rule = res["held_back"]["rule"]
        need = {k: rule["min_advantage_by_side"].get(k, rule["min_advantage"]) for k in ("left", "right")}
        if d["source"] == "agent":  # the held-back rule changes where the agent keeps
            asked = {k: v for k, v in d["advantages"].items() if k not in d["too_soon"] + d["undone"]}
            reached = {k: v for k, v in asked.items() if v >= need[k]}  # each side its own pace
            assert side in reached and d["advantages"][side] == max(reached.values())
        else:  # the rule changes where the agent keeps: below its pace (its drivers' onsets, rl.drive.pace)
            # on every side it may take (a change to the left it would at once undo it may not)
            wanted = {k: v for k, v in d["advantages"].items() if k not in d["undone"]}
            assert d["source"] in ("rule", "return") and all(v < need[k] for k, v in wanted.items())
    assert res["totals"]["follow"]["undone"] >= sum(bool(d["undone"]) for d in res["decisions"])
    ((meta, ego, _),) = [r for r in _ingested(tmp_path / "d3", tmp_path / "ws3")]
    assert set(ego["ego_lane"].unique()) <= {0, 1, 2}


def _ingested(folder: Path, ws: Path) -> list:
    _invoke("ingest", str(folder), "--driver", "agent", "-w", str(ws))
    return list(Workspace(ws).iter_recordings())


@pytest.mark.slow
def test_drive_in_the_traffic_and_vtypes_of_another_family(trained, tmp_path):
    from laneprint.simulator.sumo.styles import ACCEPTANCE_STYLE_PARAMS, STYLE_PARAMS

    ws, run_id = trained
    res = _invoke(
        "drive",
        run_id,
        "--engine",
        "sumo",
        "--family",
        "acceptance",
        "--minutes",
        "1",
        "--section",
        "90",
        "--seed",
        "1",
        "--no-sumo-model",
        "--out",
        str(tmp_path / "acc"),
        "-w",
        str(ws),
    )
    factor = ACCEPTANCE_STYLE_PARAMS["Aggressive"]["speedFactor"]
    assert factor != STYLE_PARAMS["Aggressive"]["speedFactor"]  # else this test could not tell the families apart
    assert res["family"] == "acceptance" and f"speedFactor {factor:g} " in res["held_back"]["desired_speed"]
    # not its drivers' traffic: nobody there to calibrate the dwell against, so the drivers' floor
    assert res["drivers_traffic"] == {"family": "ttc", "lanes": 2, "same_as_drive": False}
    assert res["dwell_calibration"] is None and res["dwell"] == "the drivers' 5th percentile"
    assert res["lag"] == "the floors alone"  # nor the follower's headway
    assert res["totals"]["collisions"] == 0 and res["totals"]["km"] > 0
    bad = runner.invoke(app, ["drive", run_id, "--family", "nope", "-w", str(ws)])
    assert bad.exit_code == 1 and "unknown --family 'nope'" in bad.output and "Traceback" not in bad.output


@pytest.mark.slow
def test_drive_with_the_dwell_calibrated_in_closed_loop(trained, tmp_path):
    ws, run_id = trained
    args = (
        "drive",
        run_id,
        "--engine",
        "sumo",
        "--minutes",
        "1",
        "--section",
        "90",
        "--no-sumo-model",
        "--dwell-calibrated",
        "-w",
        str(ws),
    )
    res = _invoke(*args, "--seed", "3", "--out", str(tmp_path / "a"))
    cal = res["dwell_calibration"]
    assert cal["seeds"] == [1001, 1002] and cal["family"] == "ttc" and cal["lanes"] == 2
    assert cal["pace_by"] == "pooled" and cal["undo_check"] is True and cal["pace"] is True
    assert "calibrated on drive seeds 1001, 1002" in cal["note"]
    assert res["held_back"]["rule"]["source"]["dwell_s"].startswith("drawn from the closed-loop calibration")
    # the same drives calibrate the follower's headway, on the sides where the agent changed often enough
    lag = res["held_back"]["rule"]["lag_draws"]
    assert set(lag) <= {side for side, h in cal["headways"].items() if h["agent"] >= MIN_HEADWAYS}
    assert res["lag"] == ("the floors alone" if not lag else f"calibrated in closed loop ({', '.join(sorted(lag))})")
    stored = Workspace(ws).runs_dir / run_id / "dwell_calibration.json"
    first = stored.read_text()
    again = _invoke(*args, "--seed", "4", "--out", str(tmp_path / "b"))  # made once per traffic, then reused
    assert stored.read_text() == first and again["dwell_calibration"] == cal
    for kind, draws in again["held_back"]["rule"]["dwell_draws"].items():  # never under the drivers' floor
        assert min(draws) >= again["held_back"]["rule"]["dwell_s"].get(kind, 0.0)
    for both in (
        runner.invoke(app, [*args, "--dwell-draw"]),
        runner.invoke(app, [*args, "--lag-draw", "--lag-calibrated"]),
    ):
        assert both.exit_code == 1 and "choose one" in both.output and "Traceback" not in both.output
    for off in ("--no-dwell", "--no-held-back"):  # no dwell to calibrate: refused, nothing driven
        res = runner.invoke(app, [*args, off])
        assert res.exit_code == 1 and "not with --no-held-back or --no-dwell" in res.output
    assert stored.read_text() == first
    floor = _invoke(
        "drive",
        run_id,
        "--engine",
        "sumo",
        "--minutes",
        "1",
        "--section",
        "90",
        "--no-sumo-model",
        "--no-dwell-calibrated",
        "--seed",
        "3",
        "--out",
        str(tmp_path / "c"),
        "-w",
        str(ws),
    )
    assert floor["dwell_calibration"] is None and floor["dwell"] == "the drivers' 5th percentile"
    assert not floor["held_back"]["rule"].get("dwell_draws")
    assert floor["lag_calibration"]["headways"] == cal["headways"]  # the headway still calibrated, from the same drives
    drawn = _invoke(
        "drive",
        run_id,
        "--engine",
        "sumo",
        "--minutes",
        "1",
        "--section",
        "90",
        "--no-sumo-model",
        "--no-dwell-calibrated",
        "--lag-draw",
        "--seed",
        "3",
        "--out",
        str(tmp_path / "d"),
        "-w",
        str(ws),
    )
    decisions = Workspace(ws).read_table("analysis", "decisions")
    members, _ = target_drivers(Workspace(ws), Target("style", "Aggressive"))
    presses = lag_headways(decisions[decisions["driver_id"].astype(str).isin(members)])
    assert drawn["held_back"]["rule"]["lag_draws"] == pytest.approx(presses)
    assert drawn["lag"] == (
        f"drawn from the drivers' presses ({', '.join(sorted(presses))})" if presses else "the floors alone"
    )
