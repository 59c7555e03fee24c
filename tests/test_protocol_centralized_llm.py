"""The LLM form of `centralized`: one model call per decision round naming one command per robot,
against the scripted model server (real HTTP on loopback), on real PyBullet and real Zenoh: a
command the planner cannot read becomes that robot's feedback while the others' still run."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest

from mhrc.agents.llm import OpenAIChatClient, model_spec
from mhrc.agents.protocols.centralized_llm import parse_round
from mhrc.core.protocol import ActionResult, Coordination, EpisodeDone, Navigate, Thought, Wait
from mhrc.core.protocol.thoughts import ReplyFailure
from mhrc.core.records import read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ModelReply, ScriptedModelServer

ROBOTS = ("alice", "bob", "david")


async def _episode(server: ScriptedModelServer, trace: Path, **options: object) -> EpisodeDone:
    """A centralized episode (the trio, bathroom, 3 objects, lockstep) whose planner asks `server`;
    the server is closed once it ends."""
    try:
        cfg = EpisodeConfig.build(
            protocol="centralized",
            task="pack_objects",
            scene="bathroom",
            seed=0,
            n_objects=3,
            schedule="lockstep",
            llm="openai:scripted",
            base_url=server.url,
            trace=trace,
            **options,
        )
        return await asyncio.wait_for(up_in_process(cfg.resolved()), 120)
    finally:
        server.close()


def test_a_reply_names_one_command_per_robot_and_a_bad_line_is_that_robots_problem() -> None:
    commands, problems = parse_round(
        "alice: navigate(table_1)\n- Bob: wait()\ndavid: fly(table_2)\nzed: wait()\nReasoning: look around.", ROBOTS
    )
    assert commands == {"alice": Navigate(target="table_1"), "bob": Wait()}
    assert set(problems) == {"david"} and "fly(table_2)" in problems["david"]
    _, missing = parse_round("alice: wait()", ROBOTS)
    assert set(missing) == {"bob", "david"}


async def test_one_model_call_per_round_and_an_unreadable_command_is_feedback(tmp_path: Path) -> None:
    replies = [
        "alice: navigate(table_1)\nbob: wait()\ndavid: fly(sofa)",  # david's cannot be read
        "alice: wait()\nbob: wait()\ndavid: navigate(sofa)",
        "alice: wait()\nbob: wait()\ndavid: wait()",
    ]
    server = ScriptedModelServer(replies, when_done=None)
    trace = tmp_path / "t.jsonl"
    done = await _episode(server, trace, horizon=3)
    assert done.reason == "horizon"
    assert len(server.requests) == 3  # one call per round (a tick), not one per robot
    results = [r.msg for r in read_records(trace) if isinstance(r.msg, ActionResult)]
    by_tick = {(m.tick, m.robot): m.action for m in results}
    assert by_tick[(0, "alice")] == Navigate(target="table_1")  # the readable commands ran
    assert by_tick[(0, "david")] == Wait()  # the unreadable one: david waited
    assert by_tick[(1, "david")] == Navigate(target="sofa")
    second = server.requests[1]["messages"][-1]["content"]
    assert "could not be read" in second and "fly(sofa)" in second  # ... and was told why
    for body in server.requests:  # every robot's observation in the one prompt
        prompt = body["messages"][-1]["content"]
        assert all(f"## {r}" in prompt for r in ROBOTS)
    # each robot's thought says what the planner allocated it (the report's coordination section)
    told = {(r.msg.tick, r.msg.robot): r.msg.coordination for r in read_records(trace) if isinstance(r.msg, Thought)}
    assert told[(0, "alice")] == Coordination(job="navigate(table_1, 0)", by="planner")
    assert told[(0, "bob")] == Coordination(job=None, by="planner")  # told to wait


def made_clients(monkeypatch: pytest.MonkeyPatch) -> list[OpenAIChatClient]:
    """The model clients the protocols make from now on (model_spec.make_client, real ones), in order."""
    made: list[OpenAIChatClient] = []
    make = model_spec.make_client

    def noted(*args: object, **kwargs: object) -> OpenAIChatClient:
        made.append(make(*args, **kwargs))  # type: ignore[arg-type]
        return made[-1]

    monkeypatch.setattr(model_spec, "make_client", noted)
    return made


async def test_with_structured_one_json_reply_names_each_robots_command_from_its_own_schema(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--structured: the request carries one schema with a command for each robot (each from that
    robot's own skills and scene graph); a robot's command the schema would refuse is its problem.
    The planner's one model client is closed once the episode is over."""
    made = made_clients(monkeypatch)
    replies = [
        json.dumps(
            {
                "analysis": "alice goes to the sink, bob waits, david flies",
                "commands": {
                    "alice": {"skill": "navigate", "furniture": "table_1", "stand_pose": 0},
                    "bob": {"skill": "wait"},
                    "david": {"skill": "fly"},
                },
            }
        ),
        '{"analysis": "nothing"}',  # no commands at all: every robot waits and is told why
    ]
    server = ScriptedModelServer(replies, when_done=None)
    trace = tmp_path / "t.jsonl"
    done = await _episode(server, trace, horizon=2, structured=True)
    assert done.reason == "horizon" and len(server.requests) == 2
    schema = server.requests[0]["response_format"]["json_schema"]["schema"]
    assert schema["properties"]["commands"]["required"] == list(ROBOTS)
    bob = schema["properties"]["commands"]["properties"]["bob"]["anyOf"]
    assert "navigate" not in {v["properties"]["skill"]["const"] for v in bob}  # bob's own skills: an arm
    results = {(r.msg.tick, r.msg.robot): r.msg.action for r in read_records(trace) if isinstance(r.msg, ActionResult)}
    assert results[(0, "alice")] == Navigate(target="table_1", stand_pose=0) and results[(0, "david")] == Wait()
    second = server.requests[1]["messages"][-1]["content"]
    assert "could not be read" in second and "fly" in second
    thoughts = [r.msg for r in read_records(trace) if isinstance(r.msg, Thought) and r.msg.reply is not None]
    assert thoughts and all(t.schema_hash for t in thoughts)
    assert len(made) == 1 and made[0].closed


async def test_a_planner_whose_model_does_not_answer_has_every_robot_wait_and_say_why(tmp_path: Path) -> None:
    """The model down (503 on every call, after the client's retries): the round is every robot's
    wait, each robot's thought carries the failure's code, and the episode goes on to its horizon."""
    server = ScriptedModelServer(
        lambda body: ModelReply(status=503, headers={"Retry-After": "0"}, body=b'{"error": "down"}'), when_done=None
    )
    trace = tmp_path / "t.jsonl"
    done = await _episode(server, trace, horizon=1)
    assert done.reason == "horizon"
    thoughts = [r.msg for r in read_records(trace) if isinstance(r.msg, Thought)]
    assert {t.robot for t in thoughts} == set(ROBOTS)
    assert all(t.failure is ReplyFailure.MODEL_UNREACHABLE and t.action == "wait()" for t in thoughts)
