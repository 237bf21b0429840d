"""Fleet training: many DQN agents trained together as one batched computation.

`FleetTrainer` is the DQN training loop (`rl.learners.dqn.DQNLoop`, the one `DQNTrainer`
runs for its single agent) over K agents at once. Each agent keeps everything that makes
it itself: its settings and seed, its environments (its own recorded approaches or lines),
its random generator (drawn from in the same order as alone), its replay memory, epsilon
and learning-rate schedules, target copies and policy averaging, all counted in its own
finished episodes. Only the arithmetic is shared: the K networks are stacked
(`rl.learners.batched.StackedNets`) so a forward pass, a TD loss and an Adam step are a few
batched tensor operations instead of K small ones. An agent that reaches its episodes
leaves the stack.

Per agent, a fleet computes what `DQNTrainer` computes with the same settings and
seed, up to floating-point summation order (`tests/rl/test_rl_fleet.py`), and its
checkpoints are `DQNTrainer.state_dict()`s: a fleet's agent resumes alone, and a
fleet resumes from its agents' checkpoints.
"""

from __future__ import annotations

from typing import Any, Callable

from rl.learners.batched import StackedNets
from rl.learners.dqn import DQNLoop, FleetMember
from rl.problem.env import observation_names
from rl.settings import DQNSettings

__all__ = ["FleetMember", "FleetTrainer", "SHARED_SETTINGS", "check_compatible"]

#: Settings that must be equal across a fleet (they fix tensor shapes or the shared update).
SHARED_SETTINGS = (
    "hidden",
    "num_envs",
    "batch_size",
    "gradient_steps",
    "buffer_size",
    "loss",
    "double_q",
    "gamma",
    "max_grad_norm",
    "average_tau",
)


def check_compatible(members: list[FleetMember]) -> None:
    """Raise ValueError unless the members can share one stack (same shapes, same update)."""
    first = members[0].settings
    n_obs = len(observation_names(members[0].env_config))
    for m in members[1:]:
        for name in SHARED_SETTINGS:
            if getattr(m.settings, name) != getattr(first, name):
                raise ValueError(
                    f"a fleet's agents must share {name!r}: {getattr(m.settings, name)} vs {getattr(first, name)}"
                )
        if len(observation_names(m.env_config)) != n_obs:
            raise ValueError("a fleet's agents must share the observation")


class FleetTrainer(DQNLoop):
    """Trains `members` together; each agent's run is `DQNTrainer`'s (see the module doc).

    `train(on_episode, on_checkpoint, on_finish, should_stop, on_vector_step)`: the
    callbacks get the member index first: `on_episode(i, row)`, `on_checkpoint(i,
    state)` with a `DQNTrainer.state_dict()`, `on_finish(i, policy_state_dict,
    state)` once when agent i reaches its episodes; `on_vector_step(fleet)` returning
    True stops training.
    """

    def __init__(
        self, members: list[FleetMember], threads: int = 1, states: list[dict[str, Any] | None] | None = None
    ) -> None:
        if members:
            check_compatible(members)
        super().__init__(members, StackedNets, threads, states)

    @property
    def settings(self) -> list[DQNSettings]:
        """Each member's settings, episodes resolved (in member order, finished agents included)."""
        return [a.settings for a in self._all]

    @property
    def episodes_done(self) -> list[int]:
        """Each member's finished episodes (in member order, finished and dropped agents included)."""
        return [a.episodes_done for a in self._all]

    @property
    def _all(self) -> list[Any]:
        return sorted(self.agents + self._finished, key=lambda a: a.member)

    def train(
        self,
        on_episode: Callable[[int, dict], None] | None = None,
        on_checkpoint: Callable[[int, dict], None] | None = None,
        on_finish: Callable[[int, dict, dict], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
        on_vector_step: Callable[[FleetTrainer], bool] | None = None,
    ) -> FleetTrainer:
        """Run until every agent has its episodes or `should_stop()` (see the class doc)."""

        def checkpoint(j: int) -> None:
            assert on_checkpoint is not None
            on_checkpoint(self.agents[j].member, self.agent_state_dict(j))

        def finish(j: int) -> None:
            assert on_finish is not None
            on_finish(self.agents[j].member, self.policy_state_dict(j), self.agent_state_dict(j))

        self.run(
            on_episode=on_episode,
            on_checkpoint=checkpoint if on_checkpoint is not None else None,
            on_finish=finish if on_finish is not None else None,
            should_stop=should_stop,
            on_vector_step=None if on_vector_step is None else lambda: on_vector_step(self),
        )
        return self
