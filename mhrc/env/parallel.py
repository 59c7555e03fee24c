"""`parallel_env()`: the lockstep schedule as a PettingZoo `ParallelEnv`; every live robot acts in
every step, the world runs the step's actions in the team's order and answers them together."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pettingzoo import ParallelEnv

from .engine import RobotInfo
from .making import Made

Obs = dict[str, str]


class MhrcParallelEnv(Made, ParallelEnv[str, Obs, str]):
    """One mhrc episode at a time, every robot acting in every step (the lockstep schedule).

    Made with `mhrc up`'s episode options (`task`, `scene`, `objects`, `seed`, `horizon`, `team`,
    `aids`, `noise`, `events`, `ablation`, `history_cap`, `prompts`, `structured`, `protocol`: the paper's `mhrc` only); a bad one is a
    ValueError naming it. `expert=True`: each robot's infos carry the heuristic's next command."""

    metadata = {"name": "mhrc_parallel_v0", "render_modes": ["rgb_array"], "is_parallelizable": True}

    def __init__(self, *, render_mode: str | None = None, expert: bool = False, **options: Any) -> None:
        self._make("lockstep", render_mode, expert, options)

    def reset(
        self, seed: int | None = None, options: Mapping[str, object] | None = None
    ) -> tuple[dict[str, Obs], dict[str, RobotInfo]]:
        self.core.reset(seed)
        self.agents = list(self.possible_agents)
        observations = {a: self.core.observation(a) for a in self.agents}
        return observations, {a: self.core.info(a, first=True) for a in self.agents}

    def step(
        self, actions: Mapping[str, Any]
    ) -> tuple[dict[str, Obs], dict[str, float], dict[str, bool], dict[str, bool], dict[str, RobotInfo]]:
        """Every live robot's command (a dict keyed by agent); a command that cannot be read or
        done is that robot's feedback. ValueError, with nothing run, for actions that are not such
        a dict: not a mapping, an agent that is not live, a live agent left out."""
        if not isinstance(actions, Mapping):
            raise ValueError(f"actions must be a dict of commands keyed by agent, not {type(actions).__name__}")
        not_live = sorted(map(str, set(actions) - set(self.agents)))
        missing = [a for a in self.agents if a not in actions]
        if not_live or missing:
            said = [f"not live: {', '.join(not_live)} (live: {', '.join(self.agents) or 'none'})"] if not_live else []
            said += [f"no action for {', '.join(missing)}"] if missing else []
            raise ValueError("actions: " + "; ".join(said))
        if not self.agents:
            return {}, {}, {}, {}, {}
        live = list(self.agents)
        for agent in live:  # the world runs the tick when the last of them has submitted
            self.core.act(agent, actions[agent])
        reward = self.core.reward()
        terminated, truncated = self.core.ended()
        observations = {a: self.core.observation(a) for a in live}
        infos = {a: self.core.info(a) for a in live}
        if terminated or truncated:
            self.agents = []
        return (
            observations,
            dict.fromkeys(live, reward),
            dict.fromkeys(live, terminated),
            dict.fromkeys(live, truncated),
            infos,
        )
