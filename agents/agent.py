"""One robot's agent loop: attach, then observe -> decide -> request -> await result, until done.

The agent talks to the world only through the bus (attach query, action request/ack/result,
world events, the world's liveliness token), so the same code runs in the world's process,
in another process or on another host.
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import socket
import uuid
from typing import TYPE_CHECKING

from mhrc.core.bus import Bus, Sample
from mhrc.core.deadlines import ATTACH_TIMEOUT
from mhrc.core.keys import Keys
from mhrc.core.logs import get_logger
from mhrc.core.protocol import (
    OUT_OF_STEP,
    ActionAck,
    ActionRequest,
    ActionResult,
    AttachReply,
    AttachRequest,
    EpisodeDone,
    Generating,
    Observation,
    ProtocolError,
    RejectCode,
    RobotDetached,
    Thought,
    TickClosed,
    Turn,
    decode,
    decode_event,
)
from mhrc.core.protocol.thoughts import MAX_LINE, fit

from .policy import Decision, Policy
from .progress import PROGRESS, Progress

if TYPE_CHECKING:
    from mhrc.core.security import Credentials

log = get_logger("mhrc.agent")

RESYNC_BACKOFF = (
    0.5  # s: the first wait before attaching again for a tick whose action is already taken; doubles each time
)
RESYNC_BACKOFF_MAX = 8.0  # s
EXPIRY_SLACK = 10.0  # s: a secured link that closes this close to the run's certificates' end closed because of it
GENERATING_EVERY = (
    5.0  # s: a model call longer than this says how far it got (agent/<robot>/generating), then again every as long
)


class AgentError(RuntimeError):
    """The agent cannot go on."""


class AttachRejected(AgentError):
    """The world refused this agent (robot unknown, already attached, episode over)."""


class WorldGone(AgentError):
    """The world's liveliness token disappeared or it never answered."""


class _WorldLost(Exception):
    """The world's liveliness token went away while this agent waited for `what`: the world may
    have died, or this agent's own link was cut (frozen with SIGSTOP, a network blip)."""

    def __init__(self, what: str) -> None:
        super().__init__(what)
        self.what = what


def _listening(endpoint: str | None) -> bool | None:
    """Whether something accepts TCP connections at a zenoh endpoint (tcp/ or tls/HOST:PORT); None if unknown."""
    if not endpoint or "/" not in endpoint:
        return None
    host, _, port = endpoint.split("/", 1)[1].rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=1.0):
            return True
    except ValueError:
        return None
    except OSError:
        return False


class RobotAgent:
    """Drives `policy` for `robot` in run `run` until the episode ends."""

    def __init__(
        self,
        bus: Bus,
        policy: Policy,
        *,
        run: str,
        robot: str,
        agent_id: str | None = None,
        attach_timeout: float = ATTACH_TIMEOUT,
        ack_timeout: float = 10.0,
        result_timeout: float | None = None,
        final_result_grace: float = 10.0,
        endpoint: str | None = None,
        security: Credentials | None = None,
    ) -> None:
        self.bus = bus
        self.security = security  # this agent's login, to name why a secured link closed (an expired certificate)
        self.policy = policy
        self.robot = robot
        self.keys = Keys(run)
        self.keys.alive_robot(robot)  # validates the robot id
        self.agent_id = agent_id or f"{robot}-{uuid.uuid4().hex[:8]}"
        self._session = secrets.token_hex(
            16
        )  # sent to the world alone, with each attach: a copy of the public agent id cannot re-attach
        self.attach_timeout = attach_timeout
        self.ack_timeout = ack_timeout
        self.result_timeout = result_timeout
        self.final_result_grace = final_result_grace
        # the world's endpoint, to tell a dead world from a cut link
        self.endpoint = endpoint or (bus.connected_to[0] if len(getattr(bus, "connected_to", ())) == 1 else None)
        self.episode: EpisodeDone | None = None
        self.steps = 0
        self._acks: dict[str, asyncio.Future[ActionAck]] = {}
        self._results: dict[str, asyncio.Future[ActionResult]] = {}
        self._done = asyncio.Event()
        self._world_gone = asyncio.Event()
        self._playing = False  # attached once: a world that vanishes from now on is news
        self._over = False  # the world said the episode is over
        self._turn: asyncio.Future[Turn] | None = None  # set while attaching, for a world that says wait_turn
        self._clock = asyncio.Event()  # set on every tick the world closes (the stepped schedules)
        self._via_turn = False  # whether the last attach's observation came with a Turn (a fresh turn, not a repeat)
        self._log = log.bind(run=run, robot=robot, agent=self.agent_id)

    # ------------------------------------------------------------------ bus handlers
    def _resolve(self, sample: Sample, model: type[ActionAck] | type[ActionResult], waiting: dict) -> None:  # type: ignore[type-arg]
        """Hand an ack or result to the request awaiting its goal id."""
        try:
            msg = decode(sample.payload, model)
        except ProtocolError as exc:
            self._log.warning("malformed message ignored", key=sample.key, reason=str(exc))
            return
        fut = waiting.get(msg.goal_id)
        if fut is not None and not fut.done():
            fut.set_result(msg)

    def _on_turn(self, sample: Sample) -> None:
        try:
            turn = decode(sample.payload, Turn)
        except ProtocolError as exc:
            self._log.warning("malformed turn ignored", reason=str(exc))
            return
        if turn.robot == self.robot and self._turn is not None and not self._turn.done():
            self._turn.set_result(turn)

    def _on_event(self, sample: Sample) -> None:
        try:
            event = decode_event(sample.payload)
        except ProtocolError as exc:
            self._log.warning("malformed world event ignored", reason=str(exc))
            return
        heard = getattr(self.policy, "world_event", None)  # a policy that follows the team (a central planner)
        if callable(heard):
            heard(event)
        if isinstance(event, EpisodeDone):
            self.episode = event
            self._done.set()
        elif isinstance(event, TickClosed):
            self._clock.set()
        elif isinstance(event, RobotDetached) and event.agent_id == self.agent_id and not self._done.is_set():
            # the world let this robot go (its token was late or lost) while the agent lives: attach again
            self._log.warning("the world detached this robot", reason=event.reason)
            self._world_gone.set()

    def _on_world_liveliness(self, sample: Sample) -> None:
        if not sample.is_put:
            if self._playing and not self._done.is_set():  # after the end the world leaves as it should; before
                self._log.warning("world vanished")  # the first attach, the attach says why it failed
            self._world_gone.set()

    # ------------------------------------------------------------------ running
    async def run(self) -> EpisodeDone | None:
        """Play the episode. Returns the world's final event, or None if it never came."""
        k = self.keys
        self.bus.subscribe(k.action_ack(self.robot), lambda s: self._resolve(s, ActionAck, self._acks))
        self.bus.subscribe(k.action_result(self.robot), lambda s: self._resolve(s, ActionResult, self._results))
        self.bus.subscribe(k.world_event, self._on_event)
        self.bus.subscribe(k.turn(self.robot), self._on_turn)  # before attaching: a turn may come before the reply
        self.bus.watch_liveliness(k.alive_world, self._on_world_liveliness)
        # presence before the attach: the world's deadline for it starts at the attach, and must not race it
        self.bus.declare_token(k.alive_robot(self.robot))
        try:
            attached = await self._attach()
        except AttachRejected:  # another agent may drive this robot: this token must not stand for it
            self.bus.undeclare_token(k.alive_robot(self.robot))
            raise
        self._playing = True
        while attached is not None and not self._done.is_set():
            obs = attached
            decision = await self._decide(obs)
            self._publish_thought(obs, decision)
            if self._done.is_set():  # the episode ended while this robot planned
                break
            try:
                result = await self._act(obs, decision)
            except _WorldLost as lost:
                attached = await self._reattach(lost.what)
                continue
            if result is None:
                if self._done.is_set() or self._over:
                    break
                attached = await self._resync(obs.tick)  # the world moved on (tick mismatch), or the tick is taken
                continue
            self.steps += 1
            self.policy.record(result)
            self._log.debug("action done", tick=result.tick, action=result.action.call(), ok=result.outcome.succeeded)
            attached = result.observation
            if result.done:
                break
        if self.episode is None:
            try:
                await asyncio.wait_for(self._done.wait(), 5.0)
            except TimeoutError:
                self._log.warning("no episode_done event received")
        return self.episode

    async def _reattach(self, what: str) -> Observation | None:
        """The world's token went away while this robot awaited `what`. A world that no longer
        listens is gone: say so now. Otherwise this agent's own link was cut (it was frozen, the
        network blinked) and the world detached it: attach again and go on."""
        if await asyncio.to_thread(_listening, self.endpoint) is False:  # a connect of up to 1 s: off the loop
            raise WorldGone(
                f"the world disappeared while {self.robot} awaited {what}: nothing listens at {self.endpoint} any more"
            )
        await self._closed_for_good(what)
        self._log.warning("lost the world's token, but the world may be there: attaching again", awaited=what)
        self._world_gone.clear()
        try:
            return await self._attach(again=True)
        except WorldGone:
            await self._closed_for_good(
                what
            )  # a certificate that expired in the meantime (the link may close a moment before)
            raise WorldGone(
                f"the world disappeared while {self.robot} awaited {what} and did not answer an attach since"
            ) from None

    async def _closed_for_good(self, what: str) -> None:
        """WorldGone naming the cause when a secured link closed for a reason no new attach
        fixes (an expired certificate, a foreign one)."""
        if self.security is not None and self.endpoint is not None:
            import datetime

            from mhrc.core.refusal import why_refused
            from mhrc.core.security import expiry

            why = await asyncio.to_thread(why_refused, self.endpoint, self.security)
            if why.final:
                raise WorldGone(f"the link to the world closed while {self.robot} awaited {what}: {why}")
            ends = expiry(
                self.security
            )  # the router may close links a moment before a handshake sees the certificate expired
            if (
                ends is not None
                and (ends - datetime.datetime.now(datetime.timezone.utc)).total_seconds() < EXPIRY_SLACK
            ):
                raise WorldGone(
                    f"the link to the world closed while {self.robot} awaited {what}: the run's certificate expired "
                    f"({ends:%Y-%m-%d %H:%M:%S} UTC): issue new credentials (mhrc credentials, or a new mhrc up)"
                )

    async def _resync(self, tick: int) -> Observation | None:
        """The world rejected this robot's request for `tick` as out of step: attach again to
        plan on the world's tick of now. If that is `tick` still, with no new turn, the robot's
        action of it is already taken (its own earlier request, sent again after its link blinked,
        or another process driving the same robot on the open bus): a new request would be
        rejected at once, again and again. Wait for the world to close a tick, or for a backoff
        that doubles each time, before attaching again."""
        delay = RESYNC_BACKOFF
        while True:
            self._clock.clear()
            attached = await self._attach()
            if attached is None or attached.tick != tick or self._via_turn or self._done.is_set():
                return attached
            if delay == RESYNC_BACKOFF:
                self._log.warning(
                    "this robot's action of the tick is already taken (its own earlier request, or another agent "
                    "process driving it): waiting for the tick to close",
                    tick=tick,
                )
            clock = asyncio.ensure_future(self._clock.wait())
            done = asyncio.ensure_future(self._done.wait())
            try:
                await asyncio.wait({clock, done}, timeout=delay, return_when=asyncio.FIRST_COMPLETED)
            finally:
                clock.cancel()
                done.cancel()
            if self._done.is_set():
                return None
            delay = min(delay * 2, RESYNC_BACKOFF_MAX)

    async def _attach(self, *, again: bool = False) -> Observation | None:
        """Attach and return the first observation to plan on; None when the episode ended
        while this robot waited for its turn. `again`: the world was there and its token went
        away; each unanswered attach probes whether it still listens (WorldGone when not: the
        probe before the first attempt can still connect to a world that is dying). A world
        whose token goes away while an attach is unanswered is handled as during any other
        exchange (_reattach)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.attach_timeout
        request = AttachRequest(robot=self.robot, agent_id=self.agent_id)
        self._turn = loop.create_future()  # a Turn from before this attach is stale
        self._via_turn = False
        try:
            while True:
                replies = await self.bus.get(
                    f"{self.keys.attach(self.robot)}?session={self._session}", request, timeout=2.0
                )
                if replies:
                    try:
                        reply = decode(replies[0], AttachReply)
                    except ProtocolError as exc:
                        raise AgentError(f"the world sent a malformed attach reply: {exc}") from None
                    if reply.accepted and reply.wait_turn:
                        self._log.info("attached, waiting for the turn", tick=reply.tick)
                        try:
                            turn = await self._await_turn(self._turn)
                        except _WorldLost:  # frozen or cut off while the teammates acted: probe, attach again
                            return await self._reattach("its turn")
                        self._via_turn = turn is not None
                        return None if turn is None else turn.observation
                    if not reply.accepted or reply.observation is None:
                        raise AttachRejected(f"the world refused {self.robot}: {reply.reason}")
                    self._log.info("attached", tick=reply.tick)
                    return reply.observation
                if (
                    not again and self._world_gone.is_set()
                ):  # its token went while this attach went unanswered: probe, attach again
                    return await self._reattach("its attach reply")
                if loop.time() >= deadline:
                    raise WorldGone(f"no world answered for run {self.keys.run!r} within {self.attach_timeout:.0f} s")
                if again and await asyncio.to_thread(_listening, self.endpoint) is False:
                    raise WorldGone(f"nothing listens at {self.endpoint} any more")
                await asyncio.sleep(0.2)
        finally:
            self._turn = None

    async def _await_turn(self, fut: asyncio.Future[Turn]) -> Turn | None:
        """The world's Turn for this robot; None when the episode ended first. Waiting for a
        turn is waiting for the teammates earlier in the order to plan and act, so it is bounded
        like awaiting a result (result_timeout), not by the attach timeout. _WorldLost when the
        world's token went away meanwhile (the caller probes and attaches again)."""
        return fut.result() if await self._until_end(fut, self.result_timeout, "its turn") else None

    async def _act(self, obs: Observation, decision: Decision) -> ActionResult | None:
        """Request the action and await its result; None when the world rejected it as stale."""
        req = ActionRequest(robot=self.robot, agent_id=self.agent_id, tick=obs.tick, action=decision.action)
        loop = asyncio.get_running_loop()
        ack_fut: asyncio.Future[ActionAck] = loop.create_future()
        res_fut: asyncio.Future[ActionResult] = loop.create_future()
        self._acks[req.goal_id] = ack_fut
        self._results[req.goal_id] = res_fut
        try:
            self.bus.put(self.keys.action_request(self.robot), req)
            ack = await self._await(req.goal_id, ack_fut, self.ack_timeout, "ack")
            if ack is None:
                return None
            if not ack.accepted:
                if (
                    ack.code is RejectCode.EPISODE_OVER
                ):  # the world ended as this robot planned; its event is on the way
                    self._over = True
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(self._done.wait(), self.final_result_grace)
                    return None
                if (
                    ack.code in OUT_OF_STEP and not self._done.is_set()
                ):  # planned on a tick that is not (or no longer) its own
                    self._log.info(
                        "request out of step, resynchronizing", reason=ack.reason, code=getattr(ack.code, "value", None)
                    )
                    return None
                raise AgentError(f"the world rejected {decision.action.call()}: {ack.reason}")
            return await self._await(req.goal_id, res_fut, self.result_timeout, "result")
        finally:
            self._acks.pop(req.goal_id, None)
            self._results.pop(req.goal_id, None)

    async def _await(self, goal_id: str, fut: asyncio.Future, timeout: float | None, what: str):  # type: ignore[no-untyped-def]
        """The ack or result of `goal_id`; None when the episode ended without executing it.

        Results and world events travel on different keys, so `episode_done` may overtake the
        last result: when the world says it executed this goal, the result is awaited still."""
        if await self._until_end(fut, timeout, f"its {what}"):
            return fut.result()
        return await self._await_final(goal_id, fut, what)

    async def _until_end(self, fut: asyncio.Future, timeout: float | None, what: str) -> bool:  # type: ignore[type-arg]
        """Wait for `fut` while watching the episode and the world: True when `fut` is done,
        False when the episode ended first; WorldGone when the world vanished or `timeout` passed."""
        done_wait = asyncio.ensure_future(self._done.wait())
        gone_wait = asyncio.ensure_future(self._world_gone.wait())
        try:
            finished, _ = await asyncio.wait(
                {fut, done_wait, gone_wait}, timeout=timeout, return_when=asyncio.FIRST_COMPLETED
            )
        finally:
            done_wait.cancel()
            gone_wait.cancel()
        if fut in finished:
            return True
        if done_wait in finished or self._done.is_set():  # an ended episode's world may be gone too: it ended
            return False
        if gone_wait in finished:
            raise _WorldLost(what)
        raise WorldGone(f"no {what.removeprefix('its ')} from the world within {timeout} s")

    async def _await_final(self, goal_id: str, fut: asyncio.Future, what: str):  # type: ignore[no-untyped-def]
        if self.episode is None or self.episode.final_results.get(self.robot) != goal_id:
            return None  # the world ended without executing this request
        try:
            return await asyncio.wait_for(asyncio.shield(fut), self.final_result_grace)
        except TimeoutError:
            self._log.warning("the world reported a final result that never arrived", goal=goal_id, what=what)
            return None

    async def _decide(self, obs: Observation) -> Decision:
        """The policy's decision; while a model call in it takes long, its progress goes out
        every GENERATING_EVERY seconds, so that a console shows a slow model as generating."""
        progress = Progress()
        token = PROGRESS.set(progress)  # the policy's model client, awaited in this task, fills it in
        ticker = asyncio.create_task(self._tell_progress(obs.tick, progress))
        try:
            return await self.policy.decide(obs)
        finally:
            PROGRESS.reset(token)
            ticker.cancel()  # not awaited: an await here could swallow a cancellation of this agent meant for it

    async def _tell_progress(self, tick: int, progress: Progress) -> None:
        while True:
            await asyncio.sleep(GENERATING_EVERY)
            if progress.attempt == 0:
                continue  # no model call (a heuristic or scripted policy), or none under way yet
            msg = Generating(
                robot=self.robot,
                tick=tick,
                elapsed=round(progress.elapsed(), 1),
                tokens=progress.tokens,
                attempt=progress.attempt,
            )
            self.bus.put(self.keys.generating(self.robot), msg)

    def _publish_thought(self, obs: Observation, d: Decision) -> None:
        self.bus.put(
            self.keys.thought(self.robot),
            Thought(
                robot=self.robot,
                tick=obs.tick,
                policy=fit(self.policy.name, MAX_LINE) or "",
                prompt=fit(d.prompt),
                reply=fit(d.reply),
                action=fit(d.action.call(), MAX_LINE),
                parse_error=fit(d.parse_error, MAX_LINE),
                failure=d.failure,
                prompt_tokens=d.prompt_tokens,
                completion_tokens=d.completion_tokens,
                latency=d.latency,
                reasoning=fit(d.reasoning),
                reasoning_tokens=d.reasoning_tokens,
                finish_reason=fit(d.finish_reason, MAX_LINE),
                schema_hash=fit(d.schema_hash, MAX_LINE),
                ttft=d.ttft,
                coordination=d.coordination,
            ),
        )
