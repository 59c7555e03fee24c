"""The pytest plugin of `mhrc.testing` (entry point ``mhrc`` in ``pytest11``): the fixtures
``mhrc_world``, ``mhrc_model_server`` and ``mhrc_run_episode``.

pytest loads this module in every session of a project that installed mhrc, so it imports
nothing heavy: PyBullet, Zenoh and the world are imported inside the fixtures, when a test
asks for one.
"""

from __future__ import annotations

import contextlib
import itertools
from collections.abc import Awaitable, Callable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from mhrc.testing.model_server import Script, ScriptedModelServer
    from mhrc.testing.world import AgentSpec, EpisodeResult, LoopbackWorld

__all__ = ["mhrc_model_server", "mhrc_run_episode", "mhrc_world"]


@pytest.fixture
def mhrc_world(tmp_path: Path) -> Callable[..., contextlib.AbstractAsyncContextManager[LoopbackWorld]]:
    """A factory of `world_on_loopback`: ``async with mhrc_world(seed=0, horizon=5) as world``;
    each world's trace goes to the test's tmp_path unless you pass ``trace``."""
    from mhrc.testing.world import world_on_loopback  # PyBullet and Zenoh: only for a test that asks

    count = itertools.count()

    def make(**options: Any) -> contextlib.AbstractAsyncContextManager[LoopbackWorld]:
        options.setdefault("trace", tmp_path / f"mhrc-world-{next(count)}" / "trace.jsonl")
        return world_on_loopback(**options)

    return make


@pytest.fixture
def mhrc_model_server() -> Iterator[Callable[..., ScriptedModelServer]]:
    """A factory of `ScriptedModelServer` (same arguments); every server it made is closed
    at teardown."""
    from mhrc.testing.model_server import ScriptedModelServer

    servers: list[ScriptedModelServer] = []

    def make(script: Script, **kwargs: Any) -> ScriptedModelServer:
        servers.append(ScriptedModelServer(script, **kwargs))
        return servers[-1]

    yield make
    for server in servers:
        server.close()


@pytest.fixture
def mhrc_run_episode(tmp_path: Path) -> Callable[..., Awaitable[EpisodeResult]]:
    """`run_episode`, with each episode's trace in the test's tmp_path unless you pass ``trace``:
    ``result = await mhrc_run_episode({"alice": MyPolicy()}, seed=0)``."""
    from mhrc.testing.world import run_episode  # PyBullet and Zenoh: only for a test that asks

    count = itertools.count()

    async def run(policies: Mapping[str, AgentSpec] | None = None, **options: Any) -> EpisodeResult:
        options.setdefault("trace", tmp_path / f"mhrc-episode-{next(count)}" / "trace.jsonl")
        return await run_episode(policies, **options)

    return run
