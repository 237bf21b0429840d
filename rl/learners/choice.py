"""`--learner auto`: for each target, the learner whose held-out agreement is higher on an inner split.

Neither learner is best everywhere (rl/README.md, "A tree Q function"): the trees resolve a
driver who changes the moment a gap turns acceptable, the DQN reads the smoother presses of
the shipped study better. So `choose_learner` deals the target's own training sessions into
inner folds, fits both learners on all but one fold and predicts that one, scores each
learner's pooled predictions of every session once (the mean of the left and right balanced
accuracies on the presses and not-yet states, so a weak side counts), and fits the better one on
all of them; the trees must win by more than `AutoSettings.margin` (a near-tie keeps the DQN).
One split of a quarter of the sessions was too noisy a judge (rl/README.md). Inside `crossval`
this happens within each fold's training sessions: the held-out fold never takes part in the choice.

`choose_and_fit` makes the choice at about the price of one learner: the inner folds' DQNs and the
target's own DQN (the one kept when the DQN wins, as `fit_learner` would fit it) train as one
batched fleet (`rl.fleet.batch.FleetTrainer`, each agent computing what `DQNTrainer` computes up to
floating-point summation order), for every target at once (a cross-validation's outer folds), the
trees' inner fits before them (or beside them: `AutoSettings.trees_beside`). With `AutoSettings.stop_early`, from `check_from` of
the inner DQNs' episodes on, their pooled inner score is read every `check_every`; where the trees'
score lies beyond that running score + `reach` (or - `reach_down`) x the share of episodes left (beyond the margin for
the trees, within it for the DQN), the choice cannot change: the inner DQNs stop (and, when the
trees win, the target's DQN too), and the stored choice says so (`Choice.stopped`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from laneprint.progress import ProgressFn, report
from rl.baselines.imitation import labelled_states
from rl.problem.env import Approach, EnvConfig, learner_env
from rl.problem.rewards import CHANGE
from rl.settings import AutoSettings, DQNSettings, TreeQSettings

__all__ = [
    "ChoiceTask",
    "Choice",
    "Fitted",
    "InnerFold",
    "choose_and_fit",
    "choose_learner",
    "chosen_settings",
    "fit_learner",
    "inner_folds",
    "inner_trees",
]


@dataclass(frozen=True)
class Choice:
    """Which learner `choose_learner` took, and why."""

    learner: str  # 'dqn' or 'trees'
    scores: dict[str, float]  # each learner's inner held-out score (mean balanced accuracy over the sides)
    n_train: int  # the target's approaches
    n_holdout: int  # approaches the candidates were scored on (each once, by a fit without its session)
    folds: int = 0  # inner folds
    by_side: dict[str, dict[str, float]] = field(default_factory=dict)  # each learner's score per side
    stopped: str = ""  # why the inner DQNs stopped before their episodes ('' : they ran to the end)
    checks: list[dict[str, float]] = field(default_factory=list)  # the running DQN score at each check

    def to_dict(self) -> dict[str, Any]:
        return {
            "learner": self.learner,
            "scores": self.scores,
            "n_train": self.n_train,
            "n_holdout": self.n_holdout,
            "folds": self.folds,
            "by_side": self.by_side,
            "stopped": self.stopped,
            "checks": self.checks,
        }


def session_of(decision_id: str) -> str:
    """The recording a decision belongs to (decision ids are '<recording_id>:<press index>')."""
    return decision_id.rsplit(":", 1)[0]


def inner_folds(approaches: list[Approach], folds: int, seed: int) -> list[tuple[list[Approach], list[Approach]]]:
    """`folds` (fit, hold-out) pairs whose hold-outs cover the sessions once each (seeded).

    Each driver's sessions are shuffled and dealt in turn to the folds, so every driver with two or
    more sessions is held out somewhere and kept to fit on everywhere; a driver with one session is
    always fitted on. Where no driver has two sessions, whole sessions are dealt instead.
    """
    rng = np.random.default_rng([seed, 11])
    by_driver: dict[str, list[str]] = {}
    for a in approaches:
        s = session_of(a.decision_id)
        if s not in by_driver.setdefault(a.driver_id, []):
            by_driver[a.driver_id].append(s)
    groups = [sessions for sessions in by_driver.values() if len(sessions) >= 2]
    if not groups:  # one session per driver: deal the sessions themselves
        groups = [sorted({session_of(a.decision_id) for a in approaches})]
    fold_of: dict[str, int] = {}
    offset = 0
    for sessions in groups:
        for i, s in enumerate(rng.permutation(sorted(sessions))):
            fold_of[str(s)] = (offset + i) % folds  # a driver's sessions go to different folds first
        offset += len(sessions)  # the next driver starts where this one stopped: folds stay even
    pairs = []
    for f in range(folds):
        out = [a for a in approaches if fold_of.get(session_of(a.decision_id)) == f]
        fit = [a for a in approaches if fold_of.get(session_of(a.decision_id)) != f]
        if out and fit:
            pairs.append((fit, out))
    return pairs


def side_scores(change: np.ndarray, y: np.ndarray, left: np.ndarray) -> dict[str, float]:
    """The balanced accuracy of the changes `change` against labels `y`, per side present ('left', 'right')."""
    scores = {}
    for name, side in (("left", left), ("right", ~left)):
        yes, no = side & (y == 1), side & (y == 0)
        if yes.any() and no.any():
            scores[name] = round(float(0.5 * (change[yes].mean() + (~change[no]).mean())), 4)
    return scores


def held_out_changes(net: Any, approaches: list[Approach], cfg: EnvConfig) -> tuple[np.ndarray, ...]:
    """(`net`'s greedy change-or-not, the labels, whether the side is left) on `approaches`' states."""
    from rl.learners.dqn import greedy_actions

    x, y = labelled_states(approaches, cfg)
    left = np.concatenate([a.scene.left for a in approaches])
    return greedy_actions(net, x) == CHANGE, y, left


def fit_learner(
    approaches: list[Approach],
    cfg: EnvConfig,
    settings: DQNSettings | TreeQSettings,
    progress: ProgressFn | None = None,
    label: str = "agent",
) -> Any:
    """The Q network of `settings`' learner fitted on `approaches` (`cfg` as that learner reads it)."""
    if isinstance(settings, TreeQSettings):
        from rl.learners.trees import fit_tree_q

        return fit_tree_q(approaches, learner_env(cfg, "trees"), settings, progress, label)
    from rl.learners.dqn import DQNTrainer

    trainer = DQNTrainer(cfg, settings, approaches=approaches)

    def tick(t: Any) -> bool:
        report(progress, t.episodes_done, t.settings.episodes, label)
        return False

    trainer.train(on_vector_step=tick)
    return trainer.policy_net


def choose_learner(
    approaches: list[Approach],
    cfg: EnvConfig,
    settings: AutoSettings,
    progress: ProgressFn | None = None,
    label: str = "agent",
    inner: list[InnerFold] | None = None,
) -> Choice:
    """Which learner to fit on `approaches`: both fitted and scored across inner folds of the sessions.

    Each learner's held-out changes from every inner fold are pooled and scored once, so every
    session the target drove takes part in the choice. `cfg` is the DQN's environment; the trees read
    it with their own press scale (`learner_env`). With too few sessions to hold any out, the DQN is taken.
    `inner`: the inner folds, each with its seed (a cross-validation's other outer folds); None: `inner_folds`.
    """
    settings = with_seed(settings, settings.seed)
    given = _given_folds(approaches, settings, inner)
    pairs = [(f.fit, f.held) for f in given]
    if not pairs:
        return Choice("dqn", {}, len(approaches), 0)
    scores, by_side = {}, {}
    for name in ("dqn", "trees"):
        pooled = []
        for i, (fit, held) in enumerate(pairs):
            seeded = with_seed(settings, given[i].seed)
            if name == "trees":  # the inner trees' (`inner_trees`) predictions, as `choose_and_fit` takes them
                report(progress, i, len(pairs), f"{label}: choosing, trees {i + 1}/{len(pairs)}")
                pooled.append(_trees_fit(fit, [held], cfg, inner_trees(seeded), None)[0])
                continue
            net = fit_learner(fit, cfg, seeded.dqn, progress, f"{label}: choosing, {name} {i + 1}/{len(pairs)}")
            pooled.append(held_out_changes(net, held, learner_env(cfg, name)))
        by_side[name] = side_scores(*(np.concatenate(parts) for parts in zip(*pooled)))
        scores[name] = round(float(np.mean(list(by_side[name].values()))), 4) if by_side[name] else float("nan")
    gain = np.nan_to_num(scores["trees"], nan=-1.0) - np.nan_to_num(scores["dqn"], nan=-1.0)
    return Choice(
        "trees" if gain > settings.margin else "dqn",
        scores,
        len(approaches),
        sum(len(held) for _, held in pairs),
        len(pairs),
        by_side,
    )


def _given_folds(approaches: list[Approach], settings: AutoSettings, inner: list[InnerFold] | None) -> list[InnerFold]:
    """`inner`, or `inner_folds` of `approaches` with the settings' seed (seeded settings)."""
    if inner is not None:
        return inner
    return [InnerFold(fit, held, settings.seed) for fit, held in inner_folds(approaches, settings.folds, settings.seed)]


def inner_trees(settings: AutoSettings) -> TreeQSettings:
    """The trees fitted on the inner folds: `AutoSettings.inner_trees` of the boosting stages, each step as much
    larger (the trees kept, when they win, are fitted with `settings.trees`)."""
    share, trees = settings.inner_trees, settings.trees
    if share >= 1:
        return trees
    return replace(trees, trees=max(1, round(trees.trees * share)), learning_rate=trees.learning_rate / share)


def chosen_settings(settings: AutoSettings, choice: Choice) -> DQNSettings | TreeQSettings:
    """The chosen learner's settings, seeded as `choose_learner` seeded it."""
    seeded = with_seed(settings, settings.seed)
    return seeded.trees if choice.learner == "trees" else seeded.dqn


def with_seed(settings: AutoSettings, seed: int) -> AutoSettings:
    """`settings` with every random choice seeded from `seed` (a crossval fold's)."""
    return replace(settings, seed=seed, dqn=replace(settings.dqn, seed=seed), trees=replace(settings.trees, seed=seed))


# --- the choice at about the price of one learner ----------------------------------------------------------


@dataclass
class ChoiceTask:
    """One target to choose a learner for and fit it on: `choose_learner`'s arguments."""

    approaches: list[Approach]
    cfg: EnvConfig  # the DQN's environment (the trees read it through `learner_env`)
    settings: AutoSettings
    label: str = "agent"
    inner: list[InnerFold] | None = None  # the inner folds (None: `inner_folds` of the approaches)


@dataclass(frozen=True)
class InnerFold:
    """An inner fold given by the caller: fit on `fit`, score on `held`, both learners seeded with `seed`.
    Folds of equal `key` (in `choose_and_fit`'s tasks) fit the same approaches with the same seed: fitted once."""

    fit: list[Approach]
    held: list[Approach]
    seed: int
    key: Any = None  # None: its own


@dataclass
class Fitted:
    """A task's choice and the chosen learner fitted on all of its approaches."""

    choice: Choice
    settings: DQNSettings | TreeQSettings  # the chosen learner's, seeded (the DQN's episodes resolved)
    net: Any = None  # its Q network (None: trees chosen and `fit_trees` off)
    dqn_state: dict[str, Any] | None = None  # the DQN's complete state, `DQNTrainer.state_dict()`'s format
    rows: list[dict[str, Any]] = field(default_factory=list)  # the DQN's metrics lines, one per episode


class _Stopped(Exception):
    """Raised inside a tree fit whose learner can no longer change the choice."""


@dataclass
class _Target:
    """A task's book-keeping while the fleet trains."""

    task: ChoiceTask
    settings: AutoSettings  # seeded
    pairs: list[tuple[list[Approach], list[Approach]]]
    held: list[tuple[np.ndarray, np.ndarray, np.ndarray]]  # per pair: the DQN's held-out (states, labels, left)
    inner: list[int] = field(default_factory=list)  # fleet members of the inner folds' DQNs (maybe shared)
    final: int = -1  # fleet member of the target's DQN
    changes: dict[int, np.ndarray] = field(default_factory=dict)  # pair -> finished inner DQN's changes
    trees: list[Any] = field(default_factory=list)  # per pair: its `_Part` of a trees fit, (changes, labels, left)
    choice: Choice | None = None
    next_check: float = 0.0
    running: tuple[float, float, float, dict[int, np.ndarray]] | None = None  # DQN (score, reach, share, changes)
    seen: tuple[int, ...] = ()  # what `check` last noted
    # the DQNs' (changes, running, checks so far) not yet settled against the trees (fitted beside, they wait)
    notes: list[tuple[dict[int, np.ndarray], Any, int]] = field(default_factory=list)
    checks: list[dict[str, float]] = field(default_factory=list)
    fitted: Fitted | None = None
    trees_net: Any = None  # future of the chosen trees' fit on all approaches


def _pooled(parts: list[tuple[np.ndarray, ...]]) -> tuple[float, dict[str, float]]:
    """(score, by side) of pooled (changes, labels, left) parts, as `choose_learner` scores them."""
    by_side = side_scores(*(np.concatenate(p) for p in zip(*parts)))
    return (round(float(np.mean(list(by_side.values()))), 4) if by_side else float("nan")), by_side


#: Set in a trees worker process (`_trees_worker`): one event per trees fit, set when no target needs it.
_STOP_EVENTS: list[Any] = []


def _trees_worker(events: list[Any]) -> None:
    """Initialise a trees worker process (`AutoSettings.trees_beside='process'`): it dies with its parent (a
    killed run leaves no fit running)."""
    import ctypes
    import signal
    import sys

    _STOP_EVENTS[:] = events
    torch = sys.modules.get("torch")
    if torch is not None:  # a forked copy of torch's thread pool hangs at its first parallel operation
        torch.set_num_threads(1)
    try:
        ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG (Linux: the only platform forked here)
    except (OSError, AttributeError):  # pragma: no cover
        pass


def _trees_fit(
    fit: list[Approach], helds: list[list[Approach]], cfg: EnvConfig, settings: TreeQSettings, stop: Any
) -> list[tuple[np.ndarray, ...]]:
    """The trees fitted on `fit`: (changes, labels, left) on each of `helds`; `stop` (an event, or an index into
    `_STOP_EVENTS` in a worker process) ends the fit at its next regression."""
    from rl.learners.trees import ensemble_changes, fit_tree_ensembles

    event = _STOP_EVENTS[stop] if isinstance(stop, int) else stop

    def check(done: int, total: int, message: str) -> None:
        if event is not None and event.is_set():
            raise _Stopped

    tenv = learner_env(cfg, "trees")
    models, _ = fit_tree_ensembles(fit, tenv, settings, check)
    out: list[tuple[np.ndarray, ...]] = []
    for held in helds:
        x, y = labelled_states(held, tenv)
        out.append((ensemble_changes(models, x), y, np.concatenate([a.scene.left for a in held])))
    return out


@dataclass
class _TreesJob:
    """One inner trees fit, for every (target, pair) that shares it."""

    fit: list[Approach]
    cfg: EnvConfig
    settings: TreeQSettings
    users: list[tuple[Any, int]]  # (_Target, pair index)
    event: Any = None  # set when no user needs it any more: the fit stops at its next regression
    future: Any = None  # its `_trees_fit` list, one entry per user


class _Part:
    """One user's share of a `_TreesJob`, read as a future of its (changes, labels, left)."""

    def __init__(self, job: _TreesJob, index: int) -> None:
        self.job, self.index = job, index

    def done(self) -> bool:
        return bool(self.job.future is not None and self.job.future.done())

    def cancelled(self) -> bool:
        return bool(self.job.future.cancelled())

    def exception(self) -> BaseException | None:
        return self.job.future.exception()

    def result(self) -> tuple[np.ndarray, ...]:
        return self.job.future.result()[self.index]


def _gain(trees: float, dqn: float) -> float:
    return float(np.nan_to_num(trees, nan=-1.0) - np.nan_to_num(dqn, nan=-1.0))


def _fleet_keeping(members: list[Any], threads: int, keep: set[int]) -> Any:
    """A `FleetTrainer` that copies out the complete state (`Fitted.dqn_state`: the replay memory, the optimiser,
    the environments) of the members in `keep` only: every finished agent's costs about as much as a second of
    its training (a cross-validation's four outer DQNs 3 s each on the busy 2-core machine), and only a run
    keeps one (its checkpoint)."""
    from rl.fleet.batch import FleetTrainer

    class Fleet(FleetTrainer):
        def agent_state_dict(self, j: int, *args: Any, **kwargs: Any) -> dict[str, Any]:
            if self.agents[j].member not in keep:
                return {}
            return super().agent_state_dict(j, *args, **kwargs)

    return Fleet(members, threads=threads)


def choose_and_fit(
    tasks: list[ChoiceTask],
    progress: ProgressFn | None = None,
    fit_trees: bool = True,
    label: str = "",
    keep_state: bool = True,
) -> list[Fitted]:
    """`choose_learner` and `fit_learner` of the chosen learner for every task, the DQNs trained as one fleet.

    Per task: the inner folds' DQNs and the task's own DQN (kept if the DQN wins) are members of one
    `FleetTrainer` with every other task's; the trees' inner fits run first or beside them
    (`AutoSettings.trees_beside`: then the DQNs' running scores wait for the task's trees and are settled in
    order, so that it chooses and stops as it does after them, and the weights are the same). The choice is
    `choose_learner`'s for the same seed (each fleet agent computes what `DQNTrainer` does, up to floating-point
    summation order) unless `stop_early` stopped the inner DQNs once they could no longer change it (their
    running score + `reach` (- `reach_down`) x the share of their episodes left). The stored scores are then the
    ones that settled it (the DQNs' running score) and `Choice.stopped` says so. `fit_trees`: also fit the
    trees on all approaches where they win (a run fits them itself, with its own status). `keep_state`: each
    task's DQN comes with its complete state (`Fitted.dqn_state`, a run's checkpoint); off, with its network
    only. `progress` is told the phase: inner folds, scenes, training (episodes summed over the fleet, the
    trees' folds), evaluation.
    """
    import multiprocessing
    import os
    import sys
    import threading
    from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor

    import torch

    from rl.fleet.batch import FleetMember, FleetTrainer
    from rl.learners.dqn import q_network
    from rl.problem.env import observation_names

    head = f"{label}: " if label else ""
    report(progress, 0, len(tasks), f"{head}choosing the learner: dealing the inner folds")
    targets: list[_Target] = []
    members: list[FleetMember] = []
    shared: dict[Any, tuple[int, _TreesJob]] = {}  # key -> (fleet member, trees job) of an inner fold
    jobs: list[_TreesJob] = []
    users: dict[int, list[tuple[_Target, int]]] = {}  # inner member -> (target, pair index) it serves
    for task in tasks:
        s = with_seed(task.settings, task.settings.seed)
        given = _given_folds(task.approaches, s, task.inner)
        pairs = [(f.fit, f.held) for f in given]
        t = _Target(
            task,
            s,
            pairs,
            [labelled_states(held, task.cfg) + (np.concatenate([a.scene.left for a in held]),) for _, held in pairs],
            next_check=s.check_from,
        )
        for i, f in enumerate(given):
            key = f.key if f.key is not None else (len(targets), i)
            if key not in shared:
                seeded = with_seed(s, f.seed)
                jobs.append(_TreesJob(f.fit, task.cfg, inner_trees(seeded), []))
                shared[key] = (len(members), jobs[-1])
                members.append(FleetMember(task.cfg, seeded.dqn, f.fit))
            member, job = shared[key]
            t.inner.append(member)
            users.setdefault(member, []).append((t, i))
            t.trees.append(_Part(job, len(job.users)))
            job.users.append((t, i))
        t.final = len(members)
        members.append(FleetMember(task.cfg, s.dqn, task.approaches))
        if not pairs:
            t.choice = Choice("dqn", {}, len(task.approaches), 0)
        targets.append(t)
    owner = {t.final: t for t in targets}
    trees_total = len(jobs)
    beside = tasks[0].settings.trees_beside if trees_total else "no"
    if beside == "process" and sys.platform != "linux":
        beside = "no"  # a forked copy of this process is safe on Linux only (a thread would share the interpreter)
    pool: Executor
    if beside == "process":  # the other core, without the interpreter's lock: a forked copy of this process (no
        # imports to repeat, no main module to run again), before the fleet has run a torch operation
        ctx = multiprocessing.get_context("fork")
        events = [ctx.Event() for _ in jobs]
        for job, e in zip(jobs, events):
            job.event = e
        pool = ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_trees_worker, initargs=(events,))
    else:
        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="trees")
        for job in jobs:
            job.event = threading.Event()
    try:
        for k, job in enumerate(jobs):
            helds = [u.pairs[i][1] for u, i in job.users]
            if beside in ("process", "thread"):
                stop = k if beside == "process" else job.event
                job.future = pool.submit(_trees_fit, job.fit, helds, job.cfg, job.settings, stop)
            else:
                report(progress, k, trees_total, f"{head}choosing the learner: fitting the trees")
                job.future = Future()
                job.future.set_result(_trees_fit(job.fit, helds, job.cfg, job.settings, None))
        report(progress, 0, len(members), f"{head}choosing the learner: building the scenes of {len(members)} DQNs")
        fleet = _fleet_keeping(
            members, members[0].settings.threads, {t.final for t in targets} if keep_state else set()
        )
        n_obs = len(observation_names(tasks[0].cfg))
        hidden = members[0].settings.hidden
        episodes = [s.episodes for s in fleet.settings]
        gone: set[int] = set()  # members stopped before their episodes

        def as_net(sd: dict[str, Any]) -> Any:
            net = q_network(hidden, n_obs)
            net.load_state_dict(sd)
            return net

        def on_finish(member: int, policy: dict[str, Any], state: dict[str, Any]) -> None:
            if member in owner:
                t = owner[member]
                t.fitted = Fitted(
                    t.choice or Choice("dqn", {}, len(t.task.approaches), 0),
                    fleet.settings[member],
                    as_net(policy),
                    state or None,
                    t.fitted.rows if t.fitted else [],
                )
                return
            net = as_net(policy)
            for t, i in users[member]:
                t.changes[i] = held_out_changes(net, t.pairs[i][1], t.task.cfg)[0]

        def on_episode(member: int, row: dict[str, Any]) -> None:
            t = owner.get(member)
            if t is not None:
                if t.fitted is None:
                    t.fitted = Fitted(Choice("dqn", {}, 0, 0), fleet.settings[member])
                t.fitted.rows.append(row)

        def running_changes(member: int, x: np.ndarray) -> np.ndarray:
            return fleet.policy_actions(member, x) == CHANGE

        def trees_done(t: _Target) -> dict[int, tuple[np.ndarray, ...]]:
            out = {}
            for i, f in enumerate(t.trees):
                if f.done() and not f.cancelled() and not isinstance(f.exception(), _Stopped):
                    out[i] = f.result()  # raises what the fit raised
            return out

        def decide(
            t: _Target,
            learner: str,
            dqn: tuple[float, dict[str, float]],
            trees: tuple[float, dict[str, float]],
            stopped: list[str],
            checks: int,
        ) -> None:
            t.choice = Choice(
                learner,
                {"dqn": dqn[0], "trees": trees[0]},
                len(t.task.approaches),
                sum(len(held) for _, held in t.pairs),
                len(t.pairs),
                {"dqn": dqn[1], "trees": trees[1]},
                f"{learner} chosen: {'; '.join(stopped)}" if stopped else "",
                t.checks[:checks],
            )
            drop = {
                m
                for m in t.inner
                if fleet.position(m) is not None  # unless another target still needs it
                and all(u.choice is not None for u, _ in users[m])
            }
            if learner == "trees":
                drop.add(t.final)
                if fit_trees:  # the ensembles come back (scikit-learn's, plain arrays); the torch module is built
                    # here: a forked worker must not run torch (its thread pool is the parent's, and may hang)
                    from rl.learners.trees import fit_tree_ensembles

                    t.trees_net = pool.submit(
                        fit_tree_ensembles, t.task.approaches, learner_env(t.task.cfg, "trees"), t.settings.trees
                    )
            for part in t.trees:
                job = part.job
                if all(u.choice is not None for u, _ in job.users):
                    job.event.set()
                    job.future.cancel()
            gone.update(drop)
            fleet.drop(drop)

        def check(t: _Target) -> None:
            """Note what the DQNs say of `t` (their running score at each check, each finished inner DQN) and,
            once `t`'s trees are in, settle `t` at the first of those notes that decides it: the trees fitted
            beside decide where they would have decided fitted first ('no'), however late they come in."""
            if t.choice is not None:
                return
            s = t.settings
            shares = {
                m: fleet.agents[j].episodes_done / episodes[m] for m in t.inner if (j := fleet.position(m)) is not None
            }
            if shares and s.stop_early and min(shares.values()) >= t.next_check:  # the DQNs' running score
                share = min(shares.values())
                t.next_check = share + s.check_every
                now = {i: running_changes(m, t.held[i][0]) for i, m in enumerate(t.inner) if m in shares}
                score = _pooled([({**t.changes, **now}[i], *t.held[i][1:]) for i in range(len(t.pairs))])[0]
                t.running = (score, s.reach * (1.0 - share), share, now)
                t.checks.append(
                    {
                        "share": round(share, 3),
                        "dqn": score,
                        "reach": round(t.running[1], 4),
                        "reach_down": round(s.reach_down * (1.0 - share), 4),
                    }
                )
            seen = (len(t.changes), len(t.checks))
            complete = len(t.changes) == len(t.pairs)
            if seen != t.seen and (complete or (s.stop_early and t.running is not None)):
                t.seen = seen
                t.notes.append((dict(t.changes), t.running, len(t.checks)))
            tdone = trees_done(t)
            if len(tdone) < len(t.pairs):  # fitted beside: still fitting
                return
            trees = _pooled([tdone[i] for i in range(len(t.pairs))])
            while t.notes and t.choice is None:
                settle(t, *t.notes.pop(0), trees)

        def settle(
            t: _Target,
            changes: dict[int, np.ndarray],
            running: tuple[float, float, float, dict[int, np.ndarray]] | None,
            checks: int,
            trees: tuple[float, dict[str, float]],
        ) -> None:
            """Decide `t` if the DQNs' note (`changes` of the finished inner DQNs, the `running` check, the first
            `checks` checks) and the trees' score settle it: both scores complete, or the DQNs' interval out of
            reach."""
            s = t.settings
            if len(changes) == len(t.pairs):
                d = _pooled([(changes[i], *t.held[i][1:]) for i in range(len(t.pairs))])
                d_lo = d_hi = d[0]
                note = ""
            else:
                assert running is not None
                score, reach, share, now = running
                down = s.reach_down * (1.0 - share)
                d = _pooled([({**changes, **now}[i], *t.held[i][1:]) for i in range(len(t.pairs))])
                d_lo, d_hi = score - down, score + reach
                note = (
                    f"the inner DQNs stopped at {100 * share:.0f} % of their episodes (running score "
                    f"{score:.3f}, still to rise by up to {reach:.3f} or fall by {down:.3f})"
                )
            if _gain(trees[0], d_hi) > s.margin:  # the trees win whatever is left
                decide(t, "trees", d, trees, [note] if note else [], checks)
            elif _gain(trees[0], d_lo) <= s.margin:  # the DQN wins whatever is left
                decide(t, "dqn", d, trees, [note] if note else [], checks)

        def on_vector_step(f: FleetTrainer) -> bool:
            for t in targets:
                check(t)
            done = f.episodes_done
            total = sum(d if m in gone else episodes[m] for m, d in enumerate(done))
            trees = sum(job.future.done() for job in jobs)
            chosen = sum(t.choice is not None for t in targets)
            fitting = trees < trees_total or any(t.trees_net is not None and not t.trees_net.done() for t in targets)
            threads = fleet_threads if len(f.agents) >= 2 and not fitting else lone_threads
            if threads != torch.get_num_threads():  # the spare core to the stack once no tree fit needs it
                torch.set_num_threads(threads)
            report(
                progress,
                sum(done),
                total,
                f"{head}choosing the learner: training {len(f.agents)} DQNs, trees "
                f"{trees}/{trees_total}" + (f", {chosen}/{len(targets)} chosen" if len(targets) > 1 else ""),
            )
            return False

        lone_threads = members[0].settings.threads
        fleet_threads = max(lone_threads, min(tasks[0].settings.fleet_threads, os.cpu_count() or 1))
        try:
            fleet.train(on_episode=on_episode, on_finish=on_finish, on_vector_step=on_vector_step)
        finally:
            torch.set_num_threads(lone_threads)
        for t in targets:  # the trees still fitting: fold by fold, until they settle the choice
            while t.choice is None:
                report(
                    progress,
                    sum(job.future.done() for job in jobs),
                    trees_total,
                    f"{head}choosing the learner: trees beside",
                )
                pending = [f for f in t.trees if not f.done()]
                if pending:
                    try:
                        pending[0].result()
                    except _Stopped:
                        pass
                check(t)
                if not pending and t.choice is None:
                    raise RuntimeError("the learner choice did not settle")  # pragma: no cover
        report(progress, 0, len(targets), f"{head}choosing the learner: evaluation")
        for t in targets:
            assert t.choice is not None
            if t.choice.learner == "trees":
                net = None
                if t.trees_net is not None:
                    from rl.learners.trees import TreeQNetwork

                    net = TreeQNetwork.from_ensembles(*t.trees_net.result())
                t.fitted = Fitted(t.choice, t.settings.trees, net)
            else:
                assert t.fitted is not None
                t.fitted.choice = t.choice
    finally:
        for job in jobs:
            if job.event is not None:
                job.event.set()  # a fit still running ends at its next regression
        pool.shutdown(wait=True, cancel_futures=True)
    return [t.fitted for t in targets if t.fitted is not None]
