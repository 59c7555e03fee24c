"""`env()`: the paper's sequential loop (Algorithm 1) as a PettingZoo `AECEnv`; within a tick the
robots act one at a time in the team's order, each on the world the earlier ones left. A
robot's action's outcome comes back with its next turn's observation, as in the paper."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pettingzoo import AECEnv

from .making import Made

Obs = dict[str, str]


class MhrcAECEnv(Made, AECEnv[str, Obs, str]):
    """One mhrc episode at a time, the robots taking turns (the sequential schedule).

    Options as `MhrcParallelEnv`'s. A robot's observation is the one the world last gave it: its
    first comes with its first turn (before that it is empty). An action for a robot whose
    episode is over must be None (PettingZoo's rule: ValueError otherwise); `step` before `reset`,
    or after every robot has left, is a ValueError saying so, as the parallel env's is."""

    metadata = {"name": "mhrc_v0", "render_modes": ["rgb_array"], "is_parallelizable": True}

    def __init__(self, *, render_mode: str | None = None, expert: bool = False, **options: Any) -> None:
        super().__init__()
        self._make("sequential", render_mode, expert, options)
        self._was_reset = False

    def reset(self, seed: int | None = None, options: Mapping[str, object] | None = None) -> None:
        self.core.reset(seed)
        self._was_reset = True
        self.agents = list(self.possible_agents)
        self.rewards = dict.fromkeys(self.agents, 0.0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.infos = {a: self.core.info(a, first=True) for a in self.agents}
        turn = self.core.turn
        assert turn is not None
        self.agent_selection = turn

    def observe(self, agent: str) -> Obs:
        return self.core.observation(agent)

    def step(self, action: Any) -> None:
        """The selected robot's command; one that cannot be read or done is its feedback.
        ValueError, with nothing run, before `reset` and once every robot has left."""
        if not self._was_reset:
            raise ValueError("step before reset: call reset() to start an episode")
        if not self.agents:
            raise ValueError(
                f"step with no live agent (the episode is over, every robot has left; got {action!r:.80}): call reset() for another"
            )
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            self._was_dead_step(action)
            return
        self._cumulative_rewards[agent] = 0.0
        self.core.act(agent, action)
        reward = self.core.reward()
        self.rewards = dict.fromkeys(self.agents, reward)
        terminated, truncated = self.core.ended()
        for a in self.agents:
            self.infos[a] = self.core.info(a)
            self.terminations[a], self.truncations[a] = terminated, truncated
        if terminated or truncated:
            self.agent_selection = self.agents[0]  # each robot now steps None and leaves (PettingZoo's dead steps)
        else:
            turn = self.core.turn
            assert turn is not None
            self.agent_selection = turn
        self._accumulate_rewards()
