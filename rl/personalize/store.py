"""`laneprint personalize`: a personalised agent as an ordinary run folder.

The run folder is a driver run's (`rl.runs`): config.json (plus ``kind:
'personalized'``, the K decision ids used, the base agent and the style estimate),
status.json, metrics.jsonl of the fine-tuning, checkpoint.pt, weights.pt and
evaluation.json, so `runs`, `evaluate` and `export` work on it. Beside them:
``base_weights.pt`` (the base agent, reused by a later personalisation with the same
base, data and settings) and ``personalize.json`` (the style estimate and the agent
scored on the driver's decisions after the first K, when there are any). With ``--from
blend`` the base is every candidate at once: weights.pt (and base_weights.pt) is one
`q_network` with the candidates side by side (`agents.blended_network`: hidden widths
times their number, recorded in config.json's ``dqn.hidden``), every candidate kept
under ``bases/``.
"""

from __future__ import annotations

import hashlib
import io
import json
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch

from laneprint.errors import UserError
from laneprint.progress import ProgressFn, report
from laneprint.workspace import Workspace, atomic_write_bytes, atomic_write_json
from rl.evaluation.crossval import bootstrap_scores
from rl.evaluation.evaluate import agent_policy, evaluate_policies
from rl.personalize.agents import (
    PersonalizeSettings,
    advantage_scale,
    agreement,
    base_seed,
    best_fit,
    blend,
    blend_weights,
    candidates,
    finetune_settings,
    personalised_agent,
    policy_of,
    train_agent,
    weights_of,
)
from rl.personalize.split import decision_order, driver_rows, first_decisions
from clustering.pipeline import stored_settings
from rl.personalize.style import estimate_style, fit_population
from rl.problem.env import Approach, EnvConfig, approaches_from_decisions, formulation_config, replayed_approaches
from rl.problem.rewards import ReferenceLines
from rl.runs import RunWriter, Target, create_run, evaluate_run, new_run_id, now_iso, run_dir
from rl.settings import DQNSettings

KIND = "personalized"


def _save(path: Path, obj: Any) -> None:
    buf = io.BytesIO()
    torch.save(obj, buf)
    atomic_write_bytes(path, buf.getvalue())


def _base_key(drivers: list[str], env: EnvConfig, dqn: DQNSettings, fingerprint: str) -> str:
    blob = json.dumps(
        {"drivers": sorted(drivers), "env": env.to_dict(), "dqn": dqn.to_dict(), "data": fingerprint},
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _cached_base(workspace: Workspace, key: str) -> tuple[dict[str, torch.Tensor], str] | None:
    """Base weights of an earlier personalised run with the same base key, and that run's id."""
    root = workspace.runs_dir
    for folder in sorted(root.glob("*"), reverse=True) if root.exists() else []:
        try:
            config = json.loads((folder / "config.json").read_text())
        except (OSError, ValueError):
            continue
        if config.get("kind") != KIND:
            continue
        base = config.get("base", {})
        for path in ([folder / "base_weights.pt"] if base.get("key") == key else []) + [
            folder / "bases" / f"{key}.pt" for c in base.get("candidates", {}).values() if c.get("key") == key
        ]:
            if path.exists():
                return torch.load(path, weights_only=True), folder.name
    return None


def _lines(workspace: Workspace, style: str) -> ReferenceLines:
    """The style's typical lines from the stored analysis (they feed only the greedy benchmark)."""
    try:
        return ReferenceLines.from_table(workspace.read_table("analysis", "reference_lines"), style=style)
    except (UserError, KeyError, OSError):
        return ReferenceLines.paper("Normal")


def later_scores(
    net: torch.nn.Module, rows: pd.DataFrame, used: set[str], env: EnvConfig, seed: int
) -> dict[str, Any] | None:
    """The agent on the driver's decisions after the first K (None when K took them all)."""
    later = rows[~rows["decision_id"].astype(str).isin(used)]
    approaches, _ = approaches_from_decisions(later)
    if not approaches:
        return None
    ev = evaluate_policies({"agent": agent_policy(net, env)}, approaches, env)
    return bootstrap_scores(ev["states"], ev["changes"], "agent", 1000, np.random.default_rng([seed, 13]))


def check_request(workspace: Workspace, driver: str, k: int | None) -> None:
    """Refuse, in one line, what `personalize` cannot do: no analysis, an unknown driver, K too large."""
    if not workspace.has_table("analysis", "decisions"):
        raise UserError(f"no analysis in {workspace.root}: run `laneprint analyze` first")
    first_decisions(driver_rows(workspace.read_table("analysis", "decisions"), driver), k)


def personalize(
    workspace: Workspace,
    driver: str,
    k: int | None = None,
    ps: PersonalizeSettings | None = None,
    dqn: DQNSettings | None = None,
    episodes: int | None = None,
    base_episodes: int | None = None,
    seed: int = 0,
    run_id: str | None = None,
    progress: ProgressFn | None = None,
) -> dict[str, Any]:
    """Train `driver`'s agent from its first `k` decisions (None: all) and the rest of the workspace.

    Returns a JSON-ready summary: run id, the style estimate, the base, the fine-tuning.
    """
    ps = ps or PersonalizeSettings()
    dqn = replace(dqn or DQNSettings(), seed=seed)
    if not workspace.has_table("analysis", "decisions"):
        raise UserError(f"no analysis in {workspace.root}: run `laneprint analyze` first")
    decisions = workspace.read_table("analysis", "decisions")
    rows = driver_rows(decisions, driver)
    own_rows = first_decisions(rows, k)
    used = decision_order(own_rows)
    others = sorted(set(decisions["driver_id"].astype(str)) - {str(driver)})
    if not others:
        raise UserError(
            f"{driver} is the only driver in the workspace: nothing to start from "
            f"(`laneprint train --driver {driver}` trains on its decisions alone)"
        )
    report(progress, 0, 1, "phase 1: style from the decisions")
    following = workspace.read_table("analysis", "following") if workspace.has_table("analysis", "following") else None
    pop = fit_population(decisions, others, stored_settings(workspace), following)
    est = estimate_style(pop, own_rows, ps.n_bootstrap, seed, following)
    used_ps = ps.resolved(est.confidence)  # method 'unsure': fine-tune only when the style is unsure
    env = formulation_config(_lines(workspace, est.style), "decisions")
    sized: dict[str, Any] = {"episodes": base_episodes, "episodes_per_approach": 0.0} if base_episodes else {}
    base_dqn = replace(dqn, seed=base_seed(seed), **sized)
    own_app, _ = approaches_from_decisions(own_rows)
    if not own_app:
        raise UserError(f"none of {driver}'s first {len(used)} decisions can be replayed (no press rows)")
    cands: dict[str, dict[str, Any]] = {
        name: {"drivers": d, "key": _base_key(d, env, base_dqn, workspace.fingerprint())}
        for name, d in candidates(ps, est, pop, others).items()
    }
    first = next(iter(cands))
    target = Target("driver", str(driver))
    with ExitStack() as held:
        run_id = run_id or new_run_id(target, f"personalized-k{len(used)}", seed)
        ft_settings = personalised_settings(dqn, used_ps, len(own_app), episodes)
        base: dict[str, Any] = {
            "from": ps.base,
            "style": est.style,
            "chosen": first,
            "drivers": cands[first]["drivers"],
            "key": cands[first]["key"],
            "seed": base_dqn.seed,
        }
        if len(cands) > 1:
            base["candidates"] = {n: {"key": c["key"], "drivers": c["drivers"]} for n, c in cands.items()}
        folder, config = create_run(
            workspace,
            target,
            env,
            ft_settings,
            run_id=run_id,
            held=held,
            extra={
                "kind": KIND,
                "decisions": len(used),
                "decisions_available": len(decision_order(rows)),
                "decision_ids": used,
                "base": base,
                "style_estimate": est.to_dict(),
                "personalize": ps.to_dict(),
                "method": used_ps.method,
            },
        )
        writer = RunWriter(folder, ft_settings.episodes)
        cached_bases = {name: _cached_base(workspace, c["key"]) for name, c in cands.items()}
        tuning = f"personalising on {len(used)} decisions" if ft_settings.episodes else "the base agent as it is"
        phases = Phases(
            [
                "style from the decisions",
                *[f"training the base agent ({n})" for n, b in cached_bases.items() if b is None],
                tuning,
                "evaluating",
            ],
            writer,
            progress,
        )
        phases.done("style from the decisions")

        def phase(episodes_total: int, what: str) -> ProgressFn:
            """Progress to the caller and to status.json (a dashboard follows the run by it), as phase `what`."""
            phases.start(what, episodes_total)

            def tick(done: int, total: int, message: str = "") -> None:
                report(progress, done, total, phases.label(message or what))
                writer.episodes = episodes_total
                writer.status("running", done, what, force=False)

            return tick

        try:
            weights: dict[str, dict[str, torch.Tensor]] = {}
            apps: dict[str, list[Approach]] = {}
            for name, c in cands.items():
                app, _ = approaches_from_decisions(decisions[decisions["driver_id"].astype(str).isin(c["drivers"])])
                apps[name], c["n_approaches"] = app, len(app)
                cached = cached_bases[name]
                if cached is not None:
                    weights[name], c["reused_from"] = cached
                    continue
                what = f"training the base agent ({name})"
                trainer = train_agent(
                    app,
                    env,
                    base_dqn,
                    label=f"base ({name})",
                    progress=phase(base_dqn.resolved_episodes(replayed_approaches(app, env)).episodes, what),
                )
                weights[name], c["episodes"] = weights_of(trainer), trainer.episodes_done
            chosen, net_dqn = first, dqn
            blending = used_ps.base_for(est.confidence) == "blend"
            if len(cands) > 1:  # 'fit': the base that agrees best with the K decisions; 'blend': all, weighted
                fits = {n: agreement(policy_of(w, env, dqn), own_app) for n, w in weights.items()}
                shares = {f"style {s}": v for s, v in est.bootstrap.items()}
                chosen = "blend" if blending else best_fit(fits, shares)
                if blending:  # each candidate's advantage scaled by its spread on the population's states
                    blend_w = blend_weights(used_ps, shares, fits)
                    scales = {n: advantage_scale(w, env, dqn, apps["population"]) for n, w in weights.items()}
                for n, c in cands.items():
                    counted: dict[str, Any] = {x: c[x] for x in ("n_approaches", "episodes", "reused_from") if x in c}
                    base["candidates"][n].update({"agreement": fits[n], **counted})
                    if blending:
                        base["candidates"][n].update({"weight": blend_w[n], "advantage_std": scales[n]})
                    if n != chosen:
                        _save(folder / "bases" / f"{c['key']}.pt", weights[n])
            if chosen == "blend":
                base_w, net_dqn = blend(weights, blend_w, scales, dqn)
                base_app = apps["population"]
                base.update(
                    {
                        "chosen": "blend",
                        "drivers": list(others),
                        "key": None,
                        "n_approaches": len(base_app),
                        "weights": blend_w,
                        "hidden": list(net_dqn.hidden),
                    }
                )
                config["dqn"]["hidden"] = list(net_dqn.hidden)  # the blended network's widths (evaluate, export)
            else:
                counted = {
                    x: cands[chosen][x] for x in ("n_approaches", "episodes", "reused_from") if x in cands[chosen]
                }
                base.update(
                    {
                        "chosen": chosen,
                        "drivers": cands[chosen]["drivers"],
                        "key": cands[chosen]["key"],
                        **counted,
                    }
                )
                base_w, base_app = weights[chosen], apps[chosen]
            _save(folder / "base_weights.pt", base_w)
            atomic_write_json(folder / "config.json", config)
            trainer = personalised_agent(
                base_w,
                base_app,
                own_app,
                env,
                net_dqn,
                used_ps,
                episodes=episodes,
                progress=phase(ft_settings.episodes, tuning),
                on_episode=writer.metric,
            )
            writer.episodes = ft_settings.episodes
        except BaseException as exc:
            writer.flush()
            writer.status("failed", 0, f"{type(exc).__name__}: {exc}")
            writer.close()
            raise
        writer.flush()
        _save(folder / "checkpoint.pt", trainer.state_dict())
        _save(folder / "weights.pt", trainer.policy_net.state_dict())
        phases.start("evaluating", 1)
        writer.status("running", trainer.episodes_done, "evaluating")
        report(progress, 0, 1, phases.label("evaluating"))
        later = later_scores(trainer.policy_net, rows, set(used), env, seed)
        extra = {
            "run_id": run_id,
            "driver": str(driver),
            "decisions": len(used),
            "decisions_available": config["decisions_available"],
            "style": est.to_dict(),
            "base": base,
            "method": used_ps.method,
            "fine_tuned": used_ps.method != "none",
            "later_decisions": later,
            "created_at": now_iso(),
            "analysis_fingerprint": config.get("analysis_fingerprint"),
        }
        atomic_write_json(folder / "personalize.json", extra)
        evaluate_run(workspace, run_id)
        what = (
            f"the blend of {sum(v > 0 for v in base['weights'].values())} agents weighted by {len(used)} decisions"
            if chosen == "blend"
            else f"the {chosen} agent"
        )
        message = (
            f"{what} as it is" + ("" if chosen == "blend" else f", chosen by {len(used)} decisions")
            if used_ps.method == "none"
            else f"personalised on {len(used)} decisions from {what}"
        )
        if ps.method == "unsure":  # say why it did or did not fine-tune
            message += (
                f" (style {est.style} sure: confidence {est.confidence:.2f} >= {ps.min_confidence:g})"
                if used_ps.method == "none"
                else f" (style {est.style} unsure: confidence {est.confidence:.2f} < {ps.min_confidence:g})"
            )
        writer.extra = {}
        writer.status("done", trainer.episodes_done, message)
        writer.close()
    return {
        **extra,
        "folder": str(folder),
        "state": "done",
        "episodes": trainer.episodes_done,
        "env_steps": trainer.env_steps,
        "wall_s": round(trainer.wall_s, 2),
        "message": message,
    }


class Phases:
    """A personalisation's phases in order (the style, each base agent trained, the fine-tuning, the
    evaluation): which one is under way, written into status.json (`phase`, `phases`, `phase_name`,
    `phase_started_at`: a dashboard's time estimate is the phase's own) and named in the command line's bar
    ('phase 2/4: ...')."""

    def __init__(self, names: list[str], writer: RunWriter, progress: ProgressFn | None) -> None:
        self.names, self.writer, self.progress = names, writer, progress
        self.index = 0

    def label(self, message: str) -> str:
        return f"phase {self.index + 1}/{len(self.names)}: {message}"

    def start(self, name: str, episodes: int) -> None:
        """Phase `name` begins, with `episodes` to go (its status says 0 of them)."""
        self.index = self.names.index(name) if name in self.names else min(self.index + 1, len(self.names) - 1)
        self.writer.extra = {
            "phase": self.index + 1,
            "phases": len(self.names),
            "phase_name": name,
            "phase_started_at": now_iso(),
        }
        self.writer.episodes = episodes
        self.writer.status("running", 0, name)
        report(self.progress, 0, max(episodes, 1), self.label(name))

    def done(self, name: str) -> None:
        """Phase `name` is over (the style, estimated before the run's folder existed)."""
        self.index = self.names.index(name)
        report(self.progress, 1, 1, self.label(name))


def personalised_settings(dqn: DQNSettings, ps: PersonalizeSettings, k: int, episodes: int | None) -> DQNSettings:
    """The settings recorded in the run's config.json: the fine-tuning's (or the mix's from scratch)."""
    if ps.method == "mix":
        return replace(
            dqn, episodes=episodes or dqn.episodes, episodes_per_approach=0.0 if episodes else dqn.episodes_per_approach
        )
    if ps.method == "none":  # the base as it is: no episodes
        return replace(finetune_settings(dqn, ps, k), episodes=0)
    return finetune_settings(dqn, ps, k, episodes)


def load_personalized(workspace: Workspace, run_id: str) -> dict[str, Any] | None:
    """A personalised run's personalize.json (None for other runs)."""
    try:
        return json.loads((run_dir(workspace, run_id) / "personalize.json").read_text())
    except (OSError, ValueError):
        return None
