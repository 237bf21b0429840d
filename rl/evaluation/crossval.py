"""Held-out evaluation: agent vs greedy vs imitation on sessions none of them saw.

The target's sessions (recordings) are split into K folds. For each fold, the
reference lines are refitted on the other folds' presses, the agent is trained
on the other folds' approaches (or synthetic scenes with those lines), the
imitation classifier is fitted on the other folds' states, and all three
policies are scored on the held-out fold. Every decision is scored once, by
policies that never saw it.

Splits (`CrossvalSettings.split`):

- ``session``: each driver's sessions are dealt to the folds in turn, in the
  order of their speed sections, each driver starting where a section's sessions
  land in different folds: every fold holds about the same share of every driver,
  and every section keeps sessions in training (seeded);
- ``section``: a fold is a speed section (``speed_limit_kph``); the lines are then
  extrapolated over speed to the held-out section (K = the number of sections).

Figures pool the held-out states of all folds; the 95 % interval of the
balanced accuracy (and the timing error) comes from a bootstrap over decisions
(an approach and its not-yet states are resampled together, as they are not
independent). Style membership comes from the full analysis (it is a property
of drivers, not of sessions); everything fitted to decisions is refitted per fold.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from indicators.settings import AnalysisSettings
from laneprint.errors import UserError
from laneprint.parallel import run_tasks
from laneprint.progress import ProgressFn
from laneprint.reference import INDICATORS
from rl.evaluation.settings import SPLITS, CrossvalSettings  # noqa: F401
from rl.problem.env import Approach, EnvConfig, approaches_from_decisions
from rl.evaluation.evaluate import evaluate_policies, greedy_policy
from rl.baselines.imitation import ImitationClassifier
from rl.problem.rewards import ReferenceLines
from rl.settings import AutoSettings, LearnerSettings, learner_config, learner_name

POLICIES: tuple[str, ...] = ("agent", "greedy", "imitation")


def assign_folds(sessions: pd.DataFrame, settings: CrossvalSettings) -> dict[str, int]:
    """recording_id -> fold, from a frame of recording_id, driver_id, speed_limit_kph."""
    rng = np.random.default_rng(settings.seed)
    out: dict[str, int] = {}
    if settings.split == "section":
        limits = sorted(sessions["speed_limit_kph"].dropna().unique())
        if sessions["speed_limit_kph"].isna().any() or len(limits) < 2:
            raise UserError("split 'section' needs speed_limit_kph on every session and at least two sections")
        k = min(settings.folds, len(limits))
        # consecutive sections share a fold when K is below the number of sections
        fold_of = {lim: int(i * k // len(limits)) for i, lim in enumerate(limits)}
        for rid, lim in zip(sessions["recording_id"], sessions["speed_limit_kph"]):
            out[str(rid)] = fold_of[lim]
        return out
    return _session_folds(sessions, settings.folds, rng)


def _session_folds(sessions: pd.DataFrame, k: int, rng: np.random.Generator) -> dict[str, int]:
    """Deal each driver's sessions to the folds in turn, in the order of their speed sections,
    each driver starting at the fold that keeps a section's sessions in different folds.

    A fold then holds the sessions of different sections, so every section keeps
    sessions in training: a random deal (the first version) could hold out most of
    one section (shipped study, Defensive: two of the three 60 km/h sessions in one
    fold) and score extrapolation over speed under the name of a new session.
    Extrapolation has its own split ('section'). The drivers' order, the rotation
    among equally good ones and the order of sessions within a section are seeded.
    """
    out: dict[str, int] = {}
    per_section: dict[str, np.ndarray] = {}  # section -> sessions of it in each fold
    size = np.zeros(k, dtype=int)
    drivers = np.array(sorted(sessions["driver_id"].astype(str).unique()))
    for driver in drivers[rng.permutation(len(drivers))]:
        g = sessions[sessions["driver_id"].astype(str) == driver]
        sections = g["speed_limit_kph"].astype(str).to_numpy()
        order = np.lexsort((rng.random(len(g)), g["speed_limit_kph"].fillna(np.inf).to_numpy()))
        ids, sections = g["recording_id"].astype(str).to_numpy()[order], sections[order]

        def cost(start: int) -> tuple[int, int]:
            folds = (start + np.arange(len(ids))) % k
            clashes = sum(int(per_section.get(sec, np.zeros(k))[f]) for sec, f in zip(sections, folds))
            grown = size + np.bincount(folds, minlength=k)
            return clashes, int(grown.max() - grown.min())

        start = min(rng.permutation(k), key=cost)  # min keeps the first of equals: a seeded choice
        for i, (rid, sec) in enumerate(zip(ids, sections)):
            f = (start + i) % k
            out[rid] = int(f)
            per_section.setdefault(sec, np.zeros(k, dtype=int))[f] += 1
            size[f] += 1
    return out


def fold_lines(
    train: pd.DataFrame, line_drivers: list[str], fallback: ReferenceLines, analysis: AnalysisSettings
) -> tuple[ReferenceLines, list[str]]:
    """Reference lines refitted on the training folds' presses of `line_drivers` (pooled when several).

    An indicator that cannot be fitted (too few defined presses) keeps the full
    analysis's line, with a note; a flagged fit becomes its level with
    `flagged_lines='level'`, as in the analysis (`clustering.pipeline.reference_lines`).
    """
    from indicators.stats import fit_lines  # statsmodels: imported here, not by every fold's worker

    dec = train[train["driver_id"].astype(str).isin(line_drivers)].copy()
    dec["driver_id"] = "+".join(line_drivers)  # several drivers: one pooled fit
    fits = fit_lines(dec, analysis).set_index("indicator")
    got, notes = {}, []
    for ind in INDICATORS:
        row = fits.loc[ind] if ind in fits.index else None
        if row is not None and row["status"] == "ok" and row.get("flag") and analysis.flagged_lines == "level":
            got[ind] = (0.0, float(row["level"]))
            notes.append(f"{ind}: line flagged ({row['flag']}); its level used")
        elif row is not None and row["status"] == "ok":
            got[ind] = (float(row["A"]), float(row["b"]))
        else:
            got[ind] = getattr(fallback, ind)
            notes.append(f"{ind}: {row['reason'] if row is not None else 'no presses'}; the full analysis's line used")
    source = f"refitted on the training folds ({', '.join(line_drivers)})"
    return ReferenceLines(got["t_f"], got["t_nf"], got["dv_nb"], source), notes


def _decision_counts(states: pd.DataFrame, action_col: str) -> pd.DataFrame:
    """Per decision: press said change (0/1), not-yet states, not-yet states said keep."""
    said_change = states[action_col].to_numpy() == 0
    is_press = (states["label"] == "change").to_numpy()
    df = pd.DataFrame(
        {
            "decision_id": states["decision_id"].to_numpy(),
            "press_ok": (said_change & is_press).astype(float),
            "n_keep": (~is_press).astype(float),
            "keep_ok": (~said_change & ~is_press).astype(float),
        }
    )
    return df.groupby("decision_id", sort=True).sum()


def bootstrap_scores(
    states: pd.DataFrame, changes: pd.DataFrame, who: str, n_boot: int, rng: np.random.Generator
) -> dict[str, Any]:
    """Balanced accuracy, recall, specificity and timing of one policy with bootstrap 95 % intervals."""
    counts = _decision_counts(states, f"action_{who}")
    ch = changes[changes["who"] == who].set_index("decision_id").reindex(counts.index)
    err = ch["timing_error_s"].abs().to_numpy(dtype=float)
    n = len(counts)
    press_ok, n_keep, keep_ok = (counts[c].to_numpy() for c in ("press_ok", "n_keep", "keep_ok"))

    def figures(w: np.ndarray) -> tuple[float, float, float, float]:
        rec = (w @ press_ok) / w.sum()
        spec = (w @ keep_ok) / max(w @ n_keep, 1e-12)
        has = np.isfinite(err)
        mae = (w[has] @ err[has]) / w[has].sum() if w[has].sum() > 0 else np.nan
        return (rec + spec) / 2, rec, spec, mae

    ba, rec, spec, mae = figures(np.ones(n))
    w = rng.multinomial(n, np.full(n, 1.0 / n), size=n_boot).astype(float) if n else np.zeros((0, 0))
    boots = np.array([figures(wi) for wi in w]) if n else np.full((1, 4), np.nan)
    with warnings.catch_warnings():  # a policy that never changes has no timing in some resamples
        warnings.simplefilter("ignore", RuntimeWarning)
        lo, hi = np.nanpercentile(boots, [2.5, 97.5], axis=0)
    return {
        "who": who,
        "balanced_accuracy": float(ba),
        "balanced_accuracy_ci": [float(lo[0]), float(hi[0])],
        "recall": float(rec),
        "specificity": float(spec),
        "timing_mae_s": None if np.isnan(mae) else float(mae),
        "timing_mae_ci": None if np.isnan(mae) else [float(lo[3]), float(hi[3])],
        "never_rate": float(np.mean(~np.isfinite(ch["change_t_s"].to_numpy(dtype=float)))) if n else None,
        "n_decisions": int(n),
        "n_states": int(len(states)),
    }


def _train_agent(
    approaches: list[Approach],
    cfg: EnvConfig,
    dqn: LearnerSettings,
    progress: ProgressFn | None,
    label: str,
    inner: list[Any] | None = None,
) -> tuple[Any, dict[str, Any]]:
    """(the fold's agent as a policy, which learner made it: ``{"learner": ...}`` and, for 'auto', the
    inner scores it chose by)."""
    from rl.evaluation.evaluate import agent_policy
    from rl.learners.choice import choose_learner, chosen_settings, fit_learner

    if isinstance(dqn, AutoSettings):
        choice = choose_learner(approaches, cfg, dqn, progress, label, inner)
        net = fit_learner(approaches, cfg, chosen_settings(dqn, choice), progress, f"{label}: {choice.learner}")
        return agent_policy(net, cfg), {
            "learner": choice.learner,
            "learner_scores": choice.scores,
            "learner_scores_by_side": choice.by_side,
        }
    return agent_policy(fit_learner(approaches, cfg, dqn, progress, label), cfg), {"learner": learner_name(dqn)}


def outer_inner_folds(jobs: list["FoldJob"]) -> None:
    """`auto`'s inner folds in a cross-validation are the other outer folds: each job's `inner` holds, per other
    fold j, its training approaches outside j (to fit on) and in j (to score), seeded with the lower fold's seed.

    So the fit of fold k's inner fold j is fold j's inner fold k (the sessions of neither), and `choose_and_fit`
    fits it once (`InnerFold.key`): half the inner fits of dealing each fold's training sessions afresh
    (`inner_folds`), and, as there, every training session is scored once. Fewer than three folds: `inner_folds`."""
    from rl.learners.choice import InnerFold, session_of

    auto = [j for j in jobs if isinstance(j.dqn, AutoSettings)]
    if len(auto) < 3:
        return
    fold_of = {session_of(a.decision_id): j.fold for j in auto for a in j.test}
    for job in auto:
        base = job.dqn.seed - job.fold  # the cross-validation's seed (job k's is base + k)
        where = [fold_of.get(session_of(a.decision_id)) for a in job.train]
        job.inner = []
        for other in auto:
            if other.fold == job.fold:
                continue
            fit = [a for a, f in zip(job.train, where) if f != other.fold]
            held = [a for a, f in zip(job.train, where) if f == other.fold]
            if fit and held:
                job.inner.append(
                    InnerFold(fit, held, base + min(job.fold, other.fold), frozenset((job.fold, other.fold)))
                )


def fold_agents(jobs: list["FoldJob"], progress: ProgressFn | None) -> None:
    """`auto`'s agents of every fold at once: the inner folds' DQNs and each fold's own DQN of all outer
    folds train as one fleet, the trees beside them (`rl.learners.choice.choose_and_fit`); each job's
    `agent` is set to what `_train_agent` would return (the same choices for the same seeds)."""
    from rl.evaluation.evaluate import agent_policy
    from rl.learners.choice import ChoiceTask, choose_and_fit

    auto = [j for j in jobs if isinstance(j.dqn, AutoSettings) and j.agent is None]
    if not auto:
        return
    tasks = [
        ChoiceTask(j.train, j.env, j.dqn, f"fold {j.fold + 1}/{j.n_folds}", j.inner)  # type: ignore[arg-type]
        for j in auto
    ]
    for job, fitted in zip(auto, choose_and_fit(tasks, progress, label=f"{len(auto)} folds", keep_state=False)):
        c = fitted.choice
        job.agent = (
            agent_policy(fitted.net, job.env),
            {
                "learner": c.learner,
                "learner_scores": c.scores,
                "learner_scores_by_side": c.by_side,
                **({"learner_stopped": c.stopped} if c.stopped else {}),
            },
        )


@dataclass
class FoldJob:
    """One fold, self-contained: the input of `score_fold` (a task on the chosen backend)."""

    fold: int
    n_folds: int
    train: list[Approach]  # the other folds' decisions: what agent and classifier are fitted on
    test: list[Approach]  # the held-out fold's
    skipped: dict[str, int]  # held-out decisions that could not be scored, by reason
    env: EnvConfig  # with the fold's refitted lines
    dqn: LearnerSettings  # the learner's settings (DQN or trees), with the fold's seed
    imitation_seed: int
    progress: ProgressFn | None = None  # the agent's episodes; in-process only (local backend)
    agent: tuple[Any, dict[str, Any]] | None = None  # the fold's agent fitted already (`auto` on the local
    # backend: every fold's learner choice in one fleet, `fold_agents`), as `_train_agent` returns it
    inner: list[Any] | None = None  # `auto`'s inner folds (`InnerFold`s: the other outer folds, `outer_inner_folds`)


def score_fold(job: FoldJob) -> dict[str, Any]:
    """Fit agent, greedy and imitation on the training folds and score them on the held-out one.

    Returns `evaluate_policies`'s dict (``states`` and ``changes`` tagged with the fold).
    """
    label = f"fold {job.fold + 1}/{job.n_folds}: agent"
    agent, learner = job.agent or _train_agent(job.train, job.env, job.dqn, job.progress, label, job.inner)
    policies = {
        "agent": agent,
        "greedy": greedy_policy(job.env),
        "imitation": ImitationClassifier(random_state=job.imitation_seed).fit(job.train, job.env).policy(job.env),
    }
    ev = evaluate_policies(policies, job.test, job.env, job.skipped)
    ev["states"].insert(0, "fold", job.fold)
    ev["changes"].insert(0, "fold", job.fold)
    ev["learner"] = learner
    return ev


def decision_directions(decisions: pd.DataFrame) -> pd.Series:
    """'left' or 'right' of each decision_id: the side of its target lane (lanes count from the
    right, so a higher target lane is to the left)."""
    presses = decisions.drop_duplicates("decision_id")
    side = np.where(presses["target_lane"].to_numpy() > presses["ego_lane"].to_numpy(), "left", "right")
    return pd.Series(side, index=presses["decision_id"].to_numpy())


def summary_by_direction(
    decisions: pd.DataFrame, states: pd.DataFrame, changes: pd.DataFrame, settings: CrossvalSettings
) -> list[dict[str, Any]]:
    """`bootstrap_scores` of every policy on the left and on the right decisions alone (rows carry
    `direction`); a direction without scored decisions has no rows. Its own seeded generator,
    so the pooled summary's intervals do not move."""
    rng = np.random.default_rng([settings.seed, 8])
    side = decision_directions(decisions)
    rows = []
    for direction in ("left", "right"):
        ids = side.index[side.to_numpy() == direction]
        st = states[states["decision_id"].isin(ids)]
        if st.empty:
            continue
        ch = changes[changes["decision_id"].isin(ids)]
        rows += [
            {"direction": direction, **bootstrap_scores(st, ch, who, settings.n_bootstrap, rng)} for who in POLICIES
        ]
    return rows


def crossvalidate(
    decisions: pd.DataFrame,
    drivers: list[str],
    line_drivers: list[str],
    env: EnvConfig,
    dqn: LearnerSettings,
    settings: CrossvalSettings,
    analysis: AnalysisSettings | None = None,
    refit_lines: bool = True,
    progress: ProgressFn | None = None,
    backend: str = "local",
    ray_address: str | None = None,
) -> dict[str, Any]:
    """Held-out figures of agent, greedy and imitation on `drivers`' decisions (see the module doc).

    `line_drivers`: whose presses the reference lines are refitted on (the typical
    driver of a style, or the driver). `env.lines` is the fallback for an indicator
    that cannot be refitted, and the lines used when `refit_lines` is False (Table 1).
    Each fold is one `score_fold` task on `backend` (`laneprint.parallel.run_tasks`);
    the folds' seeds do not depend on where they run, so both backends give the same figures.
    Returns a JSON-ready dict plus two frames, ``states`` and ``changes`` (out-of-fold).
    """
    analysis = analysis or AnalysisSettings()
    dec = decisions[decisions["driver_id"].astype(str).isin(drivers)]
    if dec.empty:
        raise UserError(f"no decisions of {', '.join(drivers)} in the analysis")
    sessions = (
        dec.groupby("recording_id", sort=True)
        .agg(driver_id=("driver_id", "first"), speed_limit_kph=("speed_limit_kph", "first"))
        .reset_index()
    )
    if len(sessions) < settings.folds and settings.split == "session":
        raise UserError(f"{len(sessions)} session(s) cannot make {settings.folds} folds: pass a smaller --folds")
    fold_of = assign_folds(sessions, settings)
    fold = dec["recording_id"].astype(str).map(fold_of).to_numpy()
    n_folds = int(fold.max()) + 1
    rng = np.random.default_rng([settings.seed, 7])
    jobs, per_fold, notes = [], [], []
    in_process = backend == "local"  # folds here report their agent's episodes; Ray's report finished folds
    unscored: dict[str, int] = {}
    for k in range(n_folds):
        train, test = dec[fold != k], dec[fold == k]
        test_app, skipped = approaches_from_decisions(test)
        train_app, _ = approaches_from_decisions(train)
        for r, c in skipped.items():
            unscored[r] = unscored.get(r, 0) + c
        if not test_app or not train_app:
            notes.append(f"fold {k}: {'no held-out' if not test_app else 'no training'} decisions, not scored")
            continue
        cfg = env
        if refit_lines:
            lines, line_notes = fold_lines(train, line_drivers, env.lines, analysis)
            cfg = replace(env, lines=lines)
            notes += [f"fold {k}: {n}" for n in line_notes]
        jobs.append(
            FoldJob(
                k,
                n_folds,
                train_app,
                test_app,
                skipped,
                cfg,
                replace(dqn, seed=dqn.seed + k),
                settings.seed + k,
                progress if in_process else None,
            )
        )
    if not jobs:
        raise UserError("no fold could be scored: " + "; ".join(notes))
    outer_inner_folds(jobs)
    if in_process:
        fold_agents(jobs, progress)
    evs = run_tasks(
        score_fold,
        jobs,
        backend=backend,
        ray_address=ray_address,
        progress=None if in_process else progress,
        label="held-out folds",
    )
    for job, ev in zip(jobs, evs):
        held_out = dec.loc[fold == job.fold, "recording_id"].astype(str)
        per_fold.append(
            {
                "fold": job.fold,
                "sessions": sorted(held_out.unique()),
                "n_train_decisions": len(job.train),
                "n_decisions": ev["n_decisions"],
                "lines": job.env.lines.to_dict(),
                **ev.get("learner", {}),
                **{f"{r['who']}_balanced_accuracy": r["balanced_accuracy"] for r in ev["summary"]},
            }
        )
    states = pd.concat([ev["states"] for ev in evs], ignore_index=True)
    changes = pd.concat([ev["changes"] for ev in evs], ignore_index=True)
    summary = [bootstrap_scores(states, changes, who, settings.n_bootstrap, rng) for who in POLICIES]
    by_direction = summary_by_direction(dec, states, changes, settings)
    n_total = int(dec["decision_id"].nunique())
    n_scored = int(states["decision_id"].nunique())
    return {
        "drivers": drivers,
        "line_drivers": line_drivers,
        "folds": n_folds,
        "settings": asdict(settings),
        "env": env.to_dict(),
        **learner_config(dqn),
        "summary": summary,
        "summary_by_direction": by_direction,
        "per_fold": per_fold,
        "n_decisions_total": n_total,
        "n_decisions_scored": n_scored,
        "scored_share": n_scored / n_total if n_total else None,
        "unscored": {k: v for k, v in unscored.items() if v},
        "notes": notes,
        "states": states,
        "changes": changes,
    }
