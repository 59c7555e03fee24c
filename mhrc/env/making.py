"""What both environment classes are made of: the options checked, the episode's core, the
agents and their spaces, rendering and closing."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

from .engine import EnvCore
from .options import check_render_mode, episode_config
from .spaces import action_space, observation_space


class Made:
    """The part of `MhrcParallelEnv` and `MhrcAECEnv` that does not depend on the schedule."""

    render_mode: str | None

    def _make(self, schedule: str, render_mode: str | None, expert: bool, options: Mapping[str, object]) -> None:
        """Check the options (ValueError naming a bad one) and set up the core, agents and spaces."""
        cfg = episode_config(options)
        self.render_mode = check_render_mode(render_mode)
        self.core = EnvCore(cfg, schedule=schedule, expert=expert, render_mode=self.render_mode)
        self.possible_agents: list[str] = list(cfg.robots)
        self.agents: list[str] = []
        self.observation_spaces = {a: observation_space() for a in self.possible_agents}
        self.action_spaces = {a: action_space() for a in self.possible_agents}

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space[Any]:
        return self.action_spaces[agent]

    def render(self) -> np.ndarray | None:
        """The video's frame of the world now (rgb_array), or None without a render mode."""
        return self.core.render()

    def close(self) -> None:
        self.core.close()
