"""Where the agent loses to the imitation classifier: the network, or the reinforcement learning?

On the crossval folds of one target (sessions in K folds, `rl.evaluation.crossval`), three
supervised classifiers of press vs not-yet state are fitted on the training
folds' states, in the agent's own observation, and judged on the held-out fold:

- `trees`: the imitation benchmark (`rl.baselines.imitation`, gradient-boosted trees);
- `mlp`: the agent's own network (`rl.learners.dqn.q_network`, one output), trained
  directly on the labels (class-balanced cross-entropy, Adam, 60 epochs);
- `mlp-piecewise`: the same network reading each input piecewise-linearly over 8
  quantile bins of the training states (Gorishniy et al., NeurIPS 2022).

If the plain MLP ranks the held-out states worse than the trees even when taught
the labels directly, the agent's gap to the classifier is its function class,
not its reward or its training. Prints per classifier the pooled held-out ROC AUC
(ranking) and balanced accuracy (at the balanced 0.5 threshold), and each side's where
the target changed lanes to both; writes them to `benchmarks/results/<--out>.json` (default
`function_class_<style>`).

    python benchmarks/function_class.py -w WORKSPACE --style Aggressive [--folds 4] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from results_file import write_result  # beside this file: imported before the folder leaves the path

# benchmarks/ holds scripts named like packages (dashboard.py, ingest.py): keep it off the import path
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402
import torch  # noqa: E402
from sklearn.metrics import roc_auc_score  # noqa: E402

from laneprint.workspace import Workspace  # noqa: E402
from rl.evaluation.crossval import CrossvalSettings, assign_folds  # noqa: E402
from rl.learners.dqn import DQNSettings, q_network  # noqa: E402
from rl.problem.env import EnvConfig, approaches_from_decisions, formulation_config  # noqa: E402
from rl.baselines.imitation import ImitationClassifier, labelled_states  # noqa: E402
from rl.runs import Target, target_drivers  # noqa: E402


def piecewise(x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Each column read over its bins: 0 below a bin, 1 above it, linear inside."""
    lo, width = edges[:, :-1], np.maximum(np.diff(edges, axis=1), 1e-6)
    return np.clip((x[:, :, None] - lo) / width, 0.0, 1.0).reshape(len(x), -1).astype(np.float32)


def mlp_scores(x_train: np.ndarray, y_train: np.ndarray, x_test: np.ndarray, seed: int, epochs: int = 60) -> np.ndarray:
    """Logits of the agent-shaped MLP trained on the labels (classes balanced)."""
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    xt, yt = torch.from_numpy(x_train.astype(np.float32)), torch.from_numpy(y_train.astype(np.float32))
    net = q_network(DQNSettings().hidden, x_train.shape[1], n_actions=1)  # the agent's network, one output
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    weight = torch.where(yt == 1, float((1 - y_train.mean()) / y_train.mean()), 1.0)
    for _ in range(epochs):
        order = torch.randperm(len(yt), generator=gen)
        for i in range(0, len(yt), 256):
            b = order[i : i + 256]
            loss = torch.nn.functional.binary_cross_entropy_with_logits(net(xt[b]).squeeze(1), yt[b], weight=weight[b])
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        return net(torch.from_numpy(x_test.astype(np.float32))).squeeze(1).numpy()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-w", "--workspace", type=Path, required=True)
    ap.add_argument("--style", required=True)
    ap.add_argument("--folds", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--out", default=None, help="result file name under benchmarks/results/ (default function_class_<style>)"
    )
    args = ap.parse_args()
    torch.set_num_threads(1)
    ws = Workspace(args.workspace)
    drivers, _ = target_drivers(ws, Target("style", args.style))
    dec = ws.read_table("analysis", "decisions")
    dec = dec[dec["driver_id"].astype(str).isin(drivers)]
    cfg: EnvConfig = formulation_config(EnvConfig().lines)  # the default observation; lines play no part here
    sessions = (
        dec.groupby("recording_id", sort=True)
        .agg(driver_id=("driver_id", "first"), speed_limit_kph=("speed_limit_kph", "first"))
        .reset_index()
    )
    fold_of = assign_folds(sessions, CrossvalSettings(folds=args.folds, seed=args.seed))
    fold = dec["recording_id"].astype(str).map(fold_of).to_numpy()
    scores: dict[str, list[np.ndarray]] = {"trees": [], "mlp": [], "mlp-piecewise": []}
    labels, left = [], []
    for k in range(int(fold.max()) + 1):
        train, _ = approaches_from_decisions(dec[fold != k])
        test, _ = approaches_from_decisions(dec[fold == k])
        x_tr, y_tr = labelled_states(train, cfg)
        x_te, y_te = labelled_states(test, cfg)
        clf = ImitationClassifier(random_state=args.seed + k).fit(train, cfg)
        scores["trees"].append(clf.press_probability(x_te) - 0.5)
        scores["mlp"].append(mlp_scores(x_tr, y_tr, x_te, args.seed + k))
        edges = np.quantile(x_tr, np.linspace(0, 1, 9), axis=0).T
        scores["mlp-piecewise"].append(mlp_scores(piecewise(x_tr, edges), y_tr, piecewise(x_te, edges), args.seed + k))
        labels.append(y_te)
        left.append(np.concatenate([a.scene.left for a in test]))
        print(f"fold {k + 1}: {len(train)} training decisions, {len(test)} held out", flush=True)
    y, side = np.concatenate(labels), np.concatenate(left)
    print(f"\n{args.style}, {len(y)} held-out states ({int(y.sum())} presses), observation '{cfg.observation}':")
    rows = []
    for name, parts in scores.items():
        s = np.concatenate(parts)
        row = {"classifier": name, **_figures(y, s)}
        line = f"  {name:14s} " + _text(row)
        if side.any() and not side.all():  # changes to both sides: each side's figures too
            left, right = _figures(y[side], s[side]), _figures(y[~side], s[~side])
            line += "   left " + _text(left) + "   right " + _text(right)
            row |= {f"left_{k}": v for k, v in left.items()} | {f"right_{k}": v for k, v in right.items()}
        rows.append(row)
        print(line)
    write_result(
        args.out or f"function_class_{args.style.lower()}",
        {
            "style": args.style,
            "folds": args.folds,
            "seed": args.seed,
            "observation": cfg.observation,
            "held_out_states": len(y),
            "presses": int(y.sum()),
            "classifiers": rows,
        },
    )
    return 0


def _figures(y: np.ndarray, s: np.ndarray) -> dict[str, float]:
    ba = 0.5 * ((s[y == 1] > 0).mean() + (s[y == 0] <= 0).mean())
    return {"roc_auc": float(roc_auc_score(y, s)), "balanced_accuracy": float(ba)}


def _text(f: dict[str, float]) -> str:
    return f"ROC AUC {f['roc_auc']:.3f}, balanced accuracy {100 * f['balanced_accuracy']:.1f} %"


if __name__ == "__main__":
    sys.exit(main())
