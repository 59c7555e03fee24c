"""The world as a PettingZoo multi-agent environment, without the bus: `parallel_env()` (the
lockstep schedule) and `env()` (the paper's sequential loop), with the same simulator, skills,
feedback, partial observability, scheduling and metrics as `mhrc up` (docs/env.md).

Needs the `env` extra (`pip install -e ".[env]"`: pettingzoo and gymnasium)."""

from __future__ import annotations

import importlib.util
from typing import Any

if importlib.util.find_spec("pettingzoo") is None or importlib.util.find_spec("gymnasium") is None:
    raise ImportError('mhrc.env needs pettingzoo and gymnasium: pip install -e ".[env]" (or "mhrc[env]")')

from .aec import MhrcAECEnv  # noqa: E402
from .demos import Demonstration, Demonstrations, write_demonstrations  # noqa: E402
from .parallel import MhrcParallelEnv  # noqa: E402

__all__ = [
    "Demonstration",
    "Demonstrations",
    "MhrcAECEnv",
    "MhrcParallelEnv",
    "env",
    "parallel_env",
    "write_demonstrations",
]


def parallel_env(*, render_mode: str | None = None, expert: bool = False, **options: Any) -> MhrcParallelEnv:
    """Every robot acts in every step (lockstep). Options: `mhrc up`'s episode options (task,
    scene, objects, seed, horizon, team, aids, noise, events, ablation, history_cap, prompts,
    structured, protocol: the paper's `mhrc` only, docs/env.md); a bad one is a ValueError naming it."""
    return MhrcParallelEnv(render_mode=render_mode, expert=expert, **options)


def env(*, render_mode: str | None = None, expert: bool = False, **options: Any) -> MhrcAECEnv:
    """The robots take turns in the team's order (the paper's Algorithm 1). Options as `parallel_env`."""
    return MhrcAECEnv(render_mode=render_mode, expert=expert, **options)
