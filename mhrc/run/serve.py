"""The world's side of an episode: build the scene, open the world's bus (a router, or a
client of one), record, and run the world's service."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from mhrc.core.bus import Bus
from mhrc.core.logs import get_logger
from mhrc.core.protocol import EpisodeDone

if TYPE_CHECKING:
    from mhrc.core.security import Credentials

from mhrc.core.bus import open_client
from mhrc.core.trace import Recorder
from mhrc.core.uncancelled import to_the_end
from mhrc.run.config import EpisodeConfig
from mhrc.world.service import WorldService
from mhrc.world.service_config import SimLike, WorldConfig

log = get_logger("mhrc.run.serve")

EventHook = Callable[[Bus, str], None]  # (bus, run) -> subscribes an observer
LAST_WORDS = 2.0  # s the world waits, once the episode is over, for its agents to leave and its trace to record the end


class Simulator(SimLike, Protocol):
    """What the world's side drives and closes: world.sim.Sim, or a test's stand-in for it."""

    def close(self) -> None: ...


Simulators = Callable[[EpisodeConfig], Simulator]  # a configuration -> its simulator, built


async def serve_world(
    cfg: EpisodeConfig,
    *,
    observe: EventHook | None = None,
    connect: str | None = None,
    login: Credentials | None = None,
    on_service: Callable[[Any], None] | None = None,
    simulator: Simulators | None = None,
) -> EpisodeDone:
    """Build the scene, open the world's bus (a router on cfg.endpoint, or with `connect` a
    client of a router that already exists, logged in with `login` if given: an evaluation
    worker's), record, and run the episode. `on_service` gets the WorldService once it exists
    (the in-process runner stops it when an agent fails for good). `simulator` builds the simulator
    from `cfg` (`EpisodeConfig.sim` by default: no camera renders the world's simulator): a test injects one that wraps the real one, as httpx's
    MockTransport stands in for the network, instead of patching the world's methods."""
    sim: Simulator = await asyncio.to_thread(simulator or EpisodeConfig.sim, cfg)
    bus = None
    recorder = None
    world: WorldService | None = None
    try:
        security = login if connect and login is not None else cfg.participant("world")
        bus = await (
            open_client(connect, 30.0, security=security)
            if connect
            else Bus.open(mode="router", listen=[cfg.endpoint], security=security)
        )
        trace_failed = asyncio.Event()
        if cfg.trace is not None:
            loop = asyncio.get_running_loop()
            recorder = Recorder(
                bus, cfg.run, cfg.trace, on_error=lambda _e: loop.call_soon_threadsafe(trace_failed.set)
            ).start()
        if observe is not None:
            observe(bus, cfg.run)
        world = WorldService(
            bus,
            sim,
            WorldConfig(
                run=cfg.run,
                horizon=cfg.horizon,
                start_timeout=cfg.start_timeout,
                tick_delay=cfg.tick_delay,
                schedule=cfg.schedule,
                time_scale=cfg.time_scale,
                token_deadline=cfg.token_deadline,
                protocol=cfg.protocol,
            ),
        )
        if on_service is not None:
            on_service(world)
        world.listen()  # before the loop runs anything else: no observer acts before the world listens
        try:
            return await _until(trace_failed, world)
        except asyncio.CancelledError:
            world.stop()
            raise
        finally:
            await world.agents_left(LAST_WORDS)  # the last results and the done event reached the agents
    finally:  # to its end, even when a cancellation (SIGTERM, Ctrl-C) comes in the middle of it
        await to_the_end(
            _close(recorder, LAST_WORDS if world is not None and world.done is not None else 0.0, bus, sim)
        )
        if recorder is not None and recorder.error is not None:
            raise recorder.error  # everything is closed: one line for the user, not a run that goes on unrecorded


async def _close(recorder: Recorder | None, until_done: float, bus: Bus | None, sim: Simulator) -> None:
    """The trace (its last lines), then the bus, then the simulator."""
    if recorder is not None:
        await asyncio.to_thread(recorder.close, until_done=until_done)
    if bus is not None:
        await bus.close()
    await asyncio.to_thread(sim.close)


async def _until(failed: asyncio.Event, world: WorldService) -> EpisodeDone:
    """The world's episode, stopped (its end said to the agents) as soon as `failed` is set."""
    run, stop = asyncio.ensure_future(world.run()), asyncio.ensure_future(failed.wait())
    try:
        await asyncio.wait({run, stop}, return_when=asyncio.FIRST_COMPLETED)
        if run.done():
            return run.result()
        world.stop()
        if world.started:  # a step under way (a skill in the simulator's thread) ends before the simulator closes
            await asyncio.wait({run}, timeout=30.0)  # bounded: a stop must end
        assert world.done is not None
        return world.done
    finally:
        for task in (run, stop):
            task.cancel()
        await asyncio.gather(run, stop, return_exceptions=True)
