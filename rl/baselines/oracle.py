"""The exact optimal policy of a reward in the environment, by backward induction.

Every vehicle keeps its speed, so a scene's future is known: roll it forward
``max_steps`` steps (or until the ego reaches its leader), take the rewards of
changing and of keeping at every step, and solve
``V_k = max(r_change_k, r_keep_k + gamma * V_{k+1})`` backwards. The first
step's choice is what a perfectly trained DQN with that reward and `gamma` would
do: an upper bound that separates the reward's design from the learning.
(At the truncation horizon an unfinished episode is worth 0, as a time limit.)
"""

from __future__ import annotations

import numpy as np

from rl.problem.env import EnvConfig
from rl.problem.rewards import CHANGE, KEEP, action_rewards
from rl.problem.scene import Scene, indicators


def optimal_actions(scene: Scene, cfg: EnvConfig, gamma: float = 0.98, horizon: int | None = None) -> np.ndarray:
    """Optimal action (0 change / 1 keep) in each scene of the batch."""
    horizon = horizon or cfg.max_steps
    s = scene.copy()
    rc, rk, alive = [], [], []
    live = np.ones(len(s), bool)
    for _ in range(horizon):
        ind = indicators(s, cfg.far_follower_m, cfg.range_m)
        c, k = action_rewards(ind, cfg.lines, cfg.reward, cfg.dt_s)
        rc.append(c)
        rk.append(k)
        alive.append(live.copy())
        s.advance(cfg.dt_s)
        if cfg.end_at_leader:
            gap = np.where(s.f_present, s.x_f - s.x_e - s.hl_f, np.inf)
            live = live & (gap > 0)
    v_next = np.zeros(len(s))
    q_change = q_keep = None
    for k in range(horizon - 1, -1, -1):
        q_change = rc[k]
        # keeping into a collision ends the episode: nothing follows
        nxt = v_next if k + 1 < horizon else np.zeros(len(s))
        nxt = np.where(alive[k + 1] if k + 1 < horizon else False, nxt, 0.0)
        q_keep = rk[k] + gamma * nxt
        v_next = np.where(alive[k], np.maximum(q_change, q_keep), 0.0)
    return np.where(q_change >= q_keep, CHANGE, KEEP)


def oracle_policy(cfg: EnvConfig, gamma: float = 0.98):
    """`optimal_actions` as an evaluation policy."""
    return lambda scene: optimal_actions(scene, cfg, gamma)
