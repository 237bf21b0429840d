"""Benchmark: wall time for one agent to reach the accuracy target, ours vs SB3's DQN.

Both train on the same environment (`LaneChangeDecisionEnv`, same reward, same
reference lines) with the study's hyperparameters (Table 2 network, lr 0.005,
gamma 0.98, replay 10000, start 2000, epsilon 0.8 -> 0.1, target copy every 20
episodes; SB3 counts it in steps: 20 x the mean episode length of our run), one
torch thread each, side by side in this process, interleaved (ours seed 0, SB3
seed 0, ours seed 1, ...) so the shared machine's load falls on both. Every `--check-every` env
steps the greedy policy is scored on the drivers' recorded states of the style's
typical driver (`analysis/decisions` of the workspace); the clock stops while it
is scored. The target: recall at the presses >= the study's figure for the style
(95.9 / 100 / 98.6 %) and balanced accuracy >= the greedy benchmark's + 5 points.

    python benchmarks/train.py -w /tmp/wsbench --style Normal --repeats 20 --check-every 1000  # ~12 min
    python benchmarks/train.py ... --set gradient_steps=2 --set batch_size=128   # a variant of ours

With no analysis in the workspace, `sample_logs/` is ingested and analysed first.
Take about 20 seeds: the first hit of one seed moves by 10000-30000 steps with
one press on the policy's decision boundary, so 5 seeds give no stable median.
Prints per repeat: seconds and env steps to the target, env steps per second, and
the medians and ratio; writes the summary and every repeat to `benchmarks/results/<--out>.json`
(default `train_<style>`).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from laneprint.workspace import Workspace
from rl.learners.dqn import DQNSettings, DQNTrainer
from rl.problem.env import EnvConfig, LaneChangeDecisionEnv, approaches_from_decisions
from rl.evaluation.evaluate import greedy_policy
from rl.problem.rewards import CHANGE, ReferenceLines, RewardSettings
from rl.problem.scene import Scene, observe
from results_file import write_result  # beside this file

PAPER_RECALL = {"Defensive": 0.959, "Normal": 1.0, "Aggressive": 0.986}
REPO = Path(__file__).resolve().parents[1]


def ensure_analysis(ws: Workspace) -> None:
    if ws.has_table("analysis", "decisions"):
        return
    exe = [sys.executable, "-m", "laneprint.app.cli"]
    subprocess.run(
        exe + ["ingest", str(REPO / "sample_logs"), "-w", str(ws.root), "--json"], check=True, stdout=subprocess.DEVNULL
    )
    subprocess.run(exe + ["analyze", "-w", str(ws.root), "--json"], check=True, stdout=subprocess.DEVNULL)


class Scorer:
    """Recall and balanced accuracy of a Q network on the typical driver's states."""

    def __init__(self, ws: Workspace, style: str, cfg: EnvConfig) -> None:
        styles = ws.read_table("analysis", "styles")
        typical = styles[(styles["style"] == style) & styles["is_typical"]]["driver_id"].iloc[0]
        dec = ws.read_table("analysis", "decisions")
        # the study's rule (presses made while following are skipped), as this benchmark's
        # targets were set before issue 9 made the evaluation score them
        approaches, _ = approaches_from_decisions(dec[dec["driver_id"] == typical], include_following=False)
        scene = Scene.concat([a.scene for a in approaches])
        self.obs = torch.as_tensor(observe(scene, cfg.range_m, cfg.v_max_mps))
        self.press = np.concatenate([[False] * (len(a) - 1) + [True] for a in approaches])
        g = greedy_policy(cfg)(scene) == CHANGE
        self.greedy = self.score(g)
        self.target_recall = PAPER_RECALL[style]
        self.target_bacc = self.greedy["balanced_accuracy"] + 0.05
        self.typical = typical

    def score(self, said_change: np.ndarray) -> dict[str, float]:
        recall = float(said_change[self.press].mean())
        spec = float((~said_change[~self.press]).mean())
        return {"recall": recall, "balanced_accuracy": (recall + spec) / 2}

    def __call__(self, net: torch.nn.Module) -> tuple[bool, dict[str, float]]:
        with torch.no_grad():
            s = self.score((net(self.obs).argmax(1) == CHANGE).numpy())
        ok = s["recall"] >= self.target_recall - 1e-9 and s["balanced_accuracy"] >= self.target_bacc - 1e-9
        return ok, s


def run_ours(
    cfg: EnvConfig, settings: DQNSettings, scorer: Scorer, check_every: int, budget_s: float, stop_at_hit: bool = False
) -> dict:
    trainer = DQNTrainer(cfg, settings)
    state = {"next": check_every, "eval_s": 0.0, "hit": None, "last": None, "lengths": []}
    t0 = time.perf_counter()

    def on_step(t: DQNTrainer) -> bool:
        if t.env_steps < state["next"]:
            return time.perf_counter() - t0 - state["eval_s"] > budget_s
        state["next"] += check_every
        e0 = time.perf_counter()
        ok, s = scorer(t.policy_net)
        state["eval_s"] += time.perf_counter() - e0
        state["last"] = s
        if ok and state["hit"] is None:
            state["hit"] = {
                "wall_s": time.perf_counter() - t0 - state["eval_s"],
                "env_steps": t.env_steps,
                "episodes": t.episodes_done,
                **s,
            }
            return stop_at_hit
        return time.perf_counter() - t0 - state["eval_s"] > budget_s

    trainer.train(on_episode=lambda r: state["lengths"].append(r["length"]), on_vector_step=on_step)
    wall = time.perf_counter() - t0 - state["eval_s"]
    return {
        "hit": state["hit"],
        "last": state["last"],
        "wall_s": wall,
        "episodes": trainer.episodes_done,
        "env_steps": trainer.env_steps,
        "steps_per_s": trainer.env_steps / wall,
        "mean_episode_length": float(np.mean(state["lengths"] or [1])),
    }


def run_sb3(
    cfg: EnvConfig,
    scorer: Scorer,
    seed: int,
    total_steps: int,
    exploration_fraction: float,
    target_update_steps: int,
    check_every: int,
    budget_s: float,
) -> dict:
    from stable_baselines3 import DQN
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(1)
    env = LaneChangeDecisionEnv(cfg)
    model = DQN(
        "MlpPolicy",
        env,
        learning_rate=0.005,
        buffer_size=10000,
        learning_starts=2000,
        batch_size=32,
        gamma=0.98,
        train_freq=1,
        gradient_steps=1,
        target_update_interval=target_update_steps,
        exploration_initial_eps=0.8,
        exploration_final_eps=0.1,
        exploration_fraction=exploration_fraction,
        policy_kwargs={"net_arch": [128, 128, 128]},
        seed=seed,
        device="cpu",
        verbose=0,
    )
    state = {"eval_s": 0.0, "hit": None, "last": None}

    class Check(BaseCallback):
        def _on_training_start(self) -> None:
            self.t0 = time.perf_counter()

        def _on_step(self) -> bool:
            elapsed = time.perf_counter() - self.t0 - state["eval_s"]
            if self.num_timesteps % check_every:
                return elapsed < budget_s
            e0 = time.perf_counter()
            ok, s = scorer(self.model.q_net)
            state["eval_s"] += time.perf_counter() - e0
            state["last"] = s
            if ok:
                state["hit"] = {"wall_s": elapsed, "env_steps": self.num_timesteps, **s}
                return False
            return elapsed < budget_s

    cb = Check()
    t0 = time.perf_counter()
    model.learn(total_timesteps=total_steps, callback=cb)
    wall = time.perf_counter() - t0 - state["eval_s"]
    return {
        "hit": state["hit"],
        "last": state["last"],
        "wall_s": wall,
        "env_steps": model.num_timesteps,
        "steps_per_s": model.num_timesteps / wall,
        "target_update_steps": target_update_steps,
        "exploration_fraction": exploration_fraction,
        "total_timesteps": total_steps,
    }


def parse_overrides(items: list[str]) -> dict:
    """``["batch_size=128", "loss=huber"]`` -> typed DQNSettings overrides (values parsed as JSON, else strings)."""
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    DQNSettings(**out)  # fails early on an unknown key
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-w", "--workspace", default="/tmp/laneprint-bench")
    ap.add_argument("--style", default="Normal")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=DQNSettings().episodes)
    ap.add_argument("--check-every", type=int, default=2000, help="env steps between accuracy checks")
    ap.add_argument("--budget-s", type=float, default=240.0, help="give up after this much training time")
    ap.add_argument("--sb3-repeats", type=int, default=None, help="SB3 repeats (default: --repeats)")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one of our DQNSettings (repeatable), e.g. --set batch_size=128",
    )
    ap.add_argument("--out", default=None, help="result file name under benchmarks/results/ (default train_<style>)")
    args = ap.parse_args()

    torch.set_num_threads(1)
    ws = Workspace(args.workspace)
    ensure_analysis(ws)
    lines = ReferenceLines.from_table(ws.read_table("analysis", "reference_lines"), style=args.style)
    cfg = EnvConfig(lines=lines, reward=RewardSettings(name="timing"))
    scorer = Scorer(ws, args.style, cfg)
    print(
        f"style {args.style}, typical driver {scorer.typical}: target recall >= {scorer.target_recall:.3f}, "
        f"balanced accuracy >= {scorer.target_bacc:.3f} (greedy {scorer.greedy['balanced_accuracy']:.3f})",
        flush=True,
    )
    overrides = parse_overrides(args.set)
    n_ours, n_sb3 = args.repeats, args.sb3_repeats if args.sb3_repeats is not None else args.repeats
    ours, sb3 = [], []
    sched: dict[str, float] = {}

    def one_ours(seed: int) -> None:  # the full run (all episodes), noting when the target is first met
        r = run_ours(
            cfg,
            DQNSettings(**{"episodes": args.episodes, "checkpoint_every": 0, **overrides, "seed": seed}),
            scorer,
            args.check_every,
            args.budget_s,
        )
        ours.append(r)
        print(f"ours  seed {seed}: {json.dumps(r)}", flush=True)
        if not sched:  # SB3's schedules from our first full run (episode length and steps vary < 1 % by seed)
            # SB3's epsilon reaches 0.1 after as many steps as ours took for all its episodes, then stays
            sched["schedule"] = r["env_steps"]
            sched["total"] = max(3 * r["env_steps"], 150_000)
            sched["target_update"] = max(1, round(20 * r["mean_episode_length"]))

    def one_sb3(seed: int) -> None:
        r = run_sb3(
            cfg,
            scorer,
            seed,
            sched["total"],
            sched["schedule"] / sched["total"],
            sched["target_update"],
            args.check_every,
            args.budget_s,
        )
        sb3.append(r)
        print(f"sb3   seed {seed}: {json.dumps(r)}", flush=True)

    # interleaved (ours 0, SB3 0, ours 1, SB3 1, ...): the machine's load falls on both alike
    for seed in range(max(n_ours, n_sb3)):
        if seed < n_ours or not sched:
            one_ours(seed)
        if seed < n_sb3:
            one_sb3(seed)

    def med(rows: list[dict], key: str) -> float | None:
        vals = [r["hit"][key] if r["hit"] else None for r in rows]
        if any(v is None for v in vals):  # a miss counts as the whole budget (a lower bound on its time)
            vals = [
                v if v is not None else (r["wall_s"] if key == "wall_s" else r["env_steps"]) for v, r in zip(vals, rows)
            ]
        return statistics.median(vals) if vals else None

    summary = {
        "style": args.style,
        "typical_driver": scorer.typical,
        "ours_overrides": overrides,
        "check_every": args.check_every,
        "target_recall": scorer.target_recall,
        "target_balanced_accuracy": scorer.target_bacc,
        "ours_hits": sum(r["hit"] is not None for r in ours),
        "sb3_hits": sum(r["hit"] is not None for r in sb3),
        "ours_median_s_to_target": med(ours, "wall_s"),
        "sb3_median_s_to_target": med(sb3, "wall_s"),
        "ours_median_steps_to_target": med(ours, "env_steps"),
        "sb3_median_steps_to_target": med(sb3, "env_steps"),
        "ours_median_steps_per_s": statistics.median(r["steps_per_s"] for r in ours),
        "ours_median_s_full_run": statistics.median(r["wall_s"] for r in ours),
        "ours_final": [r["last"] for r in ours],
        "sb3_median_steps_per_s": statistics.median(r["steps_per_s"] for r in sb3) if sb3 else None,
    }
    if summary["ours_median_s_to_target"] and summary["sb3_median_s_to_target"]:
        summary["speedup_to_target"] = summary["sb3_median_s_to_target"] / summary["ours_median_s_to_target"]
    print(json.dumps(summary, indent=2))
    write_result(
        args.out or f"train_{args.style.lower()}",
        {
            **summary,
            "repeats": args.repeats,
            "episodes": args.episodes,
            "budget_s": args.budget_s,
            "ours": ours,
            "sb3": sb3,
        },
    )


if __name__ == "__main__":
    main()
