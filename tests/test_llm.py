"""LLM clients and the LLM policy over a real HTTP server on loopback."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import pytest

from mhrc.agents.llm import LLMError, OpenAIChatClient, check_spec
from mhrc.episode import EpisodeConfig, up_in_process
from mhrc.trace import read_trace

Reply = tuple[int, dict[str, str], bytes, float]  # status, headers, body, delay


def ok(text: str, usage: bool = True) -> Reply:
    body: dict[str, Any] = {"choices": [{"message": {"role": "assistant", "content": text}}]}
    if usage:
        body["usage"] = {"prompt_tokens": 11, "completion_tokens": 7}
    return 200, {}, json.dumps(body).encode(), 0.0


class FakeServer:
    """An OpenAI-style endpoint whose answers come from `respond(request_json)`."""

    def __init__(self, respond: Callable[[dict[str, Any]], Reply]) -> None:
        self.respond = respond
        self.requests: list[tuple[dict[str, Any], dict[str, str]]] = []
        self.spans: list[tuple[str, int, int, float]] = []  # (first system line, start, end, scripted delay)
        self.seq = 0  # one count for every request start and end: their order, never their times
        self.in_flight = 0
        self.max_in_flight = 0
        self.lock = threading.Lock()
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                with server.lock:
                    server.seq += 1
                    start = server.seq
                    server.requests.append((body, dict(self.headers)))
                    server.in_flight += 1
                    server.max_in_flight = max(server.max_in_flight, server.in_flight)
                status, headers, payload, delay = server.respond(body)
                time.sleep(delay)
                with server.lock:
                    server.in_flight -= 1
                    server.seq += 1
                    server.spans.append((body["messages"][0]["content"].split("\n")[0], start, server.seq, delay))
                try:
                    self.send_response(status)
                    for k, v in headers.items():
                        self.send_header(k, v)
                    self.send_header("Content-Length", str(len(payload)))
                    self.end_headers()
                    self.wfile.write(payload)
                except (BrokenPipeError, ConnectionResetError):
                    pass

            def log_message(self, *args: object) -> None:
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def server_factory() -> Iterator[Callable[[Callable[[dict[str, Any]], Reply]], FakeServer]]:
    servers: list[FakeServer] = []

    def make(respond: Callable[[dict[str, Any]], Reply]) -> FakeServer:
        servers.append(FakeServer(respond))
        return servers[-1]

    yield make
    for s in servers:
        s.close()


async def test_transient_failures_are_retried_then_usage_recorded(server_factory) -> None:  # type: ignore[no-untyped-def]
    script = [
        (429, {"Retry-After": "0"}, b'{"error": "slow down"}', 0.0),
        (500, {}, b"oops", 0.0),
        (200, {}, b"{not json", 0.0),
        ok("slow", usage=True)[:3] + (2.0,),  # longer than the client's timeout
        ok("Command: wait()"),
    ]
    server = server_factory(lambda body: script.pop(0))
    client = OpenAIChatClient("m1", server.url, api_key="sekret", timeout=0.5, retries=5, backoff=0.01)
    try:
        c = await client.complete([{"role": "user", "content": "hi"}], temperature=0.5)
    finally:
        await client.aclose()
    assert c.text == "Command: wait()" and (c.prompt_tokens, c.completion_tokens) == (11, 7)
    assert len(server.requests) == 5 and script == []
    body, headers = server.requests[-1]
    assert body == {"model": "m1", "messages": [{"role": "user", "content": "hi"}], "temperature": 0.5, "max_tokens": 1024}
    assert headers["Authorization"] == "Bearer sekret"


async def test_the_retry_budget_ends_in_a_typed_error(server_factory) -> None:  # type: ignore[no-untyped-def]
    server = server_factory(lambda body: (503, {}, b"down", 0.0))
    client = OpenAIChatClient("m", server.url, retries=2, backoff=0.01)
    try:
        with pytest.raises(LLMError, match="after 3 attempts: HTTP 503"):
            await client.complete([{"role": "user", "content": "x"}])
    finally:
        await client.aclose()
    assert len(server.requests) == 3


async def test_a_client_error_is_not_retried(server_factory) -> None:  # type: ignore[no-untyped-def]
    server = server_factory(lambda body: (401, {}, b'{"error": "bad key"}', 0.0))
    client = OpenAIChatClient("m", server.url, retries=3, backoff=0.01)
    try:
        with pytest.raises(LLMError, match="401"):
            await client.complete([{"role": "user", "content": "x"}])
    finally:
        await client.aclose()
    assert len(server.requests) == 1


async def test_the_concurrency_limit_holds(server_factory) -> None:  # type: ignore[no-untyped-def]
    server = server_factory(lambda body: ok("Command: wait()")[:3] + (0.2,))
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


async def test_an_llm_episode_over_http_with_bad_replies_and_concurrent_planning(server_factory, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Three LLM agents against one scripted server: malformed replies, a 500 and a 429 along
    the way; the episode runs to its horizon, and the robots' calls overlap in time."""
    hiccups = {
        "bob": [(500, {}, b"boom", 0.0), (200, {}, b"not json at all", 0.0)],
        "alice": [(429, {"Retry-After": "0"}, b"", 0.0)],
        "david": [ok("Command: wait()")[:3] + (3.0,)],  # beyond the request timeout: retried
    }
    replies = {"bob": ["I am thinking about the tray.", "Command: pick(ghost)"], "alice": [], "david": ["Command: navigate(table_1, 0)"]}
    lock = threading.Lock()

    def respond(body: dict[str, Any]) -> Reply:
        robot = body["messages"][0]["content"].split()[2].rstrip(",").lower()  # "You are Alice, ..."
        with lock:
            if hiccups.get(robot):
                return hiccups[robot].pop(0)
            text = replies[robot].pop(0) if replies[robot] else "Analysis: nothing to do.\nCommand: wait()"
        return ok(text)[:3] + (0.3,)

    server = server_factory(respond)
    cfg = EpisodeConfig.build(
        seed=0, horizon=4, llm="openai:test-model", base_url=server.url, llm_timeout=1.0, trace=tmp_path / "t.jsonl"
    ).resolved()
    done = await up_in_process(cfg)
    assert done.reason == "horizon" and done.metrics.temporal_steps == 4
    assert done.metrics.failed_actions.get("pick") == 1  # pick(ghost) reached the world and failed there

    thoughts = [line["msg"] for line in read_trace(cfg.trace) if line["key"].endswith("/thought")]
    bob = [t for t in thoughts if t["robot"] == "bob"]
    assert bob[0]["parse_error"] and "no command" in bob[0]["parse_error"] and bob[0]["action"] == "wait()"
    assert "could not be executed" in bob[1]["prompt"]  # the format error came back as feedback
    assert all(t["policy"] == "llm:test-model" and t["prompt"] and t["prompt_tokens"] > 0 for t in thoughts)

    for robot, extra in (("David", 1), ("Bob", 2), ("Alice", 1)):  # each hiccup cost one retried request
        sent = sum(1 for body, _ in server.requests if body["messages"][0]["content"].startswith(f"You are {robot}"))
        assert sent == sum(1 for t in thoughts if t["robot"] == robot.lower()) + extra

    # planning overlapped: some answered call of each robot started before another robot's answered
    # call ended and ended after it started (the order of starts and ends, not their times)
    spans = [(who, s, e) for who, s, e, delay in server.spans if delay == 0.3]
    overlapping = {a for a, s1, e1 in spans for b, s2, e2 in spans if a != b and s1 < e2 and s2 < e1}
    assert len(overlapping) == 3, spans


async def test_replay_reproduces_a_recorded_episode_exactly(server_factory, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """An LLM episode recorded against the server, then replayed from its trace alone."""
    from mhrc.agents.replay import ReplayClient, ReplayMismatch

    def respond(body: dict[str, Any]) -> Reply:
        system, user = body["messages"][0]["content"], body["messages"][1]["content"]
        if system.startswith("You are Bob"):
            return ok("Command: pick(phone)" if "Gripper: empty" in user else "Command: place(phone, tray)")
        if system.startswith("You are Alice"):
            return ok("Analysis: look around.\nCommand: navigate(drawer_unit, 0)" if "drawer_unit" not in user.split("actions so far")[-1] else "Command: open(drawer_unit)")
        return ok("Command: navigate(sofa, 0)" if "sofa" not in user.split("actions so far")[-1] else "I should wait maybe?")

    server = server_factory(respond)
    recorded = EpisodeConfig.build(seed=0, horizon=5, llm="openai:m", base_url=server.url, trace=tmp_path / "rec.jsonl").resolved()
    first = await up_in_process(recorded)
    calls = len(server.requests)  # before the replay: it must add none
    replayed = EpisodeConfig.build(seed=0, horizon=5, llm=f"replay:{recorded.trace}", trace=tmp_path / "rep.jsonl").resolved()
    second = await up_in_process(replayed)

    def actions(path: Any) -> list[tuple[str, int, str]]:
        return sorted((l["msg"]["robot"], l["msg"]["tick"], l["msg"]["action"]["skill"]) for l in read_trace(path) if l["key"].endswith("/action/result"))

    assert first.metrics.model_dump(exclude={"wall_time"}) == second.metrics.model_dump(exclude={"wall_time"})
    assert actions(recorded.trace) == actions(replayed.trace)
    assert first.metrics.action_steps > 5 and calls > 0 and len(server.requests) == calls  # the replay asked the server nothing

    client = ReplayClient(recorded.trace, "bob")
    with pytest.raises(ReplayMismatch, match="differs"):
        await client.complete([{"role": "system", "content": "another prompt"}])
