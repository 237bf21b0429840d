"""Which side would the closed loop choose at the drivers' own states in a middle lane?

    python benchmarks/sides.py RUN_ID -w WORKSPACE [--json]

The closed loop (`rl.drive.loop.choose_side`) asks the agent about each
neighbouring lane and takes the side with the larger advantage. This replays that
rule on the recorded states of the run's target drivers in a middle lane (a lane
with a neighbour on each side), read from the stored logs exactly as the live loop
reads SUMO (`live_scene`): at each press, whether the rule picks the driver's side,
the other side, or keeps; at the not-yet states of the analysis (label 'keep'),
how often it keeps. In-sample for a run trained on these drivers (with
`EnvConfig.other_side` it also saw the sides not taken). A diagnostic of issue 19's
three lanes (rl/README.md), not part of the product. The counts are written to
`benchmarks/results/<--out>.json` (default `sides_<run id>`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from results_file import write_result  # beside this file: imported before the folder leaves the path

# benchmarks/ holds scripts named like packages (dashboard.py, ingest.py): keep it off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from laneprint.errors import UserError  # noqa: E402
from laneprint.simulator.sumo.traffic import VehicleState  # noqa: E402
from laneprint.workspace import Workspace  # noqa: E402
from rl.drive.loop import advantages, live_scene, neighbour_lanes  # noqa: E402
from rl.drive.store import agent_q, load_run_config  # noqa: E402
from rl.problem.env import EnvConfig  # noqa: E402
from rl.problem.scene import Scene  # noqa: E402
from rl.runs import Target, load_weights  # noqa: E402


def _drivers(workspace: Workspace, target: Target) -> set[str]:
    styles = workspace.read_table("analysis", "styles")
    if target.kind == "driver":
        return {target.name}
    return set(styles.loc[styles["style"].astype(str).str.lower() == target.name.lower(), "driver_id"].astype(str))


def side_choices(workspace: Workspace, run_id: str) -> dict[str, Any]:
    """Counts of the side rule's choices at the target drivers' middle-lane presses and not-yet states."""
    config = load_run_config(workspace, run_id)
    cfg = EnvConfig.from_dict(config["env"])
    q = agent_q(load_weights(workspace, run_id), cfg)
    drivers = _drivers(workspace, Target(**config["target"]))
    dec = workspace.read_table("analysis", "decisions")
    dec = dec[dec["driver_id"].astype(str).isin(drivers)]
    rows = []
    for rid, group in dec.groupby("recording_id"):
        _, ego, traffic = workspace.load_recording(rid)
        n_lanes = int(max(ego["ego_lane"].max(), traffic["lane"].max() if len(traffic) else 0)) + 1
        by_t = {round(t, 6): g for t, g in traffic.groupby(traffic["t_s"].round(6))}
        times = ego["t_s"].to_numpy()
        for r in group.itertuples():
            lanes = neighbour_lanes(int(r.ego_lane), n_lanes)
            if len(lanes) < 2:
                continue  # not a middle lane
            k = int(np.argmin(np.abs(times - float(r.t_s))))  # the log's sample of the state
            t, e = round(float(times[k]), 6), ego.iloc[k]
            me = VehicleState(float(e["ego_x_m"]), float(e["ego_v_mps"]), int(r.ego_lane), float(e["ego_length_m"]))
            g = by_t.get(t, traffic.iloc[:0])
            others = {
                str(v.vehicle_id): VehicleState(float(v.x_m), float(v.v_mps), int(v.lane), float(v.length_m))
                for v in g.itertuples()
            }
            adv = dict(zip(lanes, advantages(q(Scene.concat([live_scene(me, others, k)[0] for k in lanes])))))
            own = "left" if r.target_lane > r.ego_lane else "right"
            rows.append(
                {"label": r.label, "own": own, "adv_left": float(adv[lanes[0]]), "adv_right": float(adv[lanes[1]])}
            )
    df = pd.DataFrame(rows, columns=["label", "own", "adv_left", "adv_right"])
    out: dict[str, Any] = {"run_id": run_id, "drivers": sorted(drivers)}
    for rule in RULES:
        out[rule] = _tally(df, _pick(df, rule))
    return out


#: Side rules compared: the closed loop's ('larger': the side with the larger advantage when it
#: is >= 0), and two priorities for reference ('right_first': right when its advantage is >= 0,
#: else left when >= 0; 'left_first' the mirror).
RULES: tuple[str, ...] = ("larger", "right_first", "left_first")


def _pick(df: pd.DataFrame, rule: str) -> np.ndarray:
    left, right = df["adv_left"].to_numpy(), df["adv_right"].to_numpy()
    if rule == "larger":
        side = np.where(right >= left, "right", "left")  # equal advantages: right, as choose_side
        best = np.maximum(left, right)
    elif rule == "right_first":
        side = np.where(right >= 0, "right", "left")
        best = np.where(right >= 0, right, left)
    else:
        side = np.where(left >= 0, "left", "right")
        best = np.where(left >= 0, left, right)
    return np.where(best >= 0, side, "keep")


def _tally(df: pd.DataFrame, pick: np.ndarray) -> dict[str, Any]:
    out: dict[str, Any] = {"presses": {}}
    change = (df["label"] == "change").to_numpy()
    for side in ("left", "right"):
        m = change & (df["own"] == side).to_numpy()
        out["presses"][side] = {
            "n": int(m.sum()),
            "same_side": int((pick[m] == side).sum()),
            "other_side": int(((pick[m] != side) & (pick[m] != "keep")).sum()),
            "keep": int((pick[m] == "keep").sum()),
        }
    k = (df["label"] == "keep").to_numpy()
    out["keep_states"] = {
        "n": int(k.sum()),
        "keep": int((pick[k] == "keep").sum()),
        "left": int((pick[k] == "left").sum()),
        "right": int((pick[k] == "right").sum()),
    }
    return out


def main(argv: list[str] | None = None) -> int:
    """Command line: RUN_ID -w WORKSPACE, a few lines or --json."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run_id")
    ap.add_argument("-w", "--workspace", default="workspace")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--out", default=None, help="result file name under benchmarks/results/ (default sides_<run id>)")
    args = ap.parse_args(argv)
    try:
        res = side_choices(Workspace(args.workspace), args.run_id)
    except UserError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    write_result(args.out or f"sides_{args.run_id}", res, argv)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    for rule in RULES:
        print(f"rule {rule}{' (the closed loop)' if rule == RULES[0] else ''}:")
        for side, r in res[rule]["presses"].items():
            share = r["same_side"] / r["n"] if r["n"] else np.nan
            print(
                f"  {side:>5} presses from a middle lane: {r['n']:>4}; same side {r['same_side']} ({share:.0%}), "
                f"other side {r['other_side']}, keeps {r['keep']}"
            )
        k = res[rule]["keep_states"]
        print(
            f"  not-yet states in a middle lane: {k['n']}; keeps {k['keep']} "
            f"({k['keep'] / max(k['n'], 1):.0%}), left {k['left']}, right {k['right']}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
