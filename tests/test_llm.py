"""LLM clients and the LLM policy over a real HTTP server on loopback."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from mhrc.agents.llm import LLMError, OpenAIChatClient, check_spec
from mhrc.core.protocol import ActionResult, Thought
from mhrc.core.records import messages, read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ModelReply

USAGE = {"prompt_tokens": 11, "completion_tokens": 7}


async def test_transient_failures_are_retried_then_usage_recorded(mhrc_model_server) -> None:  # type: ignore[no-untyped-def]
    server = mhrc_model_server(
        [
            ModelReply(status=429, headers={"Retry-After": "0"}, body=b'{"error": "slow down"}'),
            ModelReply(status=500, body=b"oops"),
            ModelReply(body=b"{not json"),
            ModelReply("slow", usage=USAGE, latency=2.0),  # longer than the client's timeout
            ModelReply("Command: wait()", usage=USAGE),
        ],
        when_done=None,
    )
    client = OpenAIChatClient("m1", server.url, api_key="sekret", timeout=0.5, retries=5, backoff=0.01)
    try:
        c = await client.complete([{"role": "user", "content": "hi"}], temperature=0.5)
    finally:
        await client.aclose()
    assert c.text == "Command: wait()" and (c.prompt_tokens, c.completion_tokens) == (11, 7)
    assert len(server.requests) == 5 and server.remaining() == 0
    body, headers = server.requests[-1], server.headers[-1]
    streamed = {"stream": True, "stream_options": {"include_usage": True}}  # the default: replies are streamed
    assert (
        body
        == {"model": "m1", "messages": [{"role": "user", "content": "hi"}], "temperature": 0.5, "max_tokens": 1024}
        | streamed
    )
    assert headers["Authorization"] == "Bearer sekret"


async def test_the_retry_budget_ends_in_a_typed_error(mhrc_model_server) -> None:  # type: ignore[no-untyped-def]
    server = mhrc_model_server(lambda body: ModelReply(status=503, body=b"down"))
    client = OpenAIChatClient("m", server.url, retries=2, backoff=0.01)
    try:
        with pytest.raises(LLMError, match="after 3 attempts: HTTP 503"):
            await client.complete([{"role": "user", "content": "x"}])
    finally:
        await client.aclose()
    assert len(server.requests) == 3


async def test_a_client_error_is_not_retried(mhrc_model_server) -> None:  # type: ignore[no-untyped-def]
    server = mhrc_model_server(lambda body: ModelReply(status=401, body=b'{"error": "bad key"}'))
    client = OpenAIChatClient("m", server.url, retries=3, backoff=0.01)
    try:
        with pytest.raises(LLMError, match="401"):
            await client.complete([{"role": "user", "content": "x"}])
    finally:
        await client.aclose()
    assert len(server.requests) == 1


async def test_the_concurrency_limit_holds(mhrc_model_server) -> None:  # type: ignore[no-untyped-def]
    server = mhrc_model_server(lambda body: "Command: wait()", latency=0.2)
    client = OpenAIChatClient("m", server.url, max_concurrency=2)
    try:
        await asyncio.gather(*(client.complete([{"role": "user", "content": str(i)}]) for i in range(6)))
    finally:
        await client.aclose()
    assert server.max_in_flight == 2


def test_specs_are_checked_before_any_request(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.delenv("MHRC_API_KEY", raising=False)
    with pytest.raises(ValueError, match="OPENAI_API_KEY"):
        check_spec("openai:gpt-4o")
    with pytest.raises(ValueError, match="unknown LLM provider"):
        check_spec("acme:m1")
    assert check_spec("ollama:llama3.1:8b") == ("llama3.1:8b", "http://127.0.0.1:11434/v1", None)
    assert check_spec("openai:m", "http://127.0.0.1:9/v1")[1] == "http://127.0.0.1:9/v1"


async def test_an_llm_episode_over_http_with_bad_replies_and_concurrent_planning(mhrc_model_server, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Three LLM agents against one scripted server: malformed replies, a 500 and a 429 along
    the way; the episode runs to its horizon, and the robots' calls overlap in time."""
    script = {  # each robot's hiccups (answered at once), then its replies (0.3 s each), then waits
        "bob": [
            ModelReply(status=500, body=b"boom", latency=0.0),
            ModelReply(body=b"not json at all", latency=0.0),
            "I am thinking about the tray.",
            "Command: pick(ghost)",
        ],
        "alice": [ModelReply(status=429, headers={"Retry-After": "0"}, body=b"", latency=0.0)],
        "david": [
            ModelReply("Command: wait()", latency=3.0),
            "Command: navigate(table_1, 0)",
        ],  # beyond the request timeout: retried
    }
    server = mhrc_model_server(script, latency=0.3, when_done="Analysis: nothing to do.\nCommand: wait()")
    cfg = EpisodeConfig.build(
        seed=0, horizon=4, llm="openai:test-model", base_url=server.url, llm_timeout=1.0, trace=tmp_path / "t.jsonl"
    ).resolved()
    done = await up_in_process(cfg)
    assert done.reason == "horizon" and done.metrics.temporal_steps == 4
    assert done.metrics.failed_actions.get("pick") == 1  # pick(ghost) reached the world and failed there

    thoughts = messages(read_records(cfg.trace), Thought)
    bob = [t for t in thoughts if t.robot == "bob"]
    assert bob[0].parse_error and "no command" in bob[0].parse_error and bob[0].action == "wait()"
    assert "Your command could not be read, so you waited." in bob[1].prompt  # the format error came back as feedback
    assert all(t.policy == "llm:test-model" and t.prompt and t.prompt_tokens > 0 for t in thoughts)

    for robot, extra in (("David", 1), ("Bob", 2), ("Alice", 1)):  # each hiccup cost one retried request
        sent = sum(1 for body in server.requests if body["messages"][0]["content"].startswith(f"You are {robot}"))
        assert sent == sum(1 for t in thoughts if t.robot == robot.lower()) + extra

    # planning overlapped: some answered call of each robot started before another robot's answered
    # call ended and ended after it started (the order of starts and ends, not their times)
    spans = [(call.robot, call.started, call.ended) for call in server.calls if call.latency == 0.3]
    assert all(e is not None for _, _, e in spans)
    overlapping = {a for a, s1, e1 in spans for b, s2, e2 in spans if a != b and s1 < e2 and s2 < e1}
    assert len(overlapping) == 3, spans


async def test_replay_reproduces_a_recorded_episode_exactly(mhrc_model_server, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """An LLM episode recorded against the server, then replayed from its trace alone."""
    from mhrc.agents.replay import ReplayClient, ReplayMismatch

    def respond(body: dict[str, Any]) -> str:
        system, user = body["messages"][0]["content"], body["messages"][1]["content"]
        if system.startswith("You are Bob"):
            return "Command: pick(phone)" if "Gripper: empty" in user else "Command: place(phone, tray)"
        if system.startswith("You are Alice"):
            return (
                "Analysis: look around.\nCommand: navigate(drawer_unit, 0)"
                if "drawer_unit" not in user.split("actions so far")[-1]
                else "Command: open(drawer_unit)"
            )
        return (
            "Command: navigate(sofa, 0)" if "sofa" not in user.split("actions so far")[-1] else "I should wait maybe?"
        )

    server = mhrc_model_server(respond)
    recorded = EpisodeConfig.build(
        seed=0, horizon=5, llm="openai:m", base_url=server.url, trace=tmp_path / "rec.jsonl"
    ).resolved()
    first = await up_in_process(recorded)
    calls = len(server.requests)  # before the replay: it must add none
    replayed = EpisodeConfig.build(
        seed=0, horizon=5, llm=f"replay:{recorded.trace}", trace=tmp_path / "rep.jsonl"
    ).resolved()
    second = await up_in_process(replayed)

    def actions(path: Any) -> list[tuple[str, int, str]]:
        return sorted((m.robot, m.tick, m.action.skill) for m in messages(read_records(path), ActionResult))

    assert first.metrics.model_dump(exclude={"wall_time"}) == second.metrics.model_dump(exclude={"wall_time"})
    assert actions(recorded.trace) == actions(replayed.trace)
    assert (
        first.metrics.action_steps > 5 and calls > 0 and len(server.requests) == calls
    )  # the replay asked the server nothing

    client = ReplayClient(recorded.trace, "bob")
    with pytest.raises(ReplayMismatch, match="differs"):
        await client.complete([{"role": "system", "content": "another prompt"}])
