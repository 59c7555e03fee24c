"""The agent loop with a scripted stand-in for the model's judgement, over the real world."""

from __future__ import annotations

import asyncio
import contextlib

import pytest

from mhrc.agents.agent import AttachRejected, RobotAgent
from mhrc.agents.scripted import ScriptedPolicy
from mhrc.protocol import OutcomeCode
from mhrc.trace import read_trace


async def test_scripted_replies_drive_a_robot_and_bad_replies_become_feedback(world_factory) -> None:  # type: ignore[no-untyped-def]
    async with world_factory(seed=0, horizon=3, start_timeout=0.5) as world:
        bus = await world.client()
        try:
            policy = ScriptedPolicy("bob", ["I am not sure what to do.", "**Command:** pick(ghost).", "Command: wait()"])
            agent = RobotAgent(bus, policy, run=world.cfg.run, robot="bob")
            done = await asyncio.wait_for(agent.run(), 60)
        finally:
            await bus.close()
        await world.task
    assert done is not None and done.reason == "horizon" and done.metrics.temporal_steps == 3
    assert [r.action.call() for r in policy.results] == ["wait()", "pick(ghost)", "wait()"]
    assert policy.results[1].outcome.code == OutcomeCode.OBJECT_UNKNOWN
    assert policy.format_feedback and "no command found" in policy.format_feedback[0]
    thoughts = [line["msg"] for line in read_trace(world.cfg.trace) if line["key"].endswith("/agent/bob/thought")]
    assert [t["parse_error"] is not None for t in thoughts] == [True, False, False]
    assert thoughts[0]["reply"] == "I am not sure what to do."


async def test_a_second_agent_for_an_attached_robot_is_refused(world_factory) -> None:  # type: ignore[no-untyped-def]
    async with world_factory(seed=0) as world:
        first, second = await world.client(), await world.client()
        try:
            a = asyncio.create_task(RobotAgent(first, ScriptedPolicy("bob", []), run=world.cfg.run, robot="bob").run())
            await asyncio.sleep(1.5)
            with pytest.raises(AttachRejected, match="already attached"):
                await RobotAgent(second, ScriptedPolicy("bob", []), run=world.cfg.run, robot="bob").run()
            a.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await a
        finally:
            await first.close()
            await second.close()
