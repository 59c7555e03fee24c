"""The OpenAI-compatible client against a real HTTP server on 127.0.0.1 (`mhrc.testing.ScriptedModelServer`).

The server answers from a script: OpenAI-style JSON, a 429 with Retry-After, a 500, a reply
slower than the client's timeout, a malformed body. Nothing here needs an API key or a network
beyond loopback, and no assertion depends on how long anything took.
"""

from __future__ import annotations

import asyncio
import json
import re
import socket
import ssl
from collections.abc import Callable, Iterator, MutableMapping
from pathlib import Path
from typing import Any

import pytest
from structlog.testing import capture_logs

from mhrc.agents.llm import (
    GENERIC_KEY_ENV,
    LLMError,
    LLMFatalError,
    LLMSpecError,
    OpenAIChatClient,
    ScriptedClient,
    check_spec,
    estimate_tokens,
    make_client,
)
from mhrc.testing import ModelReply, Script, ScriptedModelServer

HI = [{"role": "system", "content": "You are a test."}, {"role": "user", "content": "Say something."}]


@pytest.fixture
def serve() -> Iterator[Callable[[Script], ScriptedModelServer]]:
    """Scripted servers that keep connections alive (HTTP/1.1, as real ones do) and answer HTTP
    500 once a list script is exhausted, so that an extra request shows; closed at teardown."""
    servers: list[ScriptedModelServer] = []

    def start(script: Script) -> ScriptedModelServer:
        servers.append(ScriptedModelServer(script, when_done=None, keep_alive=True))
        return servers[-1]

    yield start
    for s in servers:
        s.close()


@pytest.fixture(autouse=True)
def _no_keys(monkeypatch: pytest.MonkeyPatch) -> None:
    for var in ("OPENAI_API_KEY", GENERIC_KEY_ENV, "MY_LLM_KEY"):
        monkeypatch.delenv(var, raising=False)


def _delays(logs: list[MutableMapping[str, Any]]) -> list[float]:
    return [e["delay"] for e in logs if e["event"] == "llm call failed, retrying"]


async def test_every_transient_failure_is_retried_and_then_the_reply_comes_through(serve) -> None:  # type: ignore[no-untyped-def]
    server = serve(
        [
            ModelReply(status=429, headers={"Retry-After": "0.05"}, body=b'{"error": {"message": "rate limited"}}'),
            ModelReply(status=500, body=b"internal error"),
            ModelReply(
                "too late", usage={"prompt_tokens": 1, "completion_tokens": 1}, latency=5.0
            ),  # beyond the timeout
            ModelReply(body=b'{"choices": [{"message": '),  # malformed JSON
            ModelReply(body=b'{"choices": []}'),  # JSON, but no completion in it
            ModelReply("Command: wait()", usage={"prompt_tokens": 123, "completion_tokens": 45}),
        ]
    )
    client = OpenAIChatClient("test-model", server.url, api_key="k-123", timeout=0.5, retries=5, backoff=0.01)
    try:
        with capture_logs() as logs:
            c = await client.complete(HI, temperature=0.5)
    finally:
        await client.aclose()
    assert c.text == "Command: wait()"
    assert (c.prompt_tokens, c.completion_tokens) == (123, 45) == (client.prompt_tokens, client.completion_tokens)
    assert len(server.requests) == 6 == client.requests
    delays = _delays(logs)
    assert delays[0] == pytest.approx(0.05)  # Retry-After honoured
    assert delays[1:] == pytest.approx([0.02, 0.04, 0.08, 0.16])  # then exponential backoff
    errors = " | ".join(e["error"] for e in logs if e["event"] == "llm call failed, retrying")
    for reason in ("HTTP 429", "HTTP 500", "no answer within 0.5 s", "unreadable completion body"):
        assert reason in errors
    path, body, headers = server.paths[-1], server.requests[-1], server.headers[-1]
    assert path == "/v1/chat/completions"
    streamed = {"stream": True, "stream_options": {"include_usage": True}}  # the default: replies are streamed
    assert body == {"model": "test-model", "messages": HI, "temperature": 0.5, "max_tokens": 1024} | streamed
    assert headers["Authorization"] == "Bearer k-123"


async def test_the_retry_budget_ends_in_a_typed_error(serve) -> None:  # type: ignore[no-untyped-def]
    server = serve(lambda body: ModelReply(status=503, headers={"Retry-After": "0"}, body=b"overloaded"))
    async with OpenAIChatClient("m", server.url, retries=2, backoff=0.01) as client:
        with pytest.raises(
            LLMError, match=r"m at http://127\.0\.0\.1:\d+/v1 failed after 3 attempts: HTTP 503: overloaded"
        ):
            await client.complete(HI)
    assert len(server.requests) == 3


async def test_a_server_that_is_not_there_is_retried_then_reported() -> None:
    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    async with OpenAIChatClient("m", f"http://127.0.0.1:{port}/v1", retries=2, backoff=0.01) as client:
        with capture_logs() as logs, pytest.raises(LLMError, match="failed after 3 attempts: ConnectError"):
            await client.complete(HI)
    assert len(_delays(logs)) == 2 and client.requests == 3


REPLY = json.dumps(
    {"choices": [{"message": {"content": "wait()"}, "finish_reason": "stop"}], "usage": {"prompt_tokens": 9}}
).encode()


async def _one_reply_each(tls: ssl.SSLContext | None = None) -> tuple[asyncio.Server, list[tuple[bytes, bytes]]]:
    """A real server on 127.0.0.1 (over TLS with `tls`) that answers every request with one whole
    completion and closes; the list gets each request's head and body as they come."""
    seen: list[tuple[bytes, bytes]] = []

    async def answer(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        head = await reader.readuntil(b"\r\n\r\n")
        length = int(re.search(rb"(?i)content-length: *(\d+)", head)[1])  # type: ignore[index]
        seen.append((head, await reader.readexactly(length)))
        writer.write(b"HTTP/1.1 200 OK\r\ncontent-type: application/json\r\nconnection: close\r\n")
        writer.write(b"content-length: %d\r\n\r\n" % len(REPLY) + REPLY)
        await writer.drain()
        writer.close()

    return await asyncio.start_server(answer, "127.0.0.1", 0, ssl=tls), seen


async def test_a_model_server_behind_tls_answers_over_a_trusted_context_and_an_untrusted_one_is_refused(
    tmp_path: Path,
) -> None:
    """HTTPS as a hosted API serves it, from a real TLS server on 127.0.0.1 whose certificate a
    CA of the test's signs: a client trusting that CA gets its reply over the aiohttp transport;
    the default client, which trusts the public CAs only, is refused, the certificate named."""
    from mhrc.agents.llm.transport import AiohttpTransport
    from mhrc.core.certs import make_ca, make_server_cert, pem_cert, pem_key

    ca, ca_key = make_ca("tls-test", days=1)
    cert, key = make_server_cert(ca, ca_key, days=1)
    (tmp_path / "ca.pem").write_bytes(pem_cert(ca))
    (tmp_path / "server.pem").write_bytes(pem_cert(cert))
    (tmp_path / "server.key").write_bytes(pem_key(key))
    served = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    served.load_cert_chain(tmp_path / "server.pem", tmp_path / "server.key")
    server, seen = await _one_reply_each(served)
    url = f"https://127.0.0.1:{server.sockets[0].getsockname()[1]}/v1"
    try:
        trusting = ssl.create_default_context(cafile=tmp_path / "ca.pem")
        async with OpenAIChatClient("m", url, stream=False, transport=AiohttpTransport(trusting)) as client:
            got = await client.complete(HI)
        assert got.text == "wait()" and json.loads(seen[0][1])["messages"] == HI
        async with OpenAIChatClient("m", url, stream=False, retries=0) as client:
            with pytest.raises(LLMError, match="ConnectError: .*certificate verify failed"):
                await client.complete(HI)
        assert len(seen) == 1  # the refused client sent nothing
    finally:
        server.close()
        await server.wait_closed()


async def test_a_proxy_the_environment_names_carries_the_calls(monkeypatch: pytest.MonkeyPatch) -> None:
    """HTTP_PROXY names a proxy (here a real one on 127.0.0.1 that answers itself): the call goes
    to it, in a proxy's absolute form, and never to the model's own address (where nothing listens)."""
    proxy, seen = await _one_reply_each()
    for var in ("NO_PROXY", "no_proxy", "ALL_PROXY", "all_proxy", "HTTPS_PROXY", "https_proxy"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("HTTP_PROXY", f"http://127.0.0.1:{proxy.sockets[0].getsockname()[1]}")
    with socket.socket() as s:  # the model's address: a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    try:
        async with OpenAIChatClient("m", f"http://127.0.0.1:{port}/v1", stream=False, retries=0) as client:
            got = await client.complete(HI)
    finally:
        proxy.close()
        await proxy.wait_closed()
    assert got.text == "wait()"
    assert seen[0][0].startswith(f"POST http://127.0.0.1:{port}/v1/chat/completions HTTP/1.1".encode())


@pytest.mark.parametrize(
    ("status", "fatal", "match"),
    [
        (401, True, "refused the credentials .HTTP 401.: check the API key .*invalid api key"),
        (403, True, "refused the credentials .HTTP 403."),
        (404, True, "HTTP 404: no model 'm'"),
        (400, False, "HTTP 400 .not retried.: .*invalid api key"),
    ],
)
async def test_a_client_error_is_reported_at_once(serve, status: int, fatal: bool, match: str) -> None:  # type: ignore[no-untyped-def]
    """Nothing a retry can fix is retried; what no later step can fix either is fatal."""
    server = serve(lambda body: ModelReply(status=status, body=b'{"error": "invalid api key"}'))
    async with OpenAIChatClient("m", server.url, retries=3, backoff=0.01) as client:
        with pytest.raises(LLMError, match=match) as err:
            await client.complete(HI)
    assert isinstance(err.value, LLMFatalError) is fatal
    assert len(server.requests) == 1


async def test_usage_is_estimated_when_the_server_reports_none(serve) -> None:  # type: ignore[no-untyped-def]
    reply = "Analysis: the tray is empty.\nCommand: pick(apple)"
    server = serve([ModelReply(reply, usage=False)])
    async with OpenAIChatClient("m", server.url) as client:
        c = await client.complete(HI, temperature=0.2)
    prompt = "You are a test.\n\nSay something."
    assert (
        (c.prompt_tokens, c.completion_tokens)
        == (estimate_tokens(prompt), estimate_tokens(reply))
        == (len(prompt) // 4, len(reply) // 4)
    )
    assert server.requests[0]["temperature"] == 0.2 and "Authorization" not in server.headers[0]


async def test_the_concurrency_limit_is_shared_by_all_calls_of_a_client(serve) -> None:  # type: ignore[no-untyped-def]
    server = serve(lambda body: ModelReply("Command: wait()", latency=0.15))
    async with OpenAIChatClient("m", server.url, max_concurrency=2) as client:
        replies = await asyncio.gather(*(client.complete([{"role": "user", "content": str(i)}]) for i in range(6)))
    assert len(replies) == 6 and len(server.requests) == 6
    assert server.max_in_flight == 2


async def test_make_client_takes_the_key_from_the_named_variable_or_the_generic_one(
    serve, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    server = serve(["Command: wait()"] * 3)
    monkeypatch.setenv("MY_LLM_KEY", "from-my-var")
    monkeypatch.setenv(GENERIC_KEY_ENV, "from-generic")
    for spec, kw, key, model in (
        ("openai:gpt-4o", {"api_key_env": "MY_LLM_KEY"}, "from-my-var", "gpt-4o"),
        ("vllm:Qwen/Qwen2.5-7B-Instruct", {}, "from-generic", "Qwen/Qwen2.5-7B-Instruct"),
        ("qwen2.5:7b", {}, "from-generic", "qwen2.5:7b"),  # no known provider: with a base URL the spec is the model
    ):
        client = make_client(spec, base_url=server.url, max_tokens=64, **kw)
        try:
            await client.complete(HI)
        finally:
            await client.aclose()
        body, headers = server.requests[-1], server.headers[-1]
        assert headers["Authorization"] == f"Bearer {key}"
        assert body["model"] == model and body["max_tokens"] == 64


def test_specs_are_checked_before_any_request(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(LLMSpecError, match="OPENAI_API_KEY") as missing:
        make_client("openai:gpt-4o")
    assert "openai:gpt-4o" in str(missing.value) and GENERIC_KEY_ENV in str(missing.value)
    with pytest.raises(LLMSpecError, match="unknown LLM provider 'acme' in LLM spec 'acme:m1'"):
        make_client("acme:m1")
    with pytest.raises(LLMSpecError, match="'gpt4' must look like provider:model"):
        make_client("gpt4")
    with pytest.raises(ValueError, match="names no model"):
        check_spec("ollama:")
    assert check_spec("ollama:llama3.1:8b") == ("llama3.1:8b", "http://127.0.0.1:11434/v1", None)
    assert check_spec("vllm:m")[1] == "http://127.0.0.1:8000/v1"
    assert check_spec("lmstudio:m")[1] == "http://127.0.0.1:1234/v1"
    assert check_spec("llamacpp:m")[1] == "http://127.0.0.1:8080/v1"
    assert check_spec("openai:m", "http://127.0.0.1:9/v1") == (
        "m",
        "http://127.0.0.1:9/v1",
        None,
    )  # a local server needs no key
    monkeypatch.setenv("OPENAI_API_KEY", "sk-test")
    client = make_client("openai:gpt-4o")
    assert client.base_url == "https://api.openai.com/v1" and client.model == "gpt-4o"  # built, never called


async def test_the_scripted_client_replies_in_order_then_waits() -> None:
    down = LLMError("model down")
    client = ScriptedClient(["Command: pick(apple)", down], latency=0.01)
    assert (await client.complete(HI)).text == "Command: pick(apple)"
    with pytest.raises(LLMError, match="model down"):
        await client.complete(HI)
    assert (await client.complete(HI)).text == ScriptedClient.EXHAUSTED
    assert client.calls == 3 and client.prompts[0] == HI

    echo = ScriptedClient(lambda messages: f"Command: communicate({messages[-1]['content']!r}, bob)")
    c = await echo.complete(HI)
    assert c.text == "Command: communicate('Say something.', bob)" and c.completion_tokens == len(c.text) // 4
