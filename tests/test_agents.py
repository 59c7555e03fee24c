"""The agent loop with a scripted stand-in for the model's judgement, over the real world."""

from __future__ import annotations

import asyncio
import contextlib

import pytest
from waits import served, subscribed, until

from mhrc.agents.agent import AttachRejected, RobotAgent, WorldGone
from mhrc.agents.llm_policy import UNREADABLE
from mhrc.agents.scripted import ScriptedLLMPolicy
from mhrc.core.bus import Bus, Sample
from mhrc.core.endpoints import endpoint, free_port
from mhrc.core.keys import Keys
from mhrc.core.protocol import (
    ActionAck,
    ActionRequest,
    ActionResult,
    AttachReply,
    EpisodeDone,
    Metrics,
    Observation,
    OutcomeCode,
    RobotStatus,
    SkillOutcome,
    Thought,
    decode,
)
from mhrc.core.protocol.thoughts import ReplyFailure
from mhrc.core.records import messages, read_records


async def test_scripted_replies_drive_a_robot_and_bad_replies_become_feedback(mhrc_world) -> None:  # type: ignore[no-untyped-def]
    async with mhrc_world(seed=0, horizon=3, start_timeout=3.0) as world:
        bus = await world.client()
        try:
            policy = ScriptedLLMPolicy(
                "bob", ["I am not sure what to do.", "**Command:** pick(ghost).", "Command: wait()"]
            )
            agent = RobotAgent(bus, policy, run=world.config.run, robot="bob")
            done = await asyncio.wait_for(agent.run(), 60)
        finally:
            await bus.close()
        await world.done()
    assert done is not None and done.reason == "horizon" and done.metrics.temporal_steps == 3
    assert [r.action.call() for r in policy.results] == ["wait()", "pick(ghost)", "wait()"]
    assert policy.results[1].outcome.code == OutcomeCode.OBJECT_UNKNOWN
    assert policy.format_feedback == [UNREADABLE]  # the paper's feedback: only that the command could not be read
    thoughts = [t for t in messages(read_records(world.config.trace), Thought) if t.robot == "bob"]
    assert [t.parse_error is not None for t in thoughts] == [True, False, False]
    assert thoughts[0].failure is ReplyFailure.UNREADABLE and "no command found" in (thoughts[0].parse_error or "")
    assert thoughts[0].reply == "I am not sure what to do."


async def test_a_second_agent_for_an_attached_robot_is_refused(mhrc_world) -> None:  # type: ignore[no-untyped-def]
    async with mhrc_world(seed=0) as world:
        first, second = await world.client(), await world.client()
        try:
            a = asyncio.create_task(
                RobotAgent(first, ScriptedLLMPolicy("bob", []), run=world.config.run, robot="bob").run()
            )
            await world.attached("bob")
            with pytest.raises(AttachRejected, match="already attached"):
                await RobotAgent(second, ScriptedLLMPolicy("bob", []), run=world.config.run, robot="bob").run()
            a.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await a
        finally:
            await first.close()
            await second.close()


class _OvertakingWorld:
    """A world that publishes `episode_done` before the result of the last tick, on purpose:
    results and events travel on different keys, so a real world's may arrive in that order."""

    def __init__(self, bus: Bus, run: str, *, name_final_result: bool) -> None:
        self.bus, self.keys, self.name_final_result = bus, Keys(run), name_final_result
        self.release_result = asyncio.Event()  # the test sets it once the agent has seen episode_done
        self.sent_result = asyncio.Event()

    def start(self) -> None:
        self.bus.serve(self.keys.attach("bob"), self._attach)
        self.bus.subscribe(self.keys.action_request("bob"), self._request)
        self.bus.declare_token(self.keys.alive_world)

    def _observation(self) -> Observation:
        status = RobotStatus(name="bob", kind="arm", skills=["pick", "place", "communicate", "wait"])
        return Observation(
            robot="bob", tick=0, status=status, furniture=[], objects=[], task_brief="b", task_detail="d"
        )

    async def _attach(self, key: str, params: dict[str, str], payload: bytes) -> AttachReply:
        return AttachReply(robot="bob", accepted=True, tick=0, horizon=1, observation=self._observation())

    async def _request(self, sample: Sample) -> None:
        req = decode(sample.payload, ActionRequest)
        self.bus.put(self.keys.action_ack("bob"), ActionAck(goal_id=req.goal_id, robot="bob", accepted=True))
        metrics = Metrics(
            success=False,
            partial_success=0.0,
            placed=0,
            total=1,
            temporal_steps=1,
            action_steps=0,
            action_steps_per_robot={"bob": 0},
        )
        final = {"bob": req.goal_id} if self.name_final_result else {}
        self.bus.put(
            self.keys.world_event,
            EpisodeDone(run=self.keys.run, reason="horizon", metrics=metrics, final_results=final),
        )
        await self.release_result.wait()  # the result arrives after the agent has seen the event
        result = ActionResult(
            goal_id=req.goal_id,
            robot="bob",
            tick=0,
            action=req.action,
            outcome=SkillOutcome.ok("You waited."),
            observation=self._observation(),
            done=True,
        )
        self.bus.put(self.keys.action_result("bob"), result)
        self.sent_result.set()


@pytest.mark.parametrize("named", [True, False])
async def test_a_result_overtaken_by_episode_done_is_still_recorded_when_the_world_names_it(named: bool) -> None:
    port = free_port()
    world_bus = await Bus.open(mode="router", listen=[endpoint("127.0.0.1", port)])
    agent_bus = await Bus.open(mode="client", connect=[endpoint("127.0.0.1", port)])
    running: asyncio.Future[EpisodeDone | None] | None = None
    try:
        world = _OvertakingWorld(world_bus, "overtake", name_final_result=named)
        world.start()
        await served(agent_bus, world.keys.attach("bob"))  # the world's declarations reached the agent's session
        await subscribed(agent_bus, world.keys.action_request("bob"))
        policy = ScriptedLLMPolicy("bob", ["Command: wait()"])
        agent = RobotAgent(agent_bus, policy, run="overtake", robot="bob")
        running = asyncio.ensure_future(agent.run())
        await until(lambda: agent.episode is not None or running.done(), "the agent seeing episode_done")
        if named:  # the world said it executed the request: the agent waits for its result, sent only now
            assert not running.done()
            world.release_result.set()
            done = await asyncio.wait_for(running, 30)
            assert [r.action.call() for r in policy.results] == ["wait()"] and world.sent_result.is_set()
        else:  # the world ended without executing it: the agent ends without a result, which was never sent
            done = await asyncio.wait_for(running, 30)
            assert policy.results == [] and not world.sent_result.is_set()
            world.release_result.set()  # the world's handler ends before its bus closes
            await asyncio.wait_for(world.sent_result.wait(), 30)
        assert done is not None and done.reason == "horizon"
    finally:
        if running is not None and not running.done():
            running.cancel()
        await agent_bus.close()
        await world_bus.close()


async def test_an_agent_declares_its_liveliness_token_before_it_attaches() -> None:
    """Issue 31: the world's deadline for an agent's token starts at its attach, so the token must
    exist by then, whatever the machine's load: a world asks the router for it inside its attach
    handler and finds it. A refused agent withdraws its token (it must not stand for a robot
    another agent drives): the world's liveliness subscriber sees it go."""
    port = free_port()
    world_bus = await Bus.open(mode="router", listen=[endpoint("127.0.0.1", port)])
    agent_bus = await Bus.open(mode="client", connect=[endpoint("127.0.0.1", port)])
    try:
        keys = Keys("tokenfirst")
        token = keys.alive_robot("bob")
        at_attach: list[list[str]] = []
        gone = asyncio.Event()

        async def on_attach(key: str, params: dict[str, str], payload: bytes) -> AttachReply:
            at_attach.append(await world_bus.alive(token))  # the router's tokens as the attach query arrives
            return AttachReply(robot="bob", accepted=False, reason="a world that only looks")

        world_bus.serve(keys.attach("bob"), on_attach)
        world_bus.watch_liveliness(token, lambda s: None if s.is_put else gone.set())
        await served(agent_bus, keys.attach("bob"))
        with pytest.raises(AttachRejected, match="only looks"):
            await asyncio.wait_for(
                RobotAgent(agent_bus, ScriptedLLMPolicy("bob", []), run="tokenfirst", robot="bob").run(), 30
            )
        assert at_attach == [[token]], "the agent's token did not exist when its attach reached the world"
        await asyncio.wait_for(gone.wait(), 10)  # withdrawn on the refusal, while the agent's session stays open
    finally:
        await agent_bus.close()
        await world_bus.close()


async def test_an_agent_whose_world_vanishes_before_answering_its_attach_fails_fast() -> None:
    """The world's token goes away while the agent's attach is unanswered (a world killed as it
    attached the robot; a robot's token no longer says its agent holds its reply, since agents
    declare it before attaching): the agent probes the world's port, finds nothing, and ends with
    WorldGone, as it does when the world vanishes during any other exchange, instead of asking
    until its attach timeout."""
    port = free_port()
    world_bus = await Bus.open(mode="router", listen=[endpoint("127.0.0.1", port)])
    agent_bus = await Bus.open(mode="client", connect=[endpoint("127.0.0.1", port)])
    keys = Keys("vanishing")
    asked, release = asyncio.Event(), asyncio.Event()

    async def on_attach(key: str, params: dict[str, str], payload: bytes) -> None:
        asked.set()
        await release.wait()  # never answered while the world lives

    agent = None
    try:
        world_bus.serve(keys.attach("bob"), on_attach)
        world_bus.declare_token(keys.alive_world)
        await served(agent_bus, keys.attach("bob"))
        robot = RobotAgent(agent_bus, ScriptedLLMPolicy("bob", []), run="vanishing", robot="bob", attach_timeout=120)
        agent = asyncio.create_task(robot.run())
        await asyncio.wait_for(asked.wait(), 30)
        await world_bus.close()  # the world and its port go
        with pytest.raises(WorldGone, match="awaited its attach reply"):
            await asyncio.wait_for(agent, 60)  # far sooner than the attach timeout
    finally:
        release.set()
        if agent is not None and not agent.done():
            agent.cancel()
            with contextlib.suppress(asyncio.CancelledError, WorldGone):
                await agent
        await agent_bus.close()
        await world_bus.close()
