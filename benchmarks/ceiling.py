"""How well can anything read a style's presses from what the agent sees? Held out, per style.

`laneprint crossval` scores the agent, greedy and imitation on held-out sessions with the
balanced accuracy (recall at the presses, specificity at the not-yet states). When an
agent misses "agent >= greedy + 10", is the agent weak, or is the bar above what the
observation holds? This script answers the second question on the same folds as
`crossval --seed S` (same fold assignment, same refitted lines for greedy):

- `greedy`: the study's greedy benchmark (as in crossval);
- `imitation`: crossval's imitation classifier (gradient-boosted trees, threshold 0.5);
- `trees` / `logistic` / `forest`: three classifiers fitted on the training folds' states,
  each scored at its best threshold **chosen on the held-out states themselves**
  (every threshold tried, the best balanced accuracy kept). That choice peeks at the
  answers, so these figures are optimistic: an upper estimate of what a policy reading this
  observation reaches, not a method;
- `ceiling`: the best of the three optimistic figures; `bar` = greedy + 10 points.

Every row is also written to `benchmarks/results/<--out>.json` (default `ceiling`).

When `ceiling < bar` no policy of this observation can be expected to meet the bar on
these sessions: the miss is the bar's, not the agent's.

    .venv/bin/python benchmarks/ceiling.py WS [WS ...] [--seeds 0 1] [--styles Defensive]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

from results_file import write_result  # beside this file: imported before the folder leaves the path

# this folder holds scripts named like packages (ingest.py): keep it off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402
from threadpoolctl import threadpool_limits  # noqa: E402

from laneprint.workspace import Workspace  # noqa: E402
from rl.baselines.imitation import ImitationClassifier, labelled_states  # noqa: E402
from rl.evaluation.crossval import CrossvalSettings, assign_folds, fold_lines  # noqa: E402
from rl.evaluation.crossval_store import stored_settings, style_names, target_env  # noqa: E402
from rl.evaluation.evaluate import greedy_policy  # noqa: E402
from rl.problem.env import EnvConfig, approaches_from_decisions, formulation_config  # noqa: E402
from rl.problem.rewards import CHANGE  # noqa: E402
from rl.problem.scene import Scene  # noqa: E402
from rl.runs import Target, target_drivers  # noqa: E402


READERS = ("trees", "logistic", "forest")


def classifiers(seed: int) -> dict:
    """The optimistic readers: name -> unfitted scikit-learn classifier (classes balanced)."""
    from sklearn.ensemble import HistGradientBoostingClassifier, RandomForestClassifier
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    return {
        "trees": HistGradientBoostingClassifier(
            max_iter=200,
            learning_rate=0.05,
            max_leaf_nodes=15,
            min_samples_leaf=20,
            class_weight="balanced",
            early_stopping=False,
            random_state=seed,
        ),
        "logistic": make_pipeline(StandardScaler(), LogisticRegression(class_weight="balanced", max_iter=2000)),
        "forest": RandomForestClassifier(
            n_estimators=300, min_samples_leaf=5, class_weight="balanced", random_state=seed, n_jobs=1
        ),
    }


def balanced_accuracy(said_change: np.ndarray, y: np.ndarray) -> float:
    return float((said_change[y == 1].mean() + (~said_change[y == 0]).mean()) / 2)


def best_threshold_ba(p: np.ndarray, y: np.ndarray) -> float:
    """The best balanced accuracy of `p > threshold` over every threshold (chosen on these labels)."""
    order = np.argsort(-p, kind="stable")
    ys = y[order]
    tp = np.cumsum(ys)  # said change for the top k
    fp = np.cumsum(1 - ys)
    rec = tp / max(ys.sum(), 1)
    spec = 1 - fp / max((1 - ys).sum(), 1)
    distinct = np.r_[p[order][1:] != p[order][:-1], True]  # cut only between different scores
    return float(max(np.max(((rec + spec) / 2)[distinct]), 0.5))


def style_ceiling(ws: Workspace, style: str, seed: int) -> dict:
    """Held-out balanced accuracy of greedy, imitation and the optimistic readers for one style."""
    target = Target("style", style)
    env: EnvConfig = target_env(
        ws, target, formulation_config(EnvConfig().lines, None, None, None, "analysis", None), "analysis"
    )
    decisions = ws.read_table("analysis", "decisions")
    drivers, typical = target_drivers(ws, target)
    dec = decisions[decisions["driver_id"].astype(str).isin(drivers)]
    sessions = (
        dec.groupby("recording_id", sort=True)
        .agg(driver_id=("driver_id", "first"), speed_limit_kph=("speed_limit_kph", "first"))
        .reset_index()
    )
    fold_of = assign_folds(sessions, CrossvalSettings(seed=seed))
    fold = dec["recording_id"].astype(str).map(fold_of).to_numpy()
    said: dict[str, list[np.ndarray]] = {n: [] for n in ("greedy", "imitation")}
    probs: dict[str, list[np.ndarray]] = {n: [] for n in READERS}
    labels = []
    for k in range(int(fold.max()) + 1):
        train_app, _ = approaches_from_decisions(dec[fold != k])
        test_app, _ = approaches_from_decisions(dec[fold == k])
        if not train_app or not test_app:
            continue
        lines, _ = fold_lines(dec[fold != k], [typical] if typical else drivers, env.lines, stored_settings(ws))
        cfg = replace(env, lines=lines)
        X, y = labelled_states(train_app, cfg)
        Xt, yt = labelled_states(test_app, cfg)
        labels.append(yt)
        scene = Scene.concat([a.scene for a in test_app])
        said["greedy"].append(greedy_policy(cfg)(scene) == CHANGE)
        said["imitation"].append(
            ImitationClassifier(random_state=seed + k).fit(train_app, cfg).policy(cfg)(scene) == CHANGE
        )
        with threadpool_limits(limits=1, user_api="openmp"):
            for name, clf in classifiers(seed + k).items():
                probs[name].append(clf.fit(X, y).predict_proba(Xt)[:, 1])
    y = np.concatenate(labels)
    out = {"style": style, "seed": seed, "n_presses": int(y.sum()), "n_states": int(len(y))}
    for name in [*said, *probs]:
        out[name] = (
            balanced_accuracy(np.concatenate(said[name]), y)
            if name in said
            else best_threshold_ba(np.concatenate(probs[name]), y)
        )
    out["ceiling"] = max(out[n] for n in probs)
    out["bar"] = out["greedy"] + 0.10
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("workspaces", nargs="+", type=Path, help="analysed workspaces")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="crossval seeds (fold assignment)")
    ap.add_argument("--styles", nargs="*", help="only these styles (default: every style)")
    ap.add_argument("--json", action="store_true", help="one JSON row per (workspace, style, seed)")
    ap.add_argument("--out", default="ceiling", help="result file name under benchmarks/results/")
    args = ap.parse_args()
    cols = ["greedy", "imitation", "trees", "logistic", "forest", "ceiling", "bar"]
    if not args.json:
        print(f"{'workspace':28} {'style':11} seed presses " + " ".join(f"{c:>9}" for c in cols) + "  ceiling<bar")
    rows = []
    for root in args.workspaces:
        ws = Workspace(root)
        for style in args.styles or style_names(ws):
            for seed in args.seeds:
                r = style_ceiling(ws, style, seed)
                r["workspace"] = str(root)
                r["ceiling_below_bar"] = r["ceiling"] < r["bar"]
                rows.append(r)
                if args.json:
                    print(json.dumps(r), flush=True)
                    continue
                print(
                    f"{root.name:28} {style:11} {seed:4} {r['n_presses']:7} "
                    + " ".join(f"{100 * r[c]:9.1f}" for c in cols)
                    + f"  {'yes' if r['ceiling'] < r['bar'] else 'no'}",
                    flush=True,
                )
    write_result(args.out, {"seeds": args.seeds, "rows": rows})


if __name__ == "__main__":
    main()
