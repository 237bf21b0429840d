"""Many Q networks as one: `q_network`'s weights stacked along a leading agent axis.

A fleet trains K agents whose networks have the same shape. Stacked, a layer's
weights are one (K, out, in) tensor and a forward pass over K batches is one
`torch.baddbmm` per layer; the per-call overhead of K small networks becomes the
overhead of one. Each agent's maths is unchanged: the loss is a sum of per-agent
losses (so each agent's gradient is its own), Adam is elementwise, and gradient
clipping, learning rate and masking are per agent. `StackedAdam` keeps torch
Adam's exact update and converts to and from its state dict, so an agent trained
in a fleet resumes alone with `DQNTrainer` and the other way round. `StackedNets` is
the fleet's arithmetic for `rl.learners.dqn.DQNLoop`, the one training loop.
"""

from __future__ import annotations

import threading
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn

from rl.learners.dqn import q_network
from rl.settings import DQNSettings

#: The agent axis of every stacked tensor.
AGENT_AXIS = 0


def layer_keys(n_layers: int) -> list[tuple[str, str]]:
    """`nn.Sequential` state-dict keys of `q_network`'s linear layers (ReLUs sit between them)."""
    return [(f"{2 * i}.weight", f"{2 * i}.bias") for i in range(n_layers)]


def stack_state_dicts(state_dicts: list[dict[str, torch.Tensor]]) -> list[torch.Tensor]:
    """[W1, b1, W2, b2, ...] with W (K, out, in) and b (K, 1, out) from K `q_network` state dicts."""
    n_layers = len(state_dicts[0]) // 2
    out: list[torch.Tensor] = []
    for wk, bk in layer_keys(n_layers):
        out.append(torch.stack([sd[wk] for sd in state_dicts]).contiguous())
        out.append(torch.stack([sd[bk] for sd in state_dicts]).unsqueeze(1).contiguous())
    return out


def agent_state_dict(params: list[torch.Tensor], k: int) -> dict[str, torch.Tensor]:
    """Agent k's weights as a `q_network` state dict (copies, detached)."""
    sd = {}
    for i, (wk, bk) in enumerate(layer_keys(len(params) // 2)):
        sd[wk] = params[2 * i][k].detach().clone()
        sd[bk] = params[2 * i + 1][k, 0].detach().clone()
    return sd


def load_agent(params: list[torch.Tensor], k: int, state_dict: dict[str, torch.Tensor]) -> None:
    """Overwrite agent k's slice of `params` with a `q_network` state dict."""
    with torch.no_grad():
        for i, (wk, bk) in enumerate(layer_keys(len(params) // 2)):
            params[2 * i][k].copy_(state_dict[wk])
            params[2 * i + 1][k, 0].copy_(state_dict[bk])


#: `nn.Linear` draws its initial weights from torch's global generator: shards built in
#: threads at once must not interleave their seeding and drawing.
_INIT_LOCK = threading.Lock()


def init_params(seeds: list[int], hidden: tuple[int, ...], n_obs: int) -> list[torch.Tensor]:
    """Stacked initial weights: agent k's are `q_network`'s after `torch.manual_seed(seeds[k])`,
    as `DQNTrainer` draws them."""
    sds = []
    with _INIT_LOCK:
        for seed in seeds:
            torch.manual_seed(seed)
            sds.append(q_network(hidden, n_obs).state_dict())
    return stack_state_dicts(sds)


def forward(params: list[torch.Tensor], x: torch.Tensor) -> torch.Tensor:
    """Q values (K, B, actions) of K stacked networks for observations x (K, B, obs).

    The weights are stored (out, in) like `nn.Linear`'s and multiplied transposed:
    MKL's batched GEMM ran 2-3x faster that way than on (in, out) copies.
    """
    last = len(params) - 2
    for i in range(0, len(params), 2):
        x = torch.baddbmm(params[i + 1], x, params[i].transpose(1, 2))
        if i < last:
            x = x.relu_()  # in place: baddbmm's backward does not need its output
    return x


def select(tensors: list[torch.Tensor], keep: torch.Tensor) -> list[torch.Tensor]:
    """The agents `keep` (indices) of each stacked tensor, as new contiguous tensors."""
    return [t.index_select(AGENT_AXIS, keep).contiguous() for t in tensors]


def _per_agent(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """A (K,) tensor shaped to broadcast over `like` (K, ...)."""
    return x.reshape((-1,) + (1,) * (like.dim() - 1))


#: A tensor whose per-agent size is a multiple of this shares the optimiser's flat buffers (`FlatLayout`).
#: Elementwise kernels run in vectors of up to 32 floats (AVX-512, two registers) and finish a tensor's last
#: partial vector one element at a time, where `lerp` rounds differently (no fused multiply-add): blocks of whole
#: vectors, each agent's starting on a vector boundary, keep every element in the kernel path it took alone.
FLAT_BLOCK = 64


class FlatLayout:
    """Where a stack's tensors (K, ...) sit in one (K, P) buffer: those of `FLAT_BLOCK`-multiple per-agent
    size side by side in each agent's row (`bulk`), the others (`q_network`'s last bias) kept apart (`rest`).

    One elementwise operation over the buffer replaces one per tensor (Adam's ten, clipping's, for 7 of
    `q_network`'s 8 tensors): for a net this small the per-operation overhead was most of Adam's time. Each
    element goes through the same kernel path as in its own tensor, so the results are the same to the bit.
    """

    def __init__(self, like: list[torch.Tensor]) -> None:
        self.shapes = [tuple(t.shape[1:]) for t in like]
        self.bulk = [i for i, t in enumerate(like) if t[0].numel() % FLAT_BLOCK == 0]
        self.rest = [i for i in range(len(like)) if i not in self.bulk]
        sizes = [like[i][0].numel() for i in self.bulk]
        self.bounds = list(zip(np.cumsum([0] + sizes[:-1]).tolist(), np.cumsum(sizes).tolist()))
        self.width = int(sum(sizes))

    def views(self, flat: torch.Tensor) -> list[torch.Tensor]:
        """The bulk tensors as views of `flat` (K, P), in `bulk` order."""
        k = flat.shape[0]
        return [flat[:, a:b].view((k,) + self.shapes[i]) for i, (a, b) in zip(self.bulk, self.bounds)]

    def assemble(self, flat: torch.Tensor, rest: list[torch.Tensor]) -> list[torch.Tensor]:
        """Every tensor in order: the bulk ones as views of `flat`, the others from `rest` (in `rest` order)."""
        out: list[torch.Tensor] = [torch.empty(0)] * len(self.shapes)
        for i, v in zip(self.bulk, self.views(flat)):
            out[i] = v
        for i, t in zip(self.rest, rest):
            out[i] = t
        return out

    def zeros(self, k: int) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """A zero buffer (K, P) and every tensor's zeros (the bulk ones its views), in tensor order."""
        flat = torch.zeros(k, self.width)
        return flat, self.assemble(flat, [torch.zeros((k,) + self.shapes[i]) for i in self.rest])


def clip_grad_norms(grads: list[torch.Tensor], max_norm: float) -> torch.Tensor:
    """Rescale each agent's gradient to at most `max_norm` (as `clip_grad_norm_` per agent); returns the norms."""
    sq = grads[0].pow(2).flatten(1).sum(1)
    for g in grads[1:]:
        sq = sq + g.pow(2).flatten(1).sum(1)
    norms = sq.sqrt()
    coef = torch.clamp(max_norm / (norms + 1e-6), max=1.0)
    for g in grads:
        g.mul_(_per_agent(coef, g))
    return norms


class StackedAdam:
    """torch Adam's update (default betas and eps, no weight decay) for stacked parameters,
    with a learning rate and an on/off mask per agent.

    The bulk tensors' (`FlatLayout`) moments and gradients live in (K, P) buffers, each of Adam's and
    clipping's elementwise passes one operation over them, in place or into a kept scratch buffer (new
    temporaries of this size cost the allocator fresh pages each time); `exp_avg` and `exp_avg_sq` hold every
    tensor's moments, the bulk ones as views of the buffers.
    """

    def __init__(
        self, params: list[torch.Tensor], betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8
    ) -> None:
        self.betas, self.eps = betas, eps
        k = params[0].shape[0]
        self.layout = FlatLayout(params)
        self._m, self.exp_avg = self.layout.zeros(k)
        self._v, self.exp_avg_sq = self.layout.zeros(k)
        self.steps = torch.zeros(k, dtype=torch.float64)
        self._scratch(k)

    def _scratch(self, k: int) -> None:
        """The gradient and scratch buffers (K, P), and the gradient buffer's views."""
        self._g, self._tmp = torch.empty(k, self.layout.width), torch.empty(k, self.layout.width)
        self._g_views = self.layout.views(self._g)

    def gradients(self, grads: Sequence[torch.Tensor]) -> list[torch.Tensor]:
        """`grads` copied into the gradient buffer (bulk) or made contiguous (rest), for `clip` and `step`
        (valid until the next call)."""
        lay = self.layout
        torch._foreach_copy_(self._g_views, [grads[i] for i in lay.bulk])
        return lay.assemble(self._g, [grads[i].contiguous() for i in lay.rest])

    @torch.no_grad()
    def clip(self, grads: list[torch.Tensor], max_norm: float) -> torch.Tensor:
        """`clip_grad_norms` of `gradients`' output: the squares taken once over the buffer and summed per
        tensor in the same order; no rescale where no agent is over the norm (a rescale by 1 changes nothing)."""
        lay = self.layout
        squares = lay.assemble(torch.pow(self._g, 2, out=self._tmp), [grads[i].pow(2) for i in lay.rest])
        sq = squares[0].flatten(1).sum(1)
        for s2 in squares[1:]:
            sq = sq + s2.flatten(1).sum(1)
        norms = sq.sqrt()
        coef = torch.clamp(max_norm / (norms + 1e-6), max=1.0)
        if bool((coef < 1.0).any()):
            self._g.mul_(coef[:, None])
            for i in lay.rest:
                grads[i].mul_(_per_agent(coef, grads[i]))
        return norms

    @torch.no_grad()
    def step(self, params: list[torch.Tensor], grads: list[torch.Tensor], lr: torch.Tensor, mask: torch.Tensor) -> None:
        """One Adam step for the agents where `mask` (K,) is true, at their learning rates `lr` (K,).
        `grads`: `gradients`' output (else they are taken through it)."""
        lay = self.layout
        if any(grads[i].data_ptr() != v.data_ptr() for i, v in zip(lay.bulk, self._g_views)):
            grads = self.gradients(grads)
        b1, b2 = self.betas
        on = mask.to(torch.float64)
        self.steps += on
        steps = self.steps.clamp(min=1.0)
        bc1 = 1.0 - b1**steps
        bc2_sqrt = (1.0 - b2**steps).sqrt()
        step_size = (lr.to(torch.float64) / bc1 * on).to(torch.float32)
        w1 = ((1.0 - b1) * on).to(torch.float32)
        keep2 = torch.where(mask, torch.tensor(b2, dtype=torch.float64), torch.tensor(1.0, dtype=torch.float64)).to(
            torch.float32
        )
        w2 = ((1.0 - b2) * on).to(torch.float32)
        bc2_sqrt = bc2_sqrt.to(torch.float32)
        # the bulk: each line the per-tensor one below, one operation over the buffers
        m, v, g, tmp = self._m, self._v, self._g, self._tmp
        m.lerp_(g, w1[:, None])
        v.mul_(keep2[:, None]).addcmul_(g, torch.mul(g, w2[:, None], out=tmp))
        denom = torch.sqrt(v, out=tmp).div_(bc2_sqrt[:, None]).add_(self.eps)
        update = torch.div(m, denom, out=tmp).mul_(step_size[:, None])
        torch._foreach_sub_([params[i] for i in lay.bulk], lay.views(update))
        for i in lay.rest:
            p, g, m, v = params[i], grads[i], self.exp_avg[i], self.exp_avg_sq[i]
            m.lerp_(g, _per_agent(w1, m))
            v.mul_(_per_agent(keep2, v)).addcmul_(g, g * _per_agent(w2, g))
            denom = (v.sqrt() / _per_agent(bc2_sqrt, v)).add_(self.eps)
            p.sub_(m / denom * _per_agent(step_size, p))

    def select(self, keep: torch.Tensor) -> None:
        lay = self.layout
        self._m, self._v = self._m.index_select(AGENT_AXIS, keep), self._v.index_select(AGENT_AXIS, keep)
        self.exp_avg = lay.assemble(self._m, select([self.exp_avg[i] for i in lay.rest], keep))
        self.exp_avg_sq = lay.assemble(self._v, select([self.exp_avg_sq[i] for i in lay.rest], keep))
        self.steps = self.steps.index_select(0, keep)
        self._scratch(len(keep))

    def agent_state_dict(self, k: int, lr: float, hidden: tuple[int, ...], n_obs: int) -> dict[str, Any]:
        """Agent k's moments in the format of `torch.optim.Adam(..., fused=True).state_dict()`."""
        template = torch.optim.Adam(q_network(hidden, n_obs).parameters(), lr=lr, fused=True).state_dict()
        state: dict[int, dict[str, torch.Tensor]] = {}
        if self.steps[k] > 0:
            for i, (m, v) in enumerate(zip(self.exp_avg, self.exp_avg_sq)):
                m_k, v_k = m[k].clone(), v[k].clone()
                if i % 2 == 1:  # biases are stored (1, out)
                    m_k, v_k = m_k[0], v_k[0]
                state[i] = {"step": torch.tensor(float(self.steps[k])), "exp_avg": m_k, "exp_avg_sq": v_k}
        return {"state": state, "param_groups": template["param_groups"]}

    @torch.no_grad()
    def load_agent(self, k: int, optimizer_state: dict[str, Any]) -> None:
        """Set agent k's moments from a torch Adam state dict (missing state: a fresh optimiser)."""
        state = optimizer_state.get("state", {})
        if not state:
            for m, v in zip(self.exp_avg, self.exp_avg_sq):
                m[k].zero_()
                v[k].zero_()
            self.steps[k] = 0.0
            return
        for i, (m, v) in enumerate(zip(self.exp_avg, self.exp_avg_sq)):
            s = state[i] if i in state else state[str(i)]
            m[k].copy_(s["exp_avg"].reshape(m[k].shape))
            v[k].copy_(s["exp_avg_sq"].reshape(v[k].shape))
            self.steps[k] = float(s["step"])


def td_losses(
    params: list[torch.Tensor],
    target_params: list[torch.Tensor],
    batch: tuple[torch.Tensor, ...],
    gamma: float,
    loss: str,
    double_q: bool,
) -> torch.Tensor:
    """Per-agent TD losses (K,) of eq. 5 on a stacked batch, as `DQNTrainer._update` computes them."""
    obs, actions, rewards, next_obs, terminated = batch
    with torch.no_grad():
        target_q = forward(target_params, next_obs)
        if double_q:
            best = forward(params, next_obs).argmax(dim=2, keepdim=True)
            target_max = target_q.gather(2, best).squeeze(2)
        else:
            target_max = target_q.max(dim=2).values
        td_target = rewards + gamma * target_max * (1.0 - terminated)
    q = forward(params, obs).gather(2, actions.unsqueeze(2)).squeeze(2)
    if loss == "mse":
        return nn.functional.mse_loss(q, td_target, reduction="none").mean(dim=1)
    return nn.functional.smooth_l1_loss(q, td_target, reduction="none").mean(dim=1)


class StackedNets:
    """K agents' nets and optimisers stacked along the agent axis: a fleet's arithmetic (`rl.learners.dqn.Nets`).

    Each agent's initial weights are `q_network`'s after `torch.manual_seed` of its seed, as
    `OneNet` draws them; its update is `OneNet`'s up to floating-point summation order.
    """

    def __init__(self, settings: list[DQNSettings], n_obs: int) -> None:
        self.hidden, self.n_obs = settings[0].hidden, n_obs
        self.q = [p.requires_grad_(True) for p in init_params([s.seed for s in settings], self.hidden, n_obs)]
        self.target = [p.detach().clone() for p in self.q]
        self.q_avg = [p.detach().clone() for p in self.q]
        self.adam = StackedAdam(self.q)

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return forward(self.q, torch.from_numpy(obs)).argmax(dim=2).numpy()

    def update(
        self,
        batch: tuple[torch.Tensor, ...],
        learning: np.ndarray,
        lr: list[float],
        averaging: np.ndarray,
        s: DQNSettings,
    ) -> np.ndarray:
        losses = td_losses(self.q, self.target, batch, s.gamma, s.loss, s.double_q)
        mask = torch.from_numpy(learning)
        # weight gradients come back as transposed views (`forward` multiplies by W^T): copied once into
        # the optimiser's flat buffer, where clipping and Adam's ~10 elementwise passes take one operation each
        grads = self.adam.gradients(torch.autograd.grad((losses * mask).sum(), self.q))
        if s.max_grad_norm:
            self.adam.clip(grads, s.max_grad_norm)
        self.adam.step(self.q, grads, torch.tensor(lr, dtype=torch.float64), mask)
        averaged = torch.from_numpy(averaging) & mask
        if bool(averaged.any()):
            w = averaged.to(torch.float32) * s.average_tau
            with torch.no_grad():  # one call, each tensor's own `lerp_`
                torch._foreach_lerp_(self.q_avg, self.q, [_per_agent(w, p) for p in self.q])
        return losses.detach().numpy()

    @staticmethod
    def _copy(dst: list[torch.Tensor], src: list[torch.Tensor], j: int) -> None:
        with torch.no_grad():
            for d, s in zip(dst, src):
                d[j].copy_(s[j])

    def copy_target(self, j: int) -> None:
        self._copy(self.target, self.q, j)

    def start_average(self, j: int) -> None:
        self._copy(self.q_avg, self.q, j)

    def policy_state_dict(self, j: int, averaging: bool) -> dict[str, torch.Tensor]:
        return agent_state_dict(self.q_avg if averaging else self.q, j)

    def policy_actions(self, j: int, averaging: bool, x: np.ndarray) -> np.ndarray:
        params = self.q_avg if averaging else self.q
        with torch.inference_mode():
            q = forward([p[j : j + 1] for p in params], torch.as_tensor(x, dtype=torch.float32)[None])[0]
        return q.argmax(dim=1).numpy()

    def agent_state_dict(self, j: int, lr: float) -> dict[str, Any]:
        return {
            "q": agent_state_dict(self.q, j),
            "target": agent_state_dict(self.target, j),
            "q_avg": agent_state_dict(self.q_avg, j),
            "optimizer": self.adam.agent_state_dict(j, lr, self.hidden, self.n_obs),
        }

    def load_agent(self, j: int, state: dict[str, Any]) -> None:
        load_agent(self.q, j, state["q"])
        load_agent(self.target, j, state["target"])
        load_agent(self.q_avg, j, state["q_avg"])
        self.adam.load_agent(j, state["optimizer"])

    def select(self, keep: list[int]) -> None:
        idx = torch.tensor(keep, dtype=torch.long)
        with torch.no_grad():
            self.q = [p.requires_grad_(True) for p in select([p.detach() for p in self.q], idx)]
        self.target = select(self.target, idx)
        self.q_avg = select(self.q_avg, idx)
        self.adam.select(idx)
