"""`mhrc play`'s runs: the world and the AI teammates in this process with the page's server
beside them (`play_here`), or the page's server alone against a world elsewhere (`play_there`)."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable
from typing import TYPE_CHECKING

from mhrc.core.protocol import EpisodeDone, Observation
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.run.serve import EventHook

from .app import serving
from .gate import Gate
from .house import house_svg, scene_of
from .session import PlaySession

if TYPE_CHECKING:
    from mhrc.core.security import Credentials

LINGER = 1.0  # s the page's server stays once the episode ended: the page hears the end


def _mapped(session: PlaySession) -> None:
    """The map the page draws: the episode's layout, or the shipped one whose furniture the robot knows."""
    cache: dict[str, tuple[str, str]] = {}

    def house(obs: Observation) -> tuple[str, str]:
        scene = session.scene or scene_of(obs) or ""
        if scene not in cache:
            cache[scene] = (scene, house_svg(scene or None, obs))
        return cache[scene]

    session.policy.house = house


async def play_here(
    cfg: EpisodeConfig,
    robot: str,
    sock: socket.socket,
    gate: Gate,
    *,
    on_ready: Callable[[], None] | None = None,
    observe: EventHook | None = None,
) -> EpisodeDone:
    """The episode of `cfg` with `robot` driven from the page served on `sock` behind `gate`, the
    other robots by their agents (heuristic or --llm) in this process."""
    session = PlaySession(
        robot,
        run=cfg.run,
        connect=cfg.endpoint,
        security=cfg.participant(robot),
        schedule=cfg.schedule,
        scene=cfg.scene,
    )
    _mapped(session)
    teammates = tuple(r for r in cfg.robots if r != robot)
    async with serving(session, sock, gate):
        if on_ready is not None:
            on_ready()
        watch = asyncio.create_task(session.watch(), name="play-watch")  # the start and detachments, for the page
        try:
            done = await up_in_process(cfg, robots=teammates, observe=observe)
            session.end(done)
            await asyncio.sleep(LINGER)
        finally:
            watch.cancel()
            await asyncio.gather(watch, return_exceptions=True)
    return done


async def play_there(
    robot: str,
    connect: str,
    run: str,
    sock: socket.socket,
    gate: Gate,
    *,
    security: Credentials | None = None,
    on_ready: Callable[[], None] | None = None,
) -> EpisodeDone:
    """The page's server as one more agent of a world elsewhere: `robot` of run `run` at `connect`."""
    session = PlaySession(robot, run=run, connect=connect, security=security)
    _mapped(session)
    async with serving(session, sock, gate):
        if on_ready is not None:
            on_ready()
        done = await session.watch()
        await asyncio.sleep(LINGER)
    return done
