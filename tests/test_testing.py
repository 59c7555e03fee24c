"""mhrc.testing, used exactly as a researcher would: the pytest plugin's fixtures (no import of
the project's own tests), a scripted robot among heuristic teammates, a scripted LLM robot
against a scripted model server, and a world with agents attached by hand."""

from __future__ import annotations

import asyncio
import time
from typing import Any

import httpx
import pytest

from mhrc.keys import Keys
from mhrc.protocol import EpisodeDone, decode_event
from mhrc.testing import ModelReply, ScriptedModelServer, ScriptedPolicy


def test_the_plugin_is_registered(pytestconfig: pytest.Config) -> None:
    assert pytestconfig.pluginmanager.hasplugin("mhrc")
    import mhrc.testing

    assert pytestconfig.pluginmanager.get_plugin("mhrc") is mhrc.testing


def test_a_scripted_policy_checks_its_commands_at_once() -> None:
    policy = ScriptedPolicy(["navigate(table_0, 0)", "Command: pick(apple)"])
    assert [a.call() for a in policy.actions] == ["navigate(table_0, 0)", "pick(apple)"] and policy.remaining == 2
    with pytest.raises(ValueError, match=r"scripted command 1 \('flyto\(moon\)'\)"):
        ScriptedPolicy(["wait()", "flyto(moon)"])


def test_the_model_server_answers_from_its_script_with_latency(mhrc_model_server: Any) -> None:
    server = mhrc_model_server(
        {"alice": ["Command: wait()", ModelReply(status=503, latency=0.0)]}, latency=0.2, when_done=None
    )
    ask = {"model": "m", "messages": [{"role": "system", "content": "You are Alice, a robot."}]}
    with httpx.Client() as http:
        started = time.monotonic()
        first = http.post(f"{server.url}/chat/completions", json=ask)
        assert time.monotonic() - started >= 0.2
        assert first.status_code == 200 and first.json()["choices"][0]["message"]["content"] == "Command: wait()"
        assert http.post(f"{server.url}/chat/completions", json=ask).status_code == 503
        assert http.post(f"{server.url}/chat/completions", json=ask).status_code == 500  # the script is exhausted
    assert server.requests == [ask] * 3 and server.paths == ["/v1/chat/completions"] * 3
    assert ScriptedModelServer.robot_of(ask) == "alice" and len(server.requests_of("alice")) == 3


async def test_a_scripted_robot_among_heuristic_teammates(mhrc_run_episode: Any) -> None:
    """David plays a script, Alice and Bob the heuristic policy (not named: their default)."""
    script = ["navigate(table_1, 0)", "navigate(table_0, 0)"]
    david = ScriptedPolicy(script)
    result = await mhrc_run_episode({"david": david}, seed=0, n_objects=3, horizon=30)
    assert result.done.reason in ("success", "horizon") and result.metrics.success == result.done.metrics.success
    assert [r.action.call() for r in david.results[:2]] == script
    assert all(r.action.call() == "wait()" for r in david.results[2:])
    assert [r["action"] for r in result.results("david")][:2] == [a.model_dump() for a in ScriptedPolicy(script).actions]
    assert {t["robot"] for t in result.thoughts()} == {"alice", "bob", "david"}
    assert {t["policy"] for t in result.thoughts("david")} == {"script"}
    assert result.trace.is_file() and result.metrics.temporal_steps == result.done.metrics.temporal_steps


async def test_a_scripted_llm_robot_whose_bad_reply_becomes_feedback(mhrc_model_server: Any, mhrc_run_episode: Any) -> None:
    """Bob on a model (the scripted server), Alice and David heuristic: Bob's first reply holds no
    command, so he waits and is told why; his second names an object that does not exist."""
    server = mhrc_model_server({"bob": ["I am thinking about the tray.", "Analysis: got it.\nCommand: pick(ghost)"]}, latency=0.05)
    result = await mhrc_run_episode({}, seed=0, horizon=3, llm="bob=openai:test", base_url=server.url)
    assert result.done.reason == "horizon" and result.metrics.temporal_steps == 3
    bob = result.thoughts("bob")
    assert bob[0]["parse_error"] and "no command" in bob[0]["parse_error"] and bob[0]["action"] == "wait()"
    assert "could not be executed" in bob[1]["prompt"]  # the format error came back as feedback
    assert bob[1]["action"] == "pick(ghost)" and result.done.metrics.failed_actions.get("pick") == 1
    assert all(t["policy"] == "llm:test" for t in bob) and len(server.requests_of("bob")) == len(bob) == len(server.requests)
    assert {t["policy"] for t in result.thoughts("alice") + result.thoughts("david")} == {"heuristic"}
    assert result.metrics.parse_failures == 1


async def test_a_world_with_agents_attached_by_hand(mhrc_world: Any) -> None:
    """Every robot waits, each on its own session; a session of our own sees the episode end."""
    async with mhrc_world(seed=0, horizon=2) as world:
        assert world.endpoint.startswith("tcp/127.0.0.1:") and world.config.horizon == 2
        events: list[EpisodeDone] = []
        bus = await world.client()
        bus.subscribe(Keys(world.run).world_event, lambda s: events.append(e) if isinstance(e := decode_event(s.payload), EpisodeDone) else None)
        policies = {robot: ScriptedPolicy([]) for robot in world.config.robots}
        tasks = [await world.agent(robot, policy) for robot, policy in policies.items()]
        done = await world.done()
        seen = await asyncio.wait_for(asyncio.gather(*tasks), 30)
    assert done.reason == "horizon" and done.metrics.temporal_steps == 2
    assert all(s is not None and s.reason == "horizon" for s in seen)
    assert all(len(p.results) == 2 and p.results[-1].done for p in policies.values())
    assert [e.reason for e in events] == ["horizon"] and world.trace.is_file()
