"""Streamed model calls (issue 22, "slow is not down"), over real HTTP on loopback.

Against scripted servers (`mhrc.testing.ScriptedModelServer` writing server-sent events): a
reply put together from its chunks, reasoning deltas and `<think>` split across chunks, usage in
the last chunk or missing, a stream that stalls mid-reply (the idle timeout), a reply that keeps
producing tokens for longer than the first-token timeout (never cut by it), a server that
answers a stream request with a whole JSON body, and `--no-stream`. Against a socket that
accepts connections and never writes: fatal at a robot's first step, like a refused
connection. Against llama.cpp's own server (slow): an abandoned stream frees its slot at once.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from waits import until

from mhrc.agents.llm import LLMSilent, LLMTimeout, OpenAIChatClient, make_client
from mhrc.agents.llm_policy import LLMPolicy, LLMUnreachable
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ModelReply, ScriptedModelServer

HI = [{"role": "system", "content": "You are a test."}, {"role": "user", "content": "Say something."}]
SSE = {"Content-Type": "text/event-stream"}


def chunk(
    content: str | None = None,
    *,
    reasoning: str | None = None,
    field: str = "reasoning_content",
    finish: str | None = None,
) -> dict[str, Any]:
    delta: dict[str, Any] = {}
    if content is not None:
        delta["content"] = content
    if reasoning is not None:
        delta[field] = reasoning
    return {
        "id": "chatcmpl-1",
        "object": "chat.completion.chunk",
        "choices": [{"index": 0, "delta": delta, "finish_reason": finish}],
    }


def events(*chunks: dict[str, Any], done: bool = True) -> list[bytes]:
    """The chunks as server-sent events, one write each, ending in `data: [DONE]`."""
    out = [f"data: {json.dumps(c)}\n\n".encode() for c in chunks]
    return out + ([b"data: [DONE]\n\n"] if done else [])


def usage(prompt: int, completion: int) -> dict[str, Any]:
    return {
        "id": "chatcmpl-1",
        "object": "chat.completion.chunk",
        "choices": [],
        "usage": {"prompt_tokens": prompt, "completion_tokens": completion},
    }


@pytest.fixture
def serve() -> Iterator[Any]:
    servers: list[ScriptedModelServer] = []

    def start(script: Any, **kwargs: Any) -> ScriptedModelServer:
        servers.append(ScriptedModelServer(script, when_done=None, **kwargs))
        return servers[-1]

    yield start
    for s in servers:
        s.close()


# -- scripted streams ----------------------------------------------------------------------------


async def test_a_streamed_reply_is_put_together_from_its_chunks_with_usage_from_the_last(serve) -> None:  # type: ignore[no-untyped-def]
    parts = ["Analysis: ", "the tray ", "is empty.", "\nCommand: ", "wait()"]
    stream = events(chunk(""), *(chunk(p) for p in parts), chunk(finish="stop"), usage(321, 12))
    server = serve([ModelReply(headers=SSE, stream=stream)])
    async with OpenAIChatClient("m", server.url) as client:
        c = await client.complete(HI)
    assert c.text == "Analysis: the tray is empty.\nCommand: wait()"
    assert (c.prompt_tokens, c.completion_tokens, c.finish_reason) == (321, 12, "stop")
    body = server.requests[0]
    assert body["stream"] is True and body["stream_options"] == {"include_usage": True}


@pytest.mark.parametrize("field", ["reasoning_content", "reasoning"])
async def test_reasoning_deltas_and_a_think_block_split_across_chunks_stay_out_of_the_answer(serve, field: str) -> None:  # type: ignore[no-untyped-def]
    stream = events(
        chunk(reasoning="I could ", field=field),
        chunk(reasoning="pick(apple).", field=field),
        chunk("<thi"),
        chunk("nk>Or navigate(sofa, 0)? Command: pick(x)</th"),
        chunk("ink>\nCommand: "),
        chunk("wait()", finish="stop"),
    )
    server = serve([ModelReply(headers=SSE, stream=stream)])
    async with OpenAIChatClient("m", server.url) as client:
        c = await client.complete(HI)
    assert c.text.strip() == "Command: wait()"
    assert (
        c.reasoning is not None
        and c.reasoning.startswith("I could pick(apple).")
        and "Or navigate(sofa, 0)?" in c.reasoning
    )
    assert c.reasoning_tokens > 0


async def test_a_stream_without_usage_or_done_is_estimated_and_keeps_its_finish_reason(serve) -> None:  # type: ignore[no-untyped-def]
    text = "Analysis: " + "x" * 400
    stream = events(chunk(text[:200]), chunk(text[200:], finish="length"), done=False)  # ends with the connection
    server = serve([ModelReply(headers=SSE, stream=stream)])
    async with OpenAIChatClient("m", server.url) as client:
        c = await client.complete(HI)
    assert c.text == text and c.finish_reason == "length"
    assert c.completion_tokens == len(text) // 4 and c.prompt_tokens > 0


async def test_a_stream_that_stalls_mid_reply_is_abandoned_after_the_idle_timeout_and_retried(serve) -> None:  # type: ignore[no-untyped-def]
    """The first token came, then nothing: the idle timeout (not the first-token timeout, which
    is far longer here) ends the call; it is retried once, then reported as a stall."""
    stalled = events(chunk("Analysis: I am "), chunk("thinking"), done=False)
    server = serve(
        lambda body: ModelReply(headers=SSE, stream=stalled, stall=True)
    )  # then no more until the test is over
    async with OpenAIChatClient("m", server.url, timeout=60, idle_timeout=0.3, backoff=0.01) as client:
        with pytest.raises(
            LLMTimeout, match=r"the stream stalled: no chunk for 0\.3 s after 2 chunk\(s\), 2 time\(s\)"
        ) as err:
            await client.complete(HI)
    assert not isinstance(err.value, LLMSilent)  # it answered: slow, not down
    assert len(server.requests) == 2


async def test_a_reply_that_keeps_producing_tokens_is_not_cut_by_the_first_token_timeout(serve) -> None:  # type: ignore[no-untyped-def]
    """Twelve chunks 0.25 s apart take about 3 s, longer than the 1 s to the first token: the
    stream is never cut while it produces (the old total timeout cut it)."""
    words = [f"w{i} " for i in range(11)]
    stream = events(*(chunk(w) for w in words), chunk("Command: wait()", finish="stop"), done=False)
    server = serve([ModelReply(headers=SSE, stream=stream, stream_interval=0.25)])
    async with OpenAIChatClient("m", server.url, timeout=1.0, idle_timeout=30, timeout_retries=0) as client:
        c = await client.complete(HI)
    assert c.text == "".join(words) + "Command: wait()"
    assert len(server.requests) == 1
    assert c.ttft is not None and 0 < c.ttft < c.latency  # the first token came well before the reply's end


async def test_a_finished_stream_leaves_its_connection_open_for_the_next_call(serve) -> None:  # type: ignore[no-untyped-def]
    """A stream read to its end (past `[DONE]`) gives its connection back to the pool: the next
    call goes out on it instead of opening another (a client that stopped reading at `[DONE]`
    hung up on every call)."""
    reply = lambda _body: ModelReply(headers=SSE, stream=events(chunk("Command: wait()", finish="stop"), usage(5, 3)))  # noqa: E731
    server = serve(reply, keep_alive=True)
    async with OpenAIChatClient("m", server.url) as client:
        for _ in range(3):
            assert (await client.complete(HI)).text == "Command: wait()"
    assert [call.connection for call in server.calls] == [1, 1, 1]


async def test_a_whole_json_body_or_a_mislabelled_stream_answers_a_stream_request(serve) -> None:  # type: ignore[no-untyped-def]
    """Some proxies answer `"stream": true` with a plain completion, or send events as JSON."""
    mislabelled = events(chunk("Command: "), chunk("wait()", finish="stop"), usage(7, 3))
    server = serve(
        [
            ModelReply("Command: wait()", usage={"prompt_tokens": 9, "completion_tokens": 4}),
            ModelReply(stream=mislabelled),
        ]
    )  # fmt: skip  (the server's own Content-Type: application/json)
    async with OpenAIChatClient("m", server.url) as client:
        whole = await client.complete(HI)
        events_as_json = await client.complete(HI)
    assert (whole.text, whole.prompt_tokens, whole.completion_tokens) == ("Command: wait()", 9, 4)
    assert (events_as_json.text, events_as_json.prompt_tokens, events_as_json.completion_tokens) == (
        "Command: wait()",
        7,
        3,
    )
    assert all(body["stream"] is True for body in server.requests)


async def test_an_error_event_in_the_stream_is_retried_as_unreadable(serve) -> None:  # type: ignore[no-untyped-def]
    bad = [b'data: {"error": {"message": "the slot was lost"}}\n\n']
    server = serve(
        [
            ModelReply(headers=SSE, stream=bad),
            ModelReply(headers=SSE, stream=events(chunk("Command: wait()", finish="stop"))),
        ]
    )
    async with OpenAIChatClient("m", server.url, backoff=0.01) as client:
        c = await client.complete(HI)
    assert c.text == "Command: wait()" and len(server.requests) == 2


async def test_no_stream_sends_plain_requests_and_every_option_reaches_the_client(serve) -> None:  # type: ignore[no-untyped-def]
    server = serve(["Command: wait()"])
    cfg = EpisodeConfig.build(llm="openai:m", base_url=server.url, stream=False, llm_idle_timeout=4.0, llm_timeout=3.0)
    options = cfg.client_options("openai:m")
    assert (options["stream"], options["idle_timeout"], options["timeout"]) == (False, 4.0, 3.0)
    assert EpisodeConfig.build(llm="openai:m", base_url=server.url).client_options("openai:m")["stream"] is True
    async with make_client("openai:m", server.url, **options) as client:
        assert (await client.complete(HI)).text == "Command: wait()"
    assert "stream" not in server.requests[0] and "stream_options" not in server.requests[0]


# -- a server that accepts and never answers --------------------------------------------------------


@pytest.fixture
def mute(serve) -> str:  # type: ignore[no-untyped-def]
    """The base URL of a server that reads each request and never sends a status line (its
    latency outlasts the test; closing the server at teardown ends it). Its path is its own: a
    client remembers, process-wide, the base URLs that ever answered (a port reused from an
    earlier test's server must not count); the scripted server answers on any path."""
    server = serve(lambda body: "Command: wait()", latency=3600.0)
    return f"http://127.0.0.1:{server.port}/mute-{uuid.uuid4().hex[:8]}/v1"


async def test_a_server_that_never_sends_a_status_line_is_silent_and_stops_a_first_step(mute: str) -> None:
    client = OpenAIChatClient("m", mute, timeout=0.3, backoff=0.01)
    try:
        with pytest.raises(LLMSilent, match="no status line"):
            await client.complete(HI)
        assert (
            client.requests == 2 and client.responses == 0 and not client.answered
        )  # the call and one retry of its timeout
        with pytest.raises(LLMUnreachable, match="never answered during its first step: .*no status line"):
            await LLMPolicy("alice", client).decide(_obs())
    finally:
        await client.aclose()


async def test_a_server_that_answered_before_and_then_goes_mute_only_costs_steps(serve) -> None:  # type: ignore[no-untyped-def]
    def respond(body: dict[str, Any]) -> ModelReply:  # one answer, then no status line, ever
        return ModelReply("Command: wait()") if len(server.requests) == 1 else ModelReply("too late", latency=3600.0)

    server = serve(respond)
    async with OpenAIChatClient("m", server.url, timeout=0.3, backoff=0.01) as client:
        policy = LLMPolicy("alice", client)
        await policy.decide(_obs(0))
        d = await policy.decide(_obs(1))
    assert d.action.skill == "wait" and d.parse_error is not None and "no answer within 0.3 s" in d.parse_error


@pytest.mark.slow
async def test_up_against_a_server_that_never_answers_is_one_line_exit_2(mute: str, tmp_path: Path) -> None:
    """Before: the run went on to its horizon, "it waits" every tick, exit 0."""
    cfg = EpisodeConfig.build(
        seed=0, horizon=50, llm="openai:m", base_url=mute, llm_timeout=0.5, trace=tmp_path / "t.jsonl"
    ).resolved()
    with pytest.raises(LLMUnreachable, match="never answered during its first step"):
        await up_in_process(cfg)
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "mhrc",
            "up",
            "--insecure",
            "--quiet",
            "--horizon",
            "50",
            "--llm",
            "openai:m",
            "--base-url",
            mute,
            "--llm-timeout",
            "0.5",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=240,
        env=env,
    )
    assert run.returncode == 2, (run.returncode, run.stderr[-3000:])
    errors = [line for line in run.stderr.splitlines() if line.startswith("mhrc up: ")]
    assert len(errors) == 1 and "never answered during its first step" in errors[0] and "no status line" in errors[0], (
        run.stderr
    )
    assert "Traceback" not in run.stderr


def test_bad_timeouts_are_refused_naming_the_option(tmp_path: Path) -> None:
    from click.testing import CliRunner

    from mhrc.cli import main

    for args in (
        ["--llm-timeout", "0"],
        ["--llm-timeout", "-1"],
        ["--llm-idle-timeout", "0"],
        ["--step-deadline", "0"],
        ["--step-deadline", "30"],
        ["--step-deadline", "10", "--llm-timeout", "20"],
    ):
        for command in ("up", "agent"):
            where = (
                ["--trace", str(tmp_path / "t.jsonl")]
                if command == "up"
                else ["--robot", "alice", "--connect", "tcp/127.0.0.1:9", "--run", "r1", "--insecure"]
            )
            result = CliRunner().invoke(
                main, [command, "--llm", "openai:m", "--base-url", "http://127.0.0.1:9/v1", *where, *args]
            )
            assert result.exit_code == 2 and f"{args[0]}: " in result.output, (command, args, result.output)
        if (
            args[0] == "--step-deadline" and args[1] != "0"
        ):  # shorter than the first-token timeout (the default 120 s, or the one given)
            assert "shorter than the first-token timeout" in result.output, result.output
    assert not (tmp_path / "t.jsonl").exists()
    assert (
        EpisodeConfig.build(llm="openai:m", base_url="http://127.0.0.1:9/v1", step_deadline=120.0).step_deadline
        == 120.0
    )  # as long is fine


async def test_a_long_call_shows_at_the_console_as_reading_then_generating_and_stays_out_of_the_trace(
    serve, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """Alice's model takes a while to its first token (the prompt), then streams slowly: the
    console says so while it runs (not "unavailable", not silence), before her result; the
    trace keeps the thought, with its time to the first token, and not the live status."""
    import io
    import re

    from rich.console import Console

    from mhrc.agents import agent as agent_module
    from mhrc.core.protocol import Thought
    from mhrc.core.records import read_records
    from mhrc.run.console import ProgressPrinter

    monkeypatch.setattr(agent_module, "GENERATING_EVERY", 0.2)
    words = [f"w{i} " for i in range(14)]
    stream = events(*(chunk(w) for w in words), chunk("Command: wait()", finish="stop"), usage(900, 15))
    server = serve({"alice": [ModelReply(headers=SSE, stream=stream, stream_interval=0.1, latency=0.7)]})
    out = io.StringIO()
    printer = ProgressPrinter(Console(file=out, width=300, highlight=False, soft_wrap=True))
    cfg = EpisodeConfig.build(
        seed=0, horizon=1, llm="alice=openai:m", base_url=server.url, trace=tmp_path / "t.jsonl"
    ).resolved()
    await up_in_process(cfg, observe=printer.attach)
    printer.close()
    lines = out.getvalue().splitlines()
    reading = [i for i, line in enumerate(lines) if re.search(r"alice waiting for the model's first token", line)]
    generating = [
        (i, int(m.group(1)))
        for i, line in enumerate(lines)
        if (m := re.search(r"alice generating \((\d+) tokens so far\)", line))
    ]
    result = next(i for i, line in enumerate(lines) if re.match(r"tick +0 +alice wait\(\)", line))
    assert reading and generating, lines
    assert max(reading) < min(i for i, _ in generating) and max(i for i, _ in generating) < result
    counts = [n for _, n in generating]
    assert counts == sorted(counts) and 0 < counts[-1] <= len(words) + 1
    assert not any("unavailable" in line for line in lines)
    trace = read_records(cfg.trace)
    assert not any(line.key.endswith("/generating") for line in trace)
    thought = next(line.msg for line in trace if line.key.endswith("/agent/alice/thought"))
    assert isinstance(thought, Thought) and thought.ttft is not None and 0.5 < thought.ttft < thought.latency


def _obs(tick: int = 0) -> Any:
    from test_llm_policy import obs  # Alice in a small house, hand-built

    return obs(tick)


# -- llama.cpp's own server (slow) ------------------------------------------------------------------


@pytest.mark.slow
async def test_an_abandoned_call_frees_llama_cpps_slot_at_once_on_a_busy_server(gemma: Path) -> None:
    """Two slots: a neighbour streams a long reply (another robot), and our long generation (up to
    1500 tokens) is abandoned the way a step deadline, Ctrl-C or the episode's end abandon it. A
    1-token request then answers while the neighbour still decodes, so it took our freed slot:
    the server's count of finished tokens is our abandoned few plus one, not a whole 1500-token
    reply it would have had to wait for. Not streamed (the old client, or --no-stream), llama.cpp
    decodes the abandoned reply on to max_tokens while another slot is busy: measured here, its
    check for a closed connection waits for a second without results, which a busy neighbour's
    tokens never leave it."""
    import httpx

    from mhrc.agents.llm.local import LocalModelServer

    long = 1500
    prompt = [{"role": "user", "content": "Count to ten thousand:"}]
    async with LocalModelServer(gemma, slots=2, n_ctx_per_slot=2048, seed=1) as srv:
        async with httpx.AsyncClient(base_url=srv.base_url.removesuffix("/v1"), timeout=300) as admin:
            neighbour = asyncio.create_task(
                _stream(
                    admin,
                    {"model": srv.model, "messages": prompt, "max_tokens": long, "ignore_eos": True, "stream": True},
                )
            )
            try:
                await until(lambda: _decoding_at_least(admin, 1), "the neighbour decoding", 300, every=0.02)
                async with OpenAIChatClient(
                    srv.model, srv.base_url, max_tokens=long, timeout=300, extra_body={"ignore_eos": True}
                ) as client:
                    call = asyncio.create_task(client.complete(prompt))
                    await until(lambda: _decoding_at_least(admin, 2), "ours decoding too", 300, every=0.02)
                    call.cancel()
                    with pytest.raises(asyncio.CancelledError):
                        await call
                    async with OpenAIChatClient(srv.model, srv.base_url, max_tokens=1, timeout=300) as one:
                        await one.complete([{"role": "user", "content": "Hi"}])
                    decoded = await _tokens_decoded(admin)
                assert not neighbour.done()  # the server was busy all along
            finally:
                neighbour.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await neighbour
    assert decoded < long, f"the abandoned generation was decoded on ({decoded} tokens finished)"


COUNT = [{"role": "user", "content": "Count to ten thousand:"}]
LONG = 1500  # tokens of a reply nobody waits for: about a minute of decoding on this machine's CPU


@pytest.mark.slow
async def test_a_step_deadline_ends_a_long_generation_and_leaves_llama_cpp_idle(gemma: Path) -> None:
    """One slot. The robot's step deadline passes while its model decodes a long reply: the
    robot waits that step, and the server stops decoding at once: a 1-token request answers from
    the only slot without waiting out the abandoned reply (the server finished only the few
    tokens decoded before the deadline, plus one)."""
    import httpx

    from mhrc.agents.llm.local import LocalModelServer

    async with LocalModelServer(gemma, slots=1, n_ctx_per_slot=2048, seed=1) as srv:
        async with httpx.AsyncClient(base_url=srv.base_url.removesuffix("/v1"), timeout=300) as admin:
            client = OpenAIChatClient(
                srv.model, srv.base_url, max_tokens=LONG, timeout=5, extra_body={"ignore_eos": True}
            )
            policy = LLMPolicy("alice", client, step_deadline=6.0)
            policy.render = lambda obs: COUNT  # type: ignore[method-assign]  (a short prompt: the deadline falls in the decoding)
            async with client:
                decision = await policy.decide(_obs())
            assert decision.action.skill == "wait" and "step deadline of 6 s" in (decision.parse_error or "")
            async with OpenAIChatClient(srv.model, srv.base_url, max_tokens=1, timeout=300) as one:
                await one.complete([{"role": "user", "content": "Hi"}])
            decoded = await _tokens_decoded(admin)
            assert await _decoding(admin) == 0
    assert 0 < decoded < LONG, f"the abandoned generation was decoded on ({decoded} tokens finished)"


@pytest.mark.slow
async def test_a_retry_does_not_wait_behind_its_abandoned_predecessor(gemma: Path) -> None:
    """One slot, and an idle timeout so short that every attempt stalls a few tokens in: the call
    is tried twice, and the retry got tokens of its own (it stalled, it did not time out waiting
    for the slot) while the server decoded neither attempt on (far fewer tokens finished than
    one whole reply)."""
    import httpx

    from mhrc.agents.llm.local import LocalModelServer

    async with LocalModelServer(gemma, slots=1, n_ctx_per_slot=2048, seed=1) as srv:
        async with httpx.AsyncClient(base_url=srv.base_url.removesuffix("/v1"), timeout=300) as admin:
            async with OpenAIChatClient(
                srv.model,
                srv.base_url,
                max_tokens=LONG,
                timeout=300,
                idle_timeout=0.005,
                backoff=0.01,
                extra_body={"ignore_eos": True},
            ) as client:
                with pytest.raises(LLMTimeout, match=r"the stream stalled: .* 2 time\(s\)"):
                    await client.complete(COUNT)
                assert client.requests == 2
            decoded = await _tokens_decoded(admin)
    assert 0 < decoded < LONG, f"an abandoned attempt was decoded on ({decoded} tokens finished)"


async def _stream(http: Any, body: dict[str, Any]) -> None:
    async with http.stream("POST", "/v1/chat/completions", json=body) as resp:
        async for _ in resp.aiter_lines():
            pass


async def _decoding_at_least(admin: Any, n: int) -> bool:
    return await _decoding(admin) >= n


async def _decoding(admin: Any) -> int:
    """Slots generating tokens now."""
    slots = (await admin.get("/slots")).raise_for_status().json()
    return sum(
        bool(slot.get("is_processing") and (slot.get("next_token") or [{}])[0].get("n_decoded", 0) > 0)
        for slot in slots
    )


async def _tokens_decoded(admin: Any) -> int:
    """Tokens of the replies the server finished, in all (its /metrics)."""
    text = (await admin.get("/metrics")).raise_for_status().text
    for line in text.splitlines():
        if line.startswith("llamacpp:tokens_predicted_total"):
            return int(float(line.split()[-1]))
    raise AssertionError(f"no tokens_predicted_total in /metrics: {text[:500]}")


async def test_a_stream_that_never_ends_is_read_no_further_than_its_bound(serve) -> None:  # type: ignore[no-untyped-def]
    """A server that streams tokens forever, fast: the client stops reading (and hangs up) once
    the reply is far past any max_tokens, and keeps a bounded reply."""
    from mhrc.agents.llm import MAX_REPLY_CHARS, MAX_STREAM_CHARS

    piece = events(chunk("x" * 10_000), done=False)[0]
    server = serve([ModelReply(headers=SSE, stream=itertools.repeat(piece))])
    async with OpenAIChatClient("m", server.url, timeout=60) as client:
        c = await client.complete(HI)
    assert c.truncated and len(c.text) < MAX_REPLY_CHARS + 100 and c.completion_tokens > MAX_STREAM_CHARS // 4


async def test_a_server_that_answered_an_earlier_client_is_slow_not_down(serve) -> None:  # type: ignore[no-untyped-def]
    """An evaluation's next episode has new clients: a server that answered this process before
    and is silent now costs that episode its steps, it does not stop the evaluation."""

    def respond(body: dict[str, Any]) -> ModelReply:  # one answer, then no status line, ever
        return ModelReply("Command: wait()") if len(server.requests) == 1 else ModelReply("too late", latency=3600.0)

    server = serve(respond)
    async with OpenAIChatClient("m", server.url) as earlier:
        await earlier.complete(HI)
    async with OpenAIChatClient("m", server.url, timeout=0.3, backoff=0.01) as client:
        d = await LLMPolicy("alice", client).decide(_obs(0))
    assert d.action.skill == "wait" and d.parse_error is not None and "no answer within 0.3 s" in d.parse_error
