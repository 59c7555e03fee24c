"""A world on loopback: `world_on_loopback` serves one episode's world, `run_episode` runs a
whole episode with your policies and returns its `EpisodeResult`."""

from __future__ import annotations

import asyncio
import contextlib
import tempfile
from collections.abc import AsyncIterator, Awaitable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeAlias

from mhrc.agents.agent import RobotAgent
from mhrc.agents.heuristic import heuristic_policy
from mhrc.agents.policy import Policy
from mhrc.analysis.metrics import EpisodeMetrics, from_trace
from mhrc.core.bus import Bus, Sample, open_client
from mhrc.core.keys import Keys
from mhrc.core.protocol import (
    ActionResult,
    EpisodeDone,
    ProtocolError,
    RobotAttached,
    RobotDetached,
    Thought,
    WorldState,
    decode,
    decode_event,
)
from mhrc.core.records import Payload, TraceLine, messages, read_records
from mhrc.run.attach import run_agent
from mhrc.run.config import EpisodeConfig
from mhrc.run.serve import Simulators, serve_world

__all__ = ["AgentSpec", "EpisodeResult", "LoopbackWorld", "run_episode", "world_on_loopback"]

DEFAULT_TIMEOUT = 300.0  # s: a bound on a whole episode, so that a regression fails instead of hanging
ATTACH_TIMEOUT = 30.0  # s: an agent's session and attach, while the world starts up

AgentSpec: TypeAlias = "Policy | Literal['heuristic'] | None"
"""What drives a robot: your `Policy`, ``"heuristic"`` (the built-in one), or None (in
`LoopbackWorld.agent`: as the episode's options configure the robot, heuristic or ``llm``; in
`run_episode`: no agent at all)."""


def _default_trace() -> Path:
    return Path(tempfile.mkdtemp(prefix="mhrc-episode-")) / "trace.jsonl"


async def robots_attached(bus: Bus, run: str, robots: set[str], timeout: float) -> None:
    """Return once the world of `run` has accepted the attach of every robot named, as `bus` sees it: its
    `robot_attached` events, and its state (`world/state`) for the attaches before this call. A robot's liveliness
    token says less: an agent declares it before it attaches. TimeoutError naming the missing ones after `timeout`."""
    keys = Keys(run)
    loop = asyncio.get_running_loop()
    attached: set[str] = set()
    news = asyncio.Event()

    def on_event(sample: Sample) -> None:
        try:
            event = decode_event(sample.payload)
        except ProtocolError:
            return
        if isinstance(event, RobotAttached):
            attached.add(event.robot)
        elif isinstance(event, RobotDetached):
            attached.discard(event.robot)
        news.set()

    bus.subscribe(keys.world_event, on_event)
    deadline = loop.time() + timeout
    known = False  # the world's state read, after the subscription: no attach falls between the two
    while not robots <= attached:
        left = deadline - loop.time()
        if left <= 0:
            raise TimeoutError(f"robots {sorted(robots - attached)} did not attach within {timeout:.0f} s")
        news.clear()
        if not known:
            replies = await bus.get(keys.world_state, timeout=min(2.0, left))
            with contextlib.suppress(ProtocolError):
                attached |= set(decode(replies[0], WorldState).attached) if replies else set()
                known = bool(replies)
            if known:
                continue
        with contextlib.suppress(TimeoutError):  # an event, or (no world answering yet) a new look at its state
            await asyncio.wait_for(news.wait(), max(0.0, min(left, 0.5 if not known else left)))


class LoopbackWorld:
    """The handle `world_on_loopback` yields: one episode's world, serving on 127.0.0.1."""

    def __init__(self, config: EpisodeConfig, world: asyncio.Task[EpisodeDone]) -> None:
        self.config = config
        self.world = world
        self.agents: dict[str, asyncio.Task[EpisodeDone | None]] = {}
        self._buses: list[Bus] = []

    @property
    def endpoint(self) -> str:
        """The world's Zenoh endpoint (``tcp/127.0.0.1:PORT``), for `open_client` or ``mhrc agent --connect``."""
        return self.config.endpoint

    @property
    def run(self) -> str:
        """The run id: every key of the episode is under ``mhrc/<run>/``."""
        return self.config.run

    @property
    def trace(self) -> Path:
        """The trace file the world writes (complete once `done()` returned)."""
        assert self.config.trace is not None
        return self.config.trace

    async def client(self, timeout: float = ATTACH_TIMEOUT) -> Bus:
        """A client session of your own on the world's bus, closed when the world's context exits."""
        bus = await open_client(self.endpoint, timeout)
        self._buses.append(bus)
        return bus

    async def attached(self, *robots: str, timeout: float = ATTACH_TIMEOUT) -> None:
        """Return once the world has accepted the attach of every robot named (its `robot_attached`
        events and its state, seen on a session of the handle's). Wait on this, not on a sleep,
        before acting on an attached robot. Raises TimeoutError after `timeout` seconds."""
        unknown = sorted(set(robots) - set(self.config.robots))
        if unknown:  # fails here, not as a timeout
            raise ValueError(
                f"no such robot in this episode: {', '.join(unknown)} (robots: {', '.join(self.config.robots)})"
            )
        await robots_attached(await self.client(timeout), self.run, set(robots), timeout)

    async def agent(
        self, robot: str, policy: AgentSpec = None, *, attach_timeout: float = ATTACH_TIMEOUT
    ) -> asyncio.Task[EpisodeDone | None]:
        """Start an agent for `robot` on its own session, driven by `policy` (a `Policy`,
        ``"heuristic"``, or None: as the episode's options configure the robot, heuristic or
        the model ``llm`` names). Returns its task, which ends with the episode (its result:
        the `EpisodeDone` the agent saw); it is cancelled, and its session closed, on exit.
        Cancelling the task is a crash as the world sees it (its liveliness goes); a new agent
        for the same robot may then be started, as a replacement."""
        if robot not in self.config.robots:
            raise ValueError(f"robot {robot!r} is not in this episode: {', '.join(self.config.robots)}")
        if robot in self.agents and not self.agents[robot].done():
            raise ValueError(f"an agent for {robot} is running; cancel its task first to replace it")
        cfg = self.config
        if policy is None:
            spec = cfg.robot_specs()[robot]
            coro: Awaitable[EpisodeDone | None] = run_agent(
                robot,
                cfg.run,
                cfg.endpoint,
                llm=spec,
                base_url=cfg.base_url,
                client_options=cfg.client_options(spec),
                attach_timeout=attach_timeout,
                **cfg.policy_options(spec),
            )
        else:
            chosen: Policy = heuristic_policy(robot) if policy == "heuristic" else policy  # type: ignore[assignment]
            coro = self._drive(robot, chosen, attach_timeout)
        task: asyncio.Task[EpisodeDone | None] = asyncio.ensure_future(coro)
        task.set_name(f"agent-{robot}")
        self.agents[robot] = task
        return task

    async def _drive(self, robot: str, policy: Policy, attach_timeout: float) -> EpisodeDone | None:
        bus = await open_client(self.endpoint, attach_timeout)
        try:
            return await RobotAgent(bus, policy, run=self.run, robot=robot, attach_timeout=attach_timeout).run()
        finally:
            await bus.close()

    async def done(self, timeout: float | None = DEFAULT_TIMEOUT) -> EpisodeDone:
        """The episode's final event, once the world has ended it (its trace is then complete).
        Raises TimeoutError after `timeout` seconds (the world keeps running)."""
        return await asyncio.wait_for(asyncio.shield(self.world), timeout)

    async def _close(self) -> None:
        tasks = [*self.agents.values(), self.world]
        for task in tasks:
            if not task.done():
                task.cancel()
        for task in tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for bus in self._buses:
            with contextlib.suppress(Exception):
                await bus.close()
        self._buses.clear()


@contextlib.asynccontextmanager
async def world_on_loopback(simulator: Simulators | None = None, **options: Any) -> AsyncIterator[LoopbackWorld]:
    """Serve one episode's world on a free port of 127.0.0.1 (a Zenoh router, multicast
    scouting off) as a task of this event loop, and yield its `LoopbackWorld`.

    `options` are `EpisodeConfig`'s fields (``task``, ``scene``, ``seed``, ``n_objects``,
    ``horizon``, ``schedule``, ``start_timeout``, ``trace``, ``llm``, ``base_url``, ...),
    checked as ``mhrc up`` checks them (`mhrc.run.config.ConfigError` names the bad one); the host
    is always 127.0.0.1, and without ``trace`` the trace goes to a fresh temporary directory.
    The world waits for every robot of the episode to attach (``start_timeout`` starts it with
    whoever came). `simulator` builds the world's simulator from the configuration
    (`EpisodeConfig.sim` by default): a test that must see or hold what the simulator does wraps the
    real one (``simulator=lambda cfg: Held(cfg.sim())``). On exit the agents and the world are cancelled if still running and every
    session opened through the handle is closed.
    """
    if options.get("host", "127.0.0.1") != "127.0.0.1":
        raise ValueError("world_on_loopback serves on 127.0.0.1 only")
    options["host"] = "127.0.0.1"
    if options.get("trace") is None:
        options["trace"] = _default_trace()
    cfg = EpisodeConfig.build(**options).resolved()
    world = LoopbackWorld(cfg, asyncio.create_task(serve_world(cfg, simulator=simulator), name=f"world-{cfg.run}"))
    try:
        yield world
    finally:
        await world._close()


# --------------------------------------------------------------------------- one whole episode


@dataclass
class EpisodeResult:
    """What `run_episode` returns: the world's final event, the trace (its file and its typed
    records, mhrc.core.records) and the metrics from it."""

    done: EpisodeDone
    trace: Path
    records: list[TraceLine]
    metrics: EpisodeMetrics
    config: EpisodeConfig

    def messages(self, kind: str, robot: str | None = None) -> list[Payload]:
        """The messages of one kind in the trace (``action_result``, ``thought``,
        ``action_request``, ``episode_started``, ...), optionally of one robot, in order, as the
        protocol's models."""
        return [
            line.msg
            for line in self.records
            if line.msg is not None
            and line.msg.kind == kind
            and (robot is None or getattr(line.msg, "robot", None) == robot)
        ]

    def results(self, robot: str | None = None) -> list[ActionResult]:
        """Every action result in the trace (or one robot's), in order."""
        return [r for r in messages(self.records, ActionResult) if robot is None or r.robot == robot]

    def thoughts(self, robot: str | None = None) -> list[Thought]:
        """Every published thought (prompt, reply, parse error, action), or one robot's."""
        return [t for t in messages(self.records, Thought) if robot is None or t.robot == robot]


async def run_episode(
    policies: Mapping[str, AgentSpec] | None = None, *, timeout: float = DEFAULT_TIMEOUT, **options: Any
) -> EpisodeResult:
    """Run one episode on loopback and return its `EpisodeResult`.

    `policies` maps a robot to your `Policy`, ``"heuristic"``, or None to leave it out (no
    agent attaches: pass ``start_timeout`` so the world starts without it). Robots not named
    play as `options` configure them: the heuristic policy, or the model ``llm`` names for them
    (``llm="bob=openai:test", base_url=server.url``). `options` are `world_on_loopback`'s.
    Each agent has its own Zenoh session. An agent that fails (your policy raised, the world
    refused it, a model that cannot answer at all) fails the call at once with its error; the
    whole episode is bounded by `timeout` seconds (TimeoutError). Everything is closed on return.
    """
    policies = dict(policies or {})
    async with asyncio.timeout(timeout), world_on_loopback(**options) as world:
        unknown = sorted(set(policies) - set(world.config.robots))
        if unknown:
            raise ValueError(
                f"no such robot in this episode: {', '.join(unknown)} (robots: {', '.join(world.config.robots)})"
            )
        for robot in world.config.robots:
            if robot in policies and policies[robot] is None:
                continue
            await world.agent(robot, policies.get(robot))
        pending: set[asyncio.Future[Any]] = {world.world, *world.agents.values()}
        while world.world in pending:
            finished, pending = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
            for task in finished:
                error = None if task is world.world else task.exception()
                if error is not None:
                    raise error
        done = world.world.result()
        for task in world.agents.values():  # they end on the world's episode_done
            await task
        trace = world.trace
        records = read_records(trace)
        return EpisodeResult(done=done, trace=trace, records=records, metrics=from_trace(records), config=world.config)
