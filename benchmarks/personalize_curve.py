"""The learning curve of personalisation, one held-out driver at a time (pure: frames in, frames out);
the harness of `benchmarks/personalize.py`.

For a driver: its last `test_sessions` sessions are held out; its first K
decisions of the earlier sessions (K = each of `ks`; 0 = all of them) are what
the new driver has shown; every other driver is the population. Policies, all
scored on the held-out sessions by `rl.evaluation.evaluate.evaluate_policies`:

- ``personalised`` (one per variant): the base agent as it is or fine-tuned on the K decisions
  (by the variant's method; 'unsure' fine-tunes when the style's confidence is below its `min_confidence`);
  base 'blend': every style's agent and the population's, their advantages weighted by `blend_weights`;
- ``style``: the agent of the style assigned from the K decisions (its members, the
  driver excluded); ``population``: the agent of all other drivers;
- ``scratch``: a DQN trained on the K decisions alone (`laneprint train --driver`'s defaults);
- ``imitation_k`` / ``imitation_pop_k``: the imitation classifier on the K decisions /
  on the population's plus the K;
- ``ceiling``: the driver's own agent on all its earlier sessions (``scratch`` at K = all).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import pandas as pd

from indicators.settings import AnalysisSettings
from laneprint.progress import ProgressFn
from rl.baselines.imitation import ImitationClassifier
from rl.evaluation.evaluate import agent_policy, evaluate_policies
from rl.personalize.agents import (
    PersonalizeSettings,
    advantage_scale,
    agreement,
    base_seed,
    best_fit,
    blend,
    blend_weights,
    personalised_agent,
    policy_of,
    train_agent,
    weights_of,
)
from rl.personalize.split import driver_rows, first_decisions, holdout_split
from rl.personalize.style import estimate_style, fit_population
from rl.problem.env import EnvConfig, approaches_from_decisions
from rl.settings import DQNSettings

#: K = 0 stands for all decisions of the earlier sessions.
ALL = 0


@dataclass(frozen=True)
class CurveSettings:
    """What the learning curve measures."""

    ks: tuple[int, ...] = (5, 10, 20, ALL)  # decisions the new driver has shown (0 = all but the held-out sessions)
    test_sessions: int = 1  # the driver's last sessions, held out and scored
    seed: int = 0  # agents, classifiers, bootstrap
    variants: dict[str, PersonalizeSettings] = field(default_factory=lambda: {"personalised": PersonalizeSettings()})


def _k_label(k: int) -> str:
    return "all" if k == ALL else str(k)


def driver_curve(
    decisions: pd.DataFrame,
    driver: str,
    others: list[str],
    env: EnvConfig,
    dqn: DQNSettings,
    settings: CurveSettings,
    analysis: AnalysisSettings,
    progress: ProgressFn | None = None,
) -> dict[str, Any]:
    """Every policy's held-out states and changes for one driver at every K (tagged ``driver``, ``k``),
    and one row per K with the style assigned and its confidence."""
    rows = driver_rows(decisions, driver)
    train_rows, test_rows = holdout_split(rows, settings.test_sessions)
    test_app, skipped = approaches_from_decisions(test_rows)
    pop = fit_population(decisions, others, analysis)
    others_rows = decisions[decisions["driver_id"].astype(str).isin(others)]
    pop_app, _ = approaches_from_decisions(others_rows)
    base_dqn = replace(dqn, seed=base_seed(dqn.seed))
    pop_agent = train_agent(pop_app, env, base_dqn, progress=progress, label=f"{driver}: population")
    agents = {"population": (weights_of(pop_agent), pop_app)}
    n_train = train_rows.loc[train_rows["label"] == "change", "decision_id"].nunique()
    need_all = any(ps.base in ("fit", "blend") for ps in settings.variants.values())
    scales: dict[str, float] = {}  # candidate -> the spread of its advantage on the population's states

    def style_agent(style: str) -> tuple[dict, list]:
        """The agent of `style`'s members (trained once per held-out driver)."""
        key = f"style:{style}"
        if key not in agents:
            members = pop.members[style]
            app, _ = approaches_from_decisions(decisions[decisions["driver_id"].astype(str).isin(members)])
            trainer = train_agent(app, env, base_dqn, progress=progress, label=f"{driver}: style {style}")
            agents[key] = (weights_of(trainer), app)
        return agents[key]

    states, changes, style_rows = [], [], []
    for k in settings.ks:
        kk = None if k == ALL or k >= n_train else k
        own_rows = first_decisions(train_rows, kk)
        own_app, _ = approaches_from_decisions(own_rows)
        est = estimate_style(pop, own_rows, PersonalizeSettings().n_bootstrap, settings.seed)
        style_key = f"style:{est.style}"
        style_agent(est.style)
        fits = {}
        if need_all:
            fits = {
                f"style:{s}": agreement(policy_of(style_agent(s)[0], env, dqn), own_app)
                for s in pop.members
                if pop.members[s]
            }
            fits["population"] = agreement(policy_of(agents["population"][0], env, dqn), own_app)
        fit_key = best_fit(fits, {f"style:{s}": v for s, v in est.bootstrap.items()}) if fits else style_key
        policies, blends = {}, {}
        for name, ps in settings.variants.items():
            ps = ps.resolved(est.confidence)  # method 'unsure': fine-tune only when the style is unsure
            which = ps.base_for(est.confidence)
            net_dqn = dqn
            if which == "blend":
                for b in fits:
                    if b not in scales:
                        scales[b] = advantage_scale(agents[b][0], env, dqn, pop_app)
                bw = blend_weights(ps, {f"style:{s}": v for s, v in est.bootstrap.items()}, fits)
                blends.update({f"blend[{name}][{b}]": v for b, v in bw.items()})
                w, net_dqn = blend({b: agents[b][0] for b in fits}, bw, scales, dqn)
                base_app = pop_app
            else:
                base_key = fit_key if which == "fit" else "population" if which == "population" else style_key
                w, base_app = agents[base_key]
            if ps.method == "none":
                policies[name] = policy_of(w, env, net_dqn)
                continue
            eps = None if ps.method == "mix" else min(dqn.episodes, ps.finetune_episodes(len(own_app)))
            trainer = personalised_agent(w, base_app, own_app, env, net_dqn, ps, episodes=eps, progress=progress)
            policies[name] = agent_policy(trainer.policy_net, env)
        policies["style"] = policy_of(agents[style_key][0], env, dqn)
        policies["population"] = policy_of(agents["population"][0], env, dqn)
        scratch = train_agent(own_app, env, dqn, progress=progress, label=f"{driver}: scratch K={_k_label(k)}")
        policies["scratch"] = agent_policy(scratch.policy_net, env)
        if k == ALL:
            policies["ceiling"] = policies["scratch"]
        policies["imitation_k"] = ImitationClassifier(random_state=settings.seed).fit(own_app, env).policy(env)
        policies["imitation_pop_k"] = (
            ImitationClassifier(random_state=settings.seed).fit(pop_app + own_app, env).policy(env)
        )
        ev = evaluate_policies(policies, test_app, env, skipped)
        for frame, out in ((ev["states"], states), (ev["changes"], changes)):
            frame.insert(0, "k", _k_label(k))
            frame.insert(0, "driver", driver)
            out.append(frame)
        style_rows.append(
            {
                "driver": driver,
                "k": _k_label(k),
                "n_decisions": len(own_app),
                "style": est.style,
                "confidence": est.confidence,
                "posterior": est.posterior[est.style],
                "fit_base": fit_key if fits else None,
                **{f"fit[{b}]": v for b, v in fits.items()},
                **blends,
            }
        )
    return {
        "states": pd.concat(states, ignore_index=True),
        "changes": pd.concat(changes, ignore_index=True),
        "styles": pd.DataFrame(style_rows),
        "n_test_decisions": len(test_app),
    }
