"""Fitted Q iteration with boosted regression trees (Ernst, Geurts & Wehenkel 2005) on recorded approaches.

The `decisions` reward's problem is known in full from the recordings: at each recorded
state TO CHANGE ends the approach with `press_reward` (its time to the driver's press), and
NOT TO CHANGE moves on to the next recorded state (earning 0) or, at the press, costs the pass
penalty and leaves a change one step late as the best that is left. So no exploration is
needed: Q(change) is regressed once on its reward and Q(keep) `iterations` times on
``gamma * max(Q(next state))``. The presses, one state in 10-30, weigh `press_weight` times
the others in both regressions (unweighted, the trees keep too often). A side a middle-lane driver did not take (`Approach.other`)
is an approach without a press, as in `VecReplayEnv`: a change there earns the reward's floor,
keeping to its end earns 0.

Why trees: where a driver changes the moment a gap turns acceptable (a sharp threshold), the
Q network cannot tell the press from the step before it and changes early, while trees can
(rl/README.md, "A tree Q function"). The fitted ensembles become `TreeQNetwork`, a torch
module with the Q network's interface (observations in, Q(change) and Q(keep) out), so
evaluation, `drive`, `annotate` and the ONNX export read it as they read the DQN's network.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Any, Iterator

import numpy as np
import torch
from sklearn.ensemble import HistGradientBoostingRegressor
from sklearn.ensemble._hist_gradient_boosting import binning as _binning
from threadpoolctl import threadpool_limits
from torch import nn

from laneprint.errors import UserError
from laneprint.progress import ProgressFn, report
from rl.problem.env import NO_PRESS_S, Approach, EnvConfig, observation
from rl.problem.rewards import CHANGE, KEEP, press_reward
from rl.settings import TreeQSettings, trees_fit

__all__ = ["TreeQNetwork", "ensemble_changes", "fit_tree_ensembles", "fit_tree_q", "fitted_q_data"]


def fitted_q_data(approaches: list[Approach], cfg: EnvConfig) -> dict[str, np.ndarray]:
    """The recorded transitions as arrays, one row per state: `obs`, `r_change` (TO CHANGE's
    reward), `press` (the driver's press), `next` (the next state's row; its own at an approach's
    end), `end` (an approach's last state) and `end_keep` (NOT TO CHANGE's value there, where the
    approach ends). A side not taken sits `NO_PRESS_S` before a press that never comes, as
    `VecReplayEnv` replays it."""
    reward = cfg.reward
    assert reward.pass_penalty is not None  # default resolved by RewardSettings.__post_init__
    after_press = -reward.pass_penalty + float(press_reward(np.array([cfg.dt_s]), reward)[0])
    sides = [(a.scene, a.t_s - a.press_t_s, after_press) for a in approaches]
    if cfg.other_side:
        sides += [(a.other, np.full(len(a), -NO_PRESS_S), 0.0) for a in approaches if a.other is not None]
    if not sides:
        raise UserError("no recorded approaches to fit the tree Q function on")
    lengths = np.array([len(t) for _, t, _ in sides])
    end = np.zeros(lengths.sum(), bool)
    end[np.cumsum(lengths) - 1] = True
    rows = np.arange(len(end))
    t_rel = np.concatenate([t for _, t, _ in sides])
    return {
        "obs": np.concatenate([observation(s, cfg) for s, _, _ in sides]).astype(np.float32),
        "r_change": press_reward(t_rel, reward),
        "press": t_rel == 0.0,
        "next": np.where(end, rows, rows + 1),
        "end": end,
        "end_keep": np.repeat([v for _, _, v in sides], lengths),
    }


_BINNING_LOCK = threading.Lock()


def _weighted_percentiles(values: np.ndarray, weight: np.ndarray, ranks: np.ndarray) -> np.ndarray:
    """scikit-learn's `_weighted_percentile(values, weight, ranks, average=True)` of a 1-D column with no
    NaN and no zero weight, every rank at once: the same sort, cumulative sum and float operations, one
    percentile after another in scikit-learn and element by element here."""
    order = np.argsort(values.reshape(-1, 1), axis=0)[:, 0]  # scikit-learn's sort (not stable) of the column
    cdf = np.cumsum(weight[order])
    rank = ranks / 100 * cdf[-1]
    rank[rank == 0] = np.nextafter(rank[rank == 0], rank[rank == 0] + 1)
    last = len(values) - 1
    at = np.clip(np.searchsorted(cdf, rank), 0, last)
    above = (cdf[at] - rank) > np.finfo(values.dtype).eps
    low, high = values[order[at]], values[order[np.clip(at + 1, 0, last)]]
    return np.where(above, low, (low + high) / 2)


def _thresholds_batched(col_data: np.ndarray, max_bins: int, sample_weight: np.ndarray | None = None) -> np.ndarray:
    """scikit-learn's `_find_binning_thresholds` with the weighted percentiles of a column taken at once.

    scikit-learn takes the 255 weighted percentiles of a column one call at a time, each sorting the column
    again (about 2 s of a 7 s fit on a style's states); `_weighted_percentiles` takes them from one sort with
    the same arithmetic, so the thresholds are the same to the bit (tests/rl/test_rl_trees.py checks them
    against scikit-learn's). Without weights, or with at most `max_bins` distinct values, scikit-learn's own."""
    from sklearn.ensemble._hist_gradient_boosting.common import ALMOST_INF, X_DTYPE

    if sample_weight is None:
        return _SKLEARN_THRESHOLDS(col_data, max_bins, sample_weight)
    missing = np.isnan(col_data)
    if missing.any():
        col_data, sample_weight = col_data[~missing], sample_weight[~missing]
    nonzero = sample_weight != 0
    col_data, sample_weight = col_data[nonzero], sample_weight[nonzero]
    order = np.argsort(col_data)
    col_data, sample_weight = col_data[order], sample_weight[order]
    if len(np.unique(col_data)) <= max_bins or col_data.dtype != np.float64 or sample_weight.dtype != np.float64:
        return _SKLEARN_THRESHOLDS(col_data, max_bins, sample_weight)
    thresholds = _weighted_percentiles(col_data, sample_weight, np.linspace(0, 100, num=max_bins + 1)[1:-1])
    unique = np.unique(thresholds)
    if unique.shape[0] != thresholds.shape[0]:
        thresholds = unique
    np.clip(thresholds, a_min=None, a_max=ALMOST_INF, out=thresholds)
    return thresholds.astype(X_DTYPE, copy=False)


_SKLEARN_THRESHOLDS = _binning._find_binning_thresholds


class _SharedBins(HistGradientBoostingRegressor):
    """`HistGradientBoostingRegressor` whose training data is binned once for all the regressions of one
    fitted Q iteration: they share the states and weights, so they share the bins. With sample weights,
    scikit-learn bins by one weighted percentile at a time, about three quarters of a fit on a style's
    states (2,261 states: 8.6 of 11.6 s per inner fold); the bins, and so the trees, are the same. Binning
    draws from `random_state` only to subsample above `_BinMapper.subsample` rows: there it bins itself."""

    _bins: dict[str, Any] | None = None  # the fitted bin mapper and binned states, set by the first fit
    _bin_mapper: Any  # scikit-learn's, set by its fit (declared for the type checker)

    def _bin_data(self, X: Any, sample_weight: Any, is_training_data: bool) -> Any:
        shared = self._bins
        if not is_training_data or shared is None or X.shape[0] > self._bin_mapper.subsample:
            return super()._bin_data(X, sample_weight, is_training_data)
        if "binned" not in shared or shared["shape"] != X.shape:
            with _BINNING_LOCK:  # scikit-learn's binning, its weighted percentiles taken one column at a time
                _binning._find_binning_thresholds = _thresholds_batched
                try:
                    binned = super()._bin_data(X, sample_weight, is_training_data)
                finally:
                    _binning._find_binning_thresholds = _SKLEARN_THRESHOLDS
            shared.update(binned=binned, mapper=self._bin_mapper, shape=X.shape)
        self._bin_mapper = shared["mapper"]
        return shared["binned"].copy(order="F")


def _regressor(settings: TreeQSettings, seed: int, bins: dict[str, Any] | None = None) -> HistGradientBoostingRegressor:
    model = _SharedBins(
        max_iter=settings.trees,
        learning_rate=settings.learning_rate,
        max_leaf_nodes=settings.max_leaf_nodes,
        min_samples_leaf=settings.min_samples_leaf,
        early_stopping=False,
        random_state=seed,
    )
    model._bins = bins
    return model


_ONE_THREAD = threading.local()


@contextmanager
def _one_thread() -> Iterator[None]:
    """One OpenMP thread, as the imitation classifier (a busy machine's spinning thread team cost 10x), set
    once for a whole fitted Q iteration: `threadpool_limits` looks up the loaded libraries on every call
    (2-3 ms, about 0.2 s of an inner fold's 72 fits and predictions); nested calls keep the outer limit."""
    if getattr(_ONE_THREAD, "depth", 0):
        yield
        return
    with threadpool_limits(limits=1, user_api="openmp"):
        _ONE_THREAD.depth = 1
        try:
            yield
        finally:
            _ONE_THREAD.depth = 0


def _fit(
    model: HistGradientBoostingRegressor, x: np.ndarray, y: np.ndarray, weight: np.ndarray
) -> HistGradientBoostingRegressor:
    with _one_thread():
        return model.fit(x, y, sample_weight=weight)


def _predict(model: HistGradientBoostingRegressor, x: np.ndarray) -> np.ndarray:
    with _one_thread():
        return model.predict(x)


def fit_tree_q(
    approaches: list[Approach],
    cfg: EnvConfig,
    settings: TreeQSettings,
    progress: ProgressFn | None = None,
    label: str = "tree Q",
) -> "TreeQNetwork":
    """Fitted Q iteration on `approaches` (the `decisions` reward); the Q function as a torch module."""
    models, x0 = fit_tree_ensembles(approaches, cfg, settings, progress, label)
    return TreeQNetwork.from_ensembles(models, x0)


def fit_tree_ensembles(
    approaches: list[Approach],
    cfg: EnvConfig,
    settings: TreeQSettings,
    progress: ProgressFn | None = None,
    label: str = "tree Q",
) -> tuple[dict[int, HistGradientBoostingRegressor], np.ndarray]:
    """Fitted Q iteration on `approaches`: (one fitted ensemble per action index, one observation) as
    `TreeQNetwork.from_ensembles` takes them."""
    if not trees_fit(cfg.reward.name, cfg.scenes):
        raise UserError(
            "the tree learner fits the 'decisions' reward on recorded scenes: "
            "leave out --reward/--scenes or use --learner dqn"
        )
    d = fitted_q_data(approaches, cfg)
    x, nxt, end = d["obs"], d["next"], d["end"]
    weight = np.where(d["press"], settings.press_weight, 1.0)
    total = settings.iterations + 1
    bins: dict[str, Any] = {}  # every regression below fits the same states with the same weights
    with _one_thread():
        q_change = _fit(_regressor(settings, settings.seed, bins), x, d["r_change"], weight)
        change_x = _predict(q_change, x)
        report(progress, 1, total, label)
        keep_x = np.zeros(len(x))
        for it in range(settings.iterations):  # at least one (`TreeQSettings` checks)
            target = np.where(end, d["end_keep"], settings.gamma * np.maximum(change_x[nxt], keep_x[nxt]))
            q_keep = _fit(_regressor(settings, settings.seed + 1 + it, bins), x, target, weight)
            keep_x = _predict(q_keep, x)
            report(progress, it + 2, total, label)
    return {CHANGE: q_change, KEEP: q_keep}, x[:1]


def ensemble_changes(models: dict[int, HistGradientBoostingRegressor], obs: np.ndarray) -> np.ndarray:
    """Whether the greedy action of the fitted ensembles is TO CHANGE at `obs` (ties change, as `greedy_actions`),
    by scikit-learn's predictions (in double precision: `TreeQNetwork` compares single-precision observations
    with single-precision thresholds, so a state on a threshold may go the other way)."""
    with _one_thread():
        return _predict(models[CHANGE], obs) >= _predict(models[KEEP], obs)


class TreeQNetwork(nn.Module):
    """Boosted regression trees as a torch module: `forward(obs) -> Q` of shape (n, 2), like `q_network`.

    Every tree of every action is one row of padded node arrays; a batch walks all trees at
    once, one level per step, by gathering each node's feature, threshold and children (a leaf
    is its own child). Its state dict is plain tensors, so a run's `weights.pt` holds it and
    `torch.onnx.export` writes it as Gather and Where operators.
    """

    # the buffers registered in __init__ (declared for the type checker: nn.Module types them as Tensor | Module)
    feature: torch.Tensor
    threshold: torch.Tensor
    left: torch.Tensor
    right: torch.Tensor
    value: torch.Tensor
    missing_left: torch.Tensor
    base: torch.Tensor
    depth: torch.Tensor

    def __init__(
        self,
        feature: torch.Tensor,
        threshold: torch.Tensor,
        left: torch.Tensor,
        right: torch.Tensor,
        value: torch.Tensor,
        missing_left: torch.Tensor,
        base: torch.Tensor,
        depth: torch.Tensor,
    ) -> None:
        super().__init__()
        for name, t in (
            ("feature", feature),
            ("threshold", threshold),
            ("left", left),
            ("right", right),
            ("value", value),
            ("missing_left", missing_left),
            ("base", base),
            ("depth", depth),
        ):
            self.register_buffer(name, t)
        self.n_actions = int(base.shape[0])
        self.n_levels = int(depth.item())

    @staticmethod
    def from_state_dict(state: dict[str, torch.Tensor]) -> "TreeQNetwork":
        """The module saved by `state_dict()` (a run's `weights.pt`)."""
        return TreeQNetwork(
            **{k: state[k] for k in ("feature", "threshold", "left", "right", "value", "missing_left", "base", "depth")}
        )

    @staticmethod
    def from_ensembles(models: dict[int, HistGradientBoostingRegressor], x0: np.ndarray) -> "TreeQNetwork":
        """Module of one fitted ensemble per action index; `x0`: one observation, to read each ensemble's
        constant (its prediction there less its trees' sum).

        Reads scikit-learn's fitted trees (`_predictors`: per boosting round, a `TreePredictor` whose
        `nodes` hold feature, threshold, children and the leaf value with the step applied); the tests
        check the module against `predict`, so a scikit-learn that changes them fails there first.
        """
        try:
            per_action = {a: [p[0].nodes for p in m._predictors] for a, m in models.items()}
        except AttributeError as exc:  # pragma: no cover - a scikit-learn without the fitted trees we read
            raise UserError(f"this scikit-learn's boosted trees cannot be read as a Q module ({exc})") from None
        n_actions = max(models) + 1
        n_trees = max(len(t) for t in per_action.values())
        width = max(len(nodes) for t in per_action.values() for nodes in t)
        shape = (n_actions * n_trees, width)
        feature, left, right = (np.zeros(shape, np.int64) for _ in range(3))
        threshold, value = np.full(shape, np.inf, np.float32), np.zeros(shape, np.float32)
        missing_left = np.ones(shape, bool)
        depth = 0
        for a in range(n_actions):  # an action's trees fill its block; the rest stay one-leaf trees of value 0
            for j, nodes in enumerate(per_action.get(a, [])):
                i, k = a * n_trees + j, len(nodes)
                leaf = nodes["is_leaf"].astype(bool)
                own = np.arange(k)
                feature[i, :k] = np.where(leaf, 0, nodes["feature_idx"])
                threshold[i, :k] = np.where(leaf, np.inf, nodes["num_threshold"])
                missing_left[i, :k] = leaf | nodes["missing_go_to_left"].astype(bool)
                left[i, :k] = np.where(leaf, own, nodes["left"])
                right[i, :k] = np.where(leaf, own, nodes["right"])
                value[i, :k] = np.where(leaf, nodes["value"], 0.0)
                depth = max(depth, int(nodes["depth"].max()))
        net = TreeQNetwork(
            torch.from_numpy(feature),
            torch.from_numpy(threshold),
            torch.from_numpy(left),
            torch.from_numpy(right),
            torch.from_numpy(value),
            torch.from_numpy(missing_left),
            torch.zeros(n_actions),
            torch.tensor(depth),
        )
        with torch.no_grad():
            sums = net.forward(torch.as_tensor(x0, dtype=torch.float32))[0]
        net.base.copy_(
            torch.tensor(
                [float(_predict(models[a], x0)[0]) - float(sums[a]) if a in models else 0.0 for a in range(n_actions)]
            )
        )
        return net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n_trees, width = self.feature.shape
        n = x.shape[0]
        offset = (torch.arange(n_trees) * width).unsqueeze(1)  # a tree's first node in the flat arrays
        f, thr, val, miss = (t.reshape(-1) for t in (self.feature, self.threshold, self.value, self.missing_left))
        lft, rgt = ((t + offset).reshape(-1) for t in (self.left, self.right))  # children as flat indices
        node = offset.reshape(1, n_trees).expand(n, n_trees).reshape(-1)  # every row at every tree's root
        for _ in range(self.n_levels):  # gathers along one flat axis (indexing a tensor by a tensor: 10x slower)
            xv = x.gather(1, f.gather(0, node).reshape(n, n_trees)).reshape(-1)
            go_left = (xv <= thr.gather(0, node)) | (torch.isnan(xv) & miss.gather(0, node))  # NaN: its trained side
            node = torch.where(go_left, lft.gather(0, node), rgt.gather(0, node))
        leaves = val.gather(0, node).reshape(n, self.n_actions, n_trees // self.n_actions)
        return leaves.sum(dim=2) + self.base
