"""`mhrc up`: the world and every agent as asyncio tasks of this process, on one Zenoh bus.

The world's session is a Zenoh router listening on `tcp/HOST:PORT`. An agent that logs in as
itself (the secured bus) connects to it as a client; on the open bus (and in an evaluation
worker, whose participants share one login) every agent shares the world's session instead
(Bus.share). Either way any participant's messages reach every other one, and the recorder on
the world's session sees them all."""

from __future__ import annotations

import asyncio
import contextlib
from typing import TYPE_CHECKING, Any

from mhrc.core.bus import Bus
from mhrc.core.keys import Keys
from mhrc.core.logs import get_logger
from mhrc.core.protocol import EpisodeDone, EpisodeStarted, ProtocolError, decode_event

if TYPE_CHECKING:
    from mhrc.core.security import Credentials

from mhrc.agents.llm import LLMFatalError
from mhrc.run.attach import local_models, run_agent
from mhrc.run.config import EpisodeConfig
from mhrc.run.coordinated import close_seats, seat
from mhrc.run.serve import EventHook, serve_world

log = get_logger("mhrc.run.inprocess")


async def up_in_process(
    cfg: EpisodeConfig,
    *,
    observe: EventHook | None = None,
    robots: tuple[str, ...] | None = None,
    connect: str | None = None,
    login: Credentials | None = None,
) -> EpisodeDone:
    """World and the given robots' agents (default: the episode's) as asyncio tasks of this
    process; with `connect`, all of them join that router's bus instead of the world listening,
    each logged in with `login` when given (an evaluation worker's credentials)."""
    robots = cfg.robots if robots is None else robots
    async with local_models({r: cfg.robot_specs()[r] for r in robots}, cfg.llm_seed) as specs:
        return await _run_in_process(cfg, specs, observe=observe, robots=robots, connect=connect, login=login)


async def _run_in_process(
    cfg: EpisodeConfig,
    specs: dict[str, str | None],
    *,
    observe: EventHook | None,
    robots: tuple[str, ...],
    connect: str | None,
    login: Credentials | None = None,
) -> EpisodeDone:
    login = login if connect else None
    listening = asyncio.Event()
    started = asyncio.Event()  # the world started the episode: a robot whose agent fails now is only detached
    services: list[Any] = []  # the WorldService, once built
    failures: list[BaseException] = []  # an agent's error that ends the run: a model that cannot answer at all

    # the agents share the world's session when they would log in as it does (an evaluation
    # worker's one login, or none: the open bus): no link, no socket between them (Bus.share)
    share = login is not None or cfg.credentials is None
    world_bus: list[Bus] = []

    def on_open(bus: Bus, run: str) -> None:
        world_bus.append(bus)
        if observe is not None:
            observe(bus, run)

        def on_event(sample: Any) -> None:
            if started.is_set():  # every later event (a tick, a snapshot) would be decoded for nothing
                return
            with contextlib.suppress(ProtocolError):
                if isinstance(decode_event(sample.payload), EpisodeStarted):
                    started.set()

        bus.subscribe(Keys(run).world_event, on_event)
        listening.set()

    def on_agent_error(exc: BaseException) -> None:
        """Heard while the failing agent's session is still open: stop the world first, so that
        its robot is not reported as vanished and no episode is scored for a run that failed."""
        if _is_fatal(exc):
            failures.append(exc)
            for service in services:
                service.stop()

    world = asyncio.create_task(
        serve_world(cfg, observe=on_open, connect=connect, login=login, on_service=services.append), name="world"
    )
    ready = asyncio.create_task(listening.wait())
    await asyncio.wait({world, ready}, return_when=asyncio.FIRST_COMPLETED)
    if world.done():  # the world could not start (its port is taken, ...): say so now, no agent is left connecting
        ready.cancel()
        return world.result()
    own = cfg.robot_specs()  # before gguf: specs became their local servers' URLs
    seats = seat(cfg, robots, specs)
    agents = [
        asyncio.create_task(
            run_agent(
                r,
                cfg.run,
                connect or cfg.endpoint,
                llm=specs[r],
                base_url=cfg.base_url,
                client_options=cfg.client_options(own[r]),
                security=login or cfg.participant(r),
                on_error=on_agent_error,
                policy=seats.get(r),
                session_of=world_bus[0] if share else None,
                attach_timeout=cfg.attach_timeout,
                **cfg.policy_options(own[r]),
            ),
            name=f"agent-{r}",
        )
        for r in robots
    ]
    try:
        pending = {world, *agents}
        while world in pending:
            finished, pending = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
            if failures:  # a model that cannot answer at all: stop now, not at the horizon
                raise failures[0]
            early = [t.exception() for t in agents if t in finished and not t.cancelled() and t.exception() is not None]
            if early and not started.is_set():  # an agent gave up before the start (e.g. its attach timed out):
                if services and services[0].done is not None:  # the world ended it first (its trace failed): its reason
                    await asyncio.wait({world})
                    world.result()
                raise early[0]  # type: ignore[misc]  # the world would wait for its robot forever
            # (an agent's task cancelled mid-episode, its agent killed, is a robot that detached: the world goes on)
            if world not in finished and not any(t in pending for t in agents):
                errors = [t.exception() for t in agents if not t.cancelled() and t.exception() is not None]
                if errors:  # every agent is gone and nobody else will attach: stop the world
                    raise errors[0]  # type: ignore[misc]
        done = world.result()
    except asyncio.CancelledError:  # interrupted: the world goes first, so that no robot is reported as vanished
        world.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await world
        raise
    finally:
        for t in agents:
            if not t.done():
                t.cancel()
        results = await asyncio.gather(*agents, return_exceptions=True)
        world_failed = (
            world.done() and not world.cancelled() and world.exception() is not None
        )  # said by the run's error
        for r, res in zip(robots, results):
            if (
                not world_failed
                and isinstance(res, BaseException)
                and not isinstance(res, asyncio.CancelledError)
                and not (failures and _is_fatal(res))
            ):
                log.warning(
                    "agent ended with an error", robot=r, error=str(res)
                )  # (the run's own failure is raised, not logged)
        if not world.done():
            world.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await world
        await close_seats(seats)  # the agents are over: the protocol's model clients close
    return done


def _is_fatal(exc: BaseException | None) -> bool:
    return isinstance(exc, LLMFatalError)
