"""`PlaySession`: the page's server as a participant of the world: one robot, one driver.

A page that connects becomes the robot's agent: a bus session of its own (with the robot's
credentials on a secured bus), a `RobotAgent` driving the shared `HumanPolicy`. A page that
goes away keeps the robot attached for `RELOAD_GRACE` seconds: a reload (or the address opened
again) within it takes over the same agent and is shown the decision still pending, so the
player's turn is kept. After it, the agent's session closes, so the world sees the robot's
liveliness token go and detaches it, as it would a killed agent; opening the page again attaches
again (the policy keeps its histories). A second page for the same robot is refused while one
drives it: one driver per robot, as the world's attach rule; the same tab reloaded (its `tab`
id, kept in the tab's sessionStorage) replaces its old socket instead. The server subscribes to
nothing but the world's events and its robot's own keys (the agent's): it never asks for
`world/state`.
"""

from __future__ import annotations

import asyncio
import contextlib
from typing import TYPE_CHECKING, Final

from mhrc.agents.agent import AgentError, RobotAgent, WorldGone
from mhrc.core.bus import Sample, open_client
from mhrc.core.keys import Keys
from mhrc.core.logs import get_logger
from mhrc.core.protocol import EpisodeDone, EpisodeStarted, ProtocolError, RobotDetached, decode_event

from .human import HumanPolicy, Send
from .messages import Done, Hello

if TYPE_CHECKING:
    from mhrc.core.security import Credentials

log = get_logger("mhrc.play")

RELOAD_GRACE = 10.0  # s a page's robot stays attached after the page went: a reload takes over its turn
REPLACED: Final = "replaced"  # the message to a page whose tab reloaded: its socket closes, the new one drives
MAX_TAB = 64  # characters of a tab id (the page makes a UUID)


class SecondDriver(RuntimeError):
    """Another page drives this robot already."""


class PlaySession:
    """The person's robot: its policy, the page that drives it now, and that page's agent."""

    def __init__(
        self,
        robot: str,
        *,
        run: str,
        connect: str,
        security: Credentials | None = None,
        schedule: str | None = None,
        scene: str | None = None,
        attach_timeout: float = 30.0,
    ) -> None:
        self.robot = robot
        self.run = run
        self.connect = connect
        self.security = security
        self.schedule = schedule
        self.scene = scene
        self.attach_timeout = attach_timeout
        self.policy = HumanPolicy(robot)
        self.done: EpisodeDone | None = None
        self.started = False
        self.attaches = 0  # how many pages have driven the robot (a reopened tab attaches again)
        self.ended = asyncio.Event()
        self.lost: WorldGone | None = None  # the world went away before the episode's end
        self.reload_grace = RELOAD_GRACE
        self._driver: object | None = None
        self._tab = ""
        self._task: asyncio.Task[None] | None = None
        self._send: Send | None = None
        self._leaving: asyncio.Task[None] | None = None  # the grace after a page went, before its agent leaves

    def hello(self) -> Hello:
        return {
            "type": "hello",
            "robot": self.robot,
            "run": self.run,
            "schedule": self.schedule,
            "waits": self.schedule != "async",  # lockstep and sequential wait for the person's decision
            "started": self.started,
        }

    @property
    def driven(self) -> bool:
        """A page drives the robot now (a refused socket never counts)."""
        return self._driver is not None

    # ------------------------------------------------------------------ pages
    def open(self, page: object, send: Send, tab: str = "") -> None:
        """`page` drives the robot from now on; SecondDriver when another does. A page of the
        same `tab` as the driver's (a reload) replaces it; a page within the grace after the
        driver went takes over its agent, its pending decision included."""
        tab = tab[:MAX_TAB]
        if self._driver is not None:
            if not tab or tab != self._tab:
                raise SecondDriver(
                    f"robot {self.robot} is already driven from another page: one driver per robot, as the world "
                    "attaches one agent per robot; close the other tab first"
                )
            if self._send is not None:
                self._send({"type": REPLACED, "reason": "this tab was reloaded: the new page drives"})
        if self.done is not None:
            send(self.hello())
            send(self._done_message())
            return
        self._driver, self._send, self._tab = page, send, tab
        if self._leaving is not None:
            self._leaving.cancel()
            self._leaving = None
        send(self.hello())
        self.policy.connect(send)
        if self._task is None or self._task.done():
            self._task = asyncio.create_task(self._drive(), name=f"play-{self.robot}")

    async def close(self, page: object) -> None:
        """`page` is gone (reloaded, or its tab closed): after the grace with no page, its agent
        leaves the world, which detaches the robot."""
        if page is not self._driver:
            return
        self._driver, self._send = None, None
        self.policy.connect(None)
        if self._leaving is None:
            self._leaving = asyncio.create_task(self._leave(), name=f"play-{self.robot}-leaving")

    async def _leave(self) -> None:
        await asyncio.sleep(self.reload_grace)
        self._leaving = None
        if self._driver is not None:
            return
        task, self._task = self._task, None
        if task is not None and not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

    def submit(self, page: object, raw: str | bytes) -> None:
        if page is self._driver:
            self.policy.submit(raw)

    # ------------------------------------------------------------------ the world
    async def watch(self) -> EpisodeDone:
        """Hear the world's events (the start, detachments, the end) on a session of the robot's
        own, for as long as the episode runs; the episode's end."""
        bus = await open_client(self.connect, self.attach_timeout, security=self.security)
        try:
            bus.subscribe(Keys(self.run).world_event, self._on_event)
            bus.watch_liveliness(Keys(self.run).alive_world, self._on_world)
            await self.ended.wait()
            if self.lost is not None:
                raise self.lost
            assert self.done is not None
            return self.done
        finally:
            await bus.close()

    # ------------------------------------------------------------------ the agent
    async def _drive(self) -> None:
        """One page's agent: its own bus session, attached until the episode ends or the page leaves.
        What ends it early (the world gone, its attach refused) is said on the page."""
        try:
            bus = await open_client(self.connect, self.attach_timeout, security=self.security)
        except Exception as exc:  # the world does not answer (BusError, a refused login): said, not raised into nothing
            self._fail(exc)
            return
        agent = RobotAgent(
            bus,
            self.policy,
            run=self.run,
            robot=self.robot,
            attach_timeout=self.attach_timeout,
            endpoint=self.connect,
            security=self.security,
        )
        self.attaches += 1
        run = asyncio.ensure_future(agent.run())
        ended = asyncio.ensure_future(self.ended.wait())
        try:
            await asyncio.wait({run, ended}, return_when=asyncio.FIRST_COMPLETED)
            if not run.done() and self.policy.deciding:  # the episode ended while the person thought
                run.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                done = await run
                if done is not None:
                    self._end(done)
        except AgentError as exc:
            self._fail(exc)
        finally:
            for t in (run, ended):
                t.cancel()
            await bus.close()

    def _fail(self, exc: BaseException) -> None:
        log.warning("the robot's agent ended", robot=self.robot, error=str(exc))
        if self._send is not None:
            self._send({"type": "error", "reason": str(exc)})

    def _on_world(self, sample: Sample) -> None:
        """The world's liveliness token went away before the episode's end: nothing will end it now."""
        if not sample.is_put and self.done is None:
            self.lost = WorldGone(f"the world of run {self.run} disappeared before the episode's end")
            self._fail(self.lost)
            self.ended.set()

    def _on_event(self, sample: Sample) -> None:
        try:
            event = decode_event(sample.payload)
        except ProtocolError:
            return
        if isinstance(event, EpisodeStarted):
            self.started = True
            if self._send is not None:
                self._send({"type": "started"})
        elif isinstance(event, EpisodeDone):
            self._end(event)
        elif isinstance(event, RobotDetached) and self._send is not None:
            self._send({"type": "detached", "robot": event.robot, "reason": event.reason})

    def end(self, done: EpisodeDone) -> None:
        """The episode is over (told by whoever ran the world)."""
        self._end(done)

    def _end(self, done: EpisodeDone) -> None:
        if self.done is None:
            self.done = done
            if self._send is not None:
                self._send(self._done_message())
        self.ended.set()

    def _done_message(self) -> Done:
        assert self.done is not None
        m = self.done.metrics
        return {
            "type": "done",
            "reason": self.done.reason,
            "success": m.success,
            "placed": m.placed,
            "total": m.total,
            "temporal_steps": m.temporal_steps,
        }
