"""`parallel_env()`: the lockstep schedule as a PettingZoo `ParallelEnv`; every live robot acts in
every step, the world runs the step's actions in the team's order and answers them together."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from .engine import EnvCore
from .options import check_render_mode, episode_config
from .spaces import action_space, observation_space

Obs = dict[str, str]


class MhrcParallelEnv(ParallelEnv[str, Obs, str]):
    """One mhrc episode at a time, every robot acting in every step (the lockstep schedule).

    Made with `mhrc up`'s episode options (`task`, `scene`, `objects`, `seed`, `horizon`, `team`,
    `aids`, `noise`, `events`, `ablation`, `history_cap`, `prompts`, `structured`); a bad one is a
    ValueError naming it. `expert=True`: each robot's infos carry the heuristic's next command."""

    metadata = {"name": "mhrc_parallel_v0", "render_modes": ["rgb_array"], "is_parallelizable": True}

    def __init__(self, *, render_mode: str | None = None, expert: bool = False, **options: Any) -> None:
        cfg = episode_config(options)
        self.render_mode = check_render_mode(render_mode)
        self.core = EnvCore(cfg, schedule="lockstep", expert=expert, render_mode=self.render_mode)
        self.possible_agents: list[str] = list(cfg.robots)
        self.agents: list[str] = []
        self.observation_spaces = {a: observation_space() for a in self.possible_agents}
        self.action_spaces = {a: action_space() for a in self.possible_agents}

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self.action_spaces[agent]

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Obs], dict[str, dict[str, Any]]]:
        self.core.reset(seed)
        self.agents = list(self.possible_agents)
        observations = {a: self.core.observation(a) for a in self.agents}
        return observations, {a: self.core.info(a, first=True) for a in self.agents}

    def step(
        self, actions: Mapping[str, Any]
    ) -> tuple[dict[str, Obs], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
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

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        return self.core.render()

    def close(self) -> None:
        self.core.close()
