"""The agents of personalisation: a base agent trained on other drivers, the new
driver's agent fine-tuned from it, and the K-decision baselines.

Fine-tuning starts from the base agent's weights and replays a mix: the driver's
K approaches, repeated so that they make `driver_share` of the replayed states,
beside the base's own approaches (so the prior is kept where the K decisions say
nothing, e.g. at speeds the driver has not driven yet). Exploration starts low and
the step size small, since the base already decides well (rl/README.md,
"A new driver from a few lane changes", has the variants measured).

The blend (base 'blend') is every candidate at once: the greedy action of the weighted
sum of their advantages Q(change) - Q(keep), each scaled by its spread on the
population's states, as one wider network (`blended_network`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import torch

from laneprint.errors import UserError
from laneprint.progress import ProgressFn, report
from rl.evaluation.evaluate import Policy
from rl.learners.dqn import DQNTrainer
from rl.problem.env import Approach, EnvConfig
from rl.problem.rewards import CHANGE, KEEP
from rl.problem.scene import Scene
from rl.settings import DQNSettings

from rl.personalize.settings import BASES, BLEND_PRIORS, METHODS, PersonalizeSettings  # noqa: F401


def mixed(base: list[Approach], own: list[Approach], share: float) -> list[Approach]:
    """`base` plus `own` repeated so that `own`'s states make about `share` of all replayed states."""
    if not base or share >= 1.0:
        return list(own)
    n_base, n_own = sum(len(a) for a in base), sum(len(a) for a in own)
    reps = max(1, int(round(share / (1 - share) * n_base / max(n_own, 1))))
    return list(base) + list(own) * reps


def train_agent(
    approaches: list[Approach],
    env: EnvConfig,
    dqn: DQNSettings,
    init: dict[str, torch.Tensor] | None = None,
    progress: ProgressFn | None = None,
    label: str = "agent",
    on_episode: Any = None,
) -> DQNTrainer:
    """A DQN trained on `approaches` (recorded scenes), from `init`'s weights when given."""
    if not approaches:
        raise UserError(f"{label}: no recorded approaches to train on")
    trainer = DQNTrainer(env, dqn, approaches=approaches)
    if init is not None:
        for net in (trainer.q, trainer.target, trainer.q_avg):
            net.load_state_dict(init)

    def tick(t: DQNTrainer) -> bool:
        report(progress, t.episodes_done, t.settings.episodes, f"{label}: episode {t.episodes_done}")
        return False

    trainer.train(on_episode=on_episode, on_vector_step=tick)
    return trainer


def finetune_settings(dqn: DQNSettings, ps: PersonalizeSettings, k: int, episodes: int | None = None) -> DQNSettings:
    """The trainer's settings for fine-tuning on `k` decisions (`episodes` overrides the rule)."""
    return replace(
        dqn,
        episodes=episodes or ps.finetune_episodes(k),
        episodes_per_approach=0.0,
        learning_rate=ps.learning_rate,
        learning_rate_end=ps.learning_rate / 10,
        eps_start=ps.eps_start,
        learning_starts=ps.learning_starts,
    )


def personalised_agent(
    base_weights: dict[str, torch.Tensor] | None,
    base: list[Approach],
    own: list[Approach],
    env: EnvConfig,
    dqn: DQNSettings,
    ps: PersonalizeSettings,
    episodes: int | None = None,
    progress: ProgressFn | None = None,
    on_episode: Any = None,
) -> DQNTrainer:
    """The driver's agent from the base (weights and approaches) and its own approaches, by `ps.method`
    ('unsure' must be resolved first: `PersonalizeSettings.resolved`)."""
    if ps.method == "unsure":
        raise ValueError("method 'unsure' depends on the style's confidence: resolve it first")
    if ps.method == "mix":
        data = mixed(base, own, ps.driver_share)
        settings = replace(
            dqn, episodes=episodes or dqn.episodes, episodes_per_approach=0.0 if episodes else dqn.episodes_per_approach
        )
        return train_agent(data, env, settings, None, progress, "personalised (mix)", on_episode)
    if base_weights is None:
        raise UserError("fine-tuning needs the base agent's weights")
    if ps.method == "none":  # the base as it is (a trainer of no episodes, so it saves as any run)
        return train_agent(
            own,
            env,
            replace(dqn, episodes=0, episodes_per_approach=0.0),
            base_weights,
            progress,
            "personalised (base as is)",
            on_episode,
        )
    data = own if ps.method == "own" else mixed(base, own, ps.driver_share)
    return train_agent(
        data, env, finetune_settings(dqn, ps, len(own), episodes), base_weights, progress, "personalised", on_episode
    )


def agreement(policy: Policy, approaches: list[Approach]) -> float:
    """Balanced accuracy of `policy` on the recorded states of `approaches` (press vs not yet)."""
    scene = Scene.concat([a.scene for a in approaches])
    y = np.concatenate([np.r_[np.zeros(len(a) - 1, bool), True] for a in approaches])
    said = np.asarray(policy(scene)) == CHANGE
    recall = said[y].mean() if y.any() else 0.5
    spec = (~said[~y]).mean() if (~y).any() else 0.5
    return float((recall + spec) / 2)


def best_fit(fits: dict[str, float], shares: dict[str, float]) -> str:
    """The base whose agent agrees best with the driver's decisions (`fits`: base -> `agreement`);
    ties go to the larger bootstrap share of the style (`shares`; the population has none, so it comes last)."""
    return max(fits, key=lambda b: (round(fits[b], 9), shares.get(b, -1.0)))


def candidates(ps: PersonalizeSettings, est: Any, pop: Any, others: list[str]) -> dict[str, list[str]]:
    """The bases `ps.base` chooses among, name -> drivers: every style's and the population's when it
    chooses by agreement or blends, else the one `ps.base_for` names (`est`: the `StyleEstimate`, `pop`: the `Population`)."""
    if ps.base_for(est.confidence) in ("fit", "blend"):
        return {**{f"style {s}": list(m) for s, m in pop.members.items() if m}, "population": list(others)}
    if ps.base_for(est.confidence) == "population":
        return {"population": list(others)}
    return {f"style {est.style}": list(pop.members[est.style])}


def network_of(weights: dict[str, torch.Tensor], env: EnvConfig, dqn: DQNSettings) -> torch.nn.Module:
    """A Q network with `weights` (the shape of `dqn.hidden` on `env`'s observation), in eval mode."""
    from rl.learners.dqn import q_network
    from rl.problem.env import observation_names

    net = q_network(dqn.hidden, len(observation_names(env)))
    net.load_state_dict(weights)
    net.eval()
    return net


def policy_of(weights: dict[str, torch.Tensor], env: EnvConfig, dqn: DQNSettings) -> Policy:
    """The greedy policy of a Q network with `weights` (`network_of`)."""
    from rl.evaluation.evaluate import agent_policy

    return agent_policy(network_of(weights, env, dqn), env)


def weights_of(trainer: DQNTrainer) -> dict[str, torch.Tensor]:
    """A copy of the trained policy's weights."""
    return {k: v.detach().clone() for k, v in trainer.policy_net.state_dict().items()}


def base_seed(seed: int) -> int:
    """The base agent's seed, apart from the personalised agent's."""
    return int(np.random.SeedSequence([seed, 3]).generate_state(1)[0] % (2**31))


# --- the blend: every candidate's advantage, weighted -------------------------------------------------------------


def advantages(
    weights: dict[str, torch.Tensor], env: EnvConfig, dqn: DQNSettings, approaches: list[Approach]
) -> np.ndarray:
    """Q(change) - Q(keep) of a Q network with `weights` on every recorded state of `approaches`."""
    from rl.learners.dqn import q_values
    from rl.problem.env import observation

    q = q_values(network_of(weights, env, dqn), observation(Scene.concat([a.scene for a in approaches]), env))
    return q[:, CHANGE] - q[:, KEEP]


def advantage_scale(
    weights: dict[str, torch.Tensor], env: EnvConfig, dqn: DQNSettings, approaches: list[Approach]
) -> float:
    """The spread (std) of an agent's advantage on the states of `approaches` (the population's in a blend:
    one set of states for every candidate), so that no candidate dominates a blend by the scale of its Q values."""
    a = advantages(weights, env, dqn, approaches)
    sd = float(np.std(a)) if len(a) > 1 else 0.0
    return sd if np.isfinite(sd) and sd > 1e-9 else 1.0


def blend_weights(ps: PersonalizeSettings, shares: dict[str, float], fits: dict[str, float]) -> dict[str, float]:
    """Each candidate's weight in the blend (summing to 1): its prior (prior 'share': a style's bootstrap share
    times 1 - `blend_population`, the population `blend_population`; 'equal': alike) times its agreement with the
    K approaches to the power `blend_fit_power`. `fits`: candidate -> agreement (every candidate; the population is
    'population'); `shares`: candidate -> the style's bootstrap share (the population has none)."""
    prior = {}
    for name in fits:
        if ps.blend_prior == "equal":
            prior[name] = 1.0
        elif name == "population":
            prior[name] = ps.blend_population
        else:
            prior[name] = (1.0 - ps.blend_population) * float(shares.get(name, 0.0))
    raw = {n: prior[n] * max(float(fits[n]), 1e-9) ** ps.blend_fit_power for n in fits}
    total = sum(raw.values())
    if total <= 0:  # no prior weight anywhere (e.g. no population and no share): all alike
        raw, total = dict.fromkeys(fits, 1.0), float(len(fits))
    return {n: v / total for n, v in raw.items()}


def blended_network(parts: list[tuple[dict[str, torch.Tensor], float]]) -> dict[str, torch.Tensor]:
    """One `q_network` whose Q values are sum_i c_i Q_i(s) for the networks and coefficients in `parts` (all of one
    shape): the networks side by side (first layer stacked, the hidden layers block-diagonal, the output layer
    scaled by c_i and summed), so its greedy action is the sign of the weighted sum of the advantages and it saves,
    evaluates and exports as any run's network (hidden widths times len(parts))."""
    if not parts:
        raise ValueError("a blend of no networks")
    keys = list(parts[0][0])
    layers = sorted({int(k.split(".")[0]) for k in keys})
    out: dict[str, torch.Tensor] = {}
    for j, layer in enumerate(layers):
        ws = [p[0][f"{layer}.weight"].detach().float() for p in parts]
        bs = [p[0][f"{layer}.bias"].detach().float() for p in parts]
        if j == 0:
            w, b = torch.cat(ws, 0), torch.cat(bs, 0)
        elif j < len(layers) - 1:
            w, b = torch.block_diag(*ws), torch.cat(bs, 0)
        else:
            w = torch.cat([c * wi for wi, (_, c) in zip(ws, parts)], 1)
            b = parts[0][1] * bs[0]  # summed in order, as sum() did from 0
            for bi, (_, c) in zip(bs[1:], parts[1:]):
                b = b + c * bi
        out[f"{layer}.weight"], out[f"{layer}.bias"] = w.contiguous(), b.contiguous()
    return out


def blend(
    nets: dict[str, dict[str, torch.Tensor]], weights: dict[str, float], scales: dict[str, float], dqn: DQNSettings
) -> tuple[dict[str, torch.Tensor], DQNSettings]:
    """The blended network (`blended_network` of the candidates of nonzero weight, coefficients weight / scale)
    and `dqn` with its hidden widths."""
    used = [n for n in nets if weights.get(n, 0.0) > 0]
    parts = [(nets[n], weights[n] / scales[n]) for n in used]
    return blended_network(parts), replace(dqn, hidden=tuple(h * len(used) for h in dqn.hidden))
