"""LLM clients: OpenAI-compatible chat completions over httpx, and a scripted stand-in.

A model spec names the provider and the model: `openai:gpt-4o`, `ollama:llama3.1:8b`,
`vllm:MODEL`, `lmstudio:MODEL`, `llamacpp:MODEL`. With an explicit `base_url` the request goes
to that server, and a spec without a known provider is the model name itself (`qwen2.5:7b`). The API
key comes from the provider's variable (OPENAI_API_KEY for openai), from `api_key_env` if
given, else from MHRC_API_KEY.

Every call is bounded: `max_tokens` (default 1024) and, where given, `seed` go in every request.
Replies are streamed (`"stream": true`, usage asked for in the stream) unless `stream=False`, and
timed by what matters: `timeout` is the time to the first token (prompt processing included:
the first `data:` event of the stream, or for a reply that comes whole, a server that does not
stream or `stream=False`, the whole reply), then `idle_timeout` between chunks; a reply that keeps
producing tokens is never cut by a total timeout, only by `max_tokens` (and a caller's deadline).
A call abandoned for any reason (a timeout, the caller's cancellation) closes its connection, so
that the server stops decoding it (llama.cpp frees the slot) and a retry never queues behind it.
Transient failures (429, 5xx, refused connections, unreadable bodies) are retried with
exponential backoff, honouring Retry-After, a bounded number of times; a timeout is retried at
most once (a server that did not answer in time will rarely answer the same request faster);
then LLMError. An answer that no retry can fix (401/403 bad credentials, 404 no such model or
endpoint, 400 for a JSON-schema response format the server does not take) raises LLMFatalError
at once: the run must stop, not wait out its horizon.

A reply is kept to MAX_REPLY_CHARS; reasoning models' thoughts (a `reasoning_content` or
`reasoning` field, or `<think>...</think>` in the text) are split off into `Completion.reasoning`
so that they never reach the command parser.
"""

from __future__ import annotations

import asyncio
import email.utils
import functools
import json
import os
import ssl
import re
import time
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, Self

import httpx
import structlog

from .progress import PROGRESS, Progress

log = structlog.get_logger("mhrc.llm")

Messages = list[dict[str, str]]

# provider -> (default base URL, environment variable holding the API key, or None)
# `replay:TRACE` is not a provider: mhrc.agents.replay builds one client per robot from a trace.
PROVIDERS: dict[str, tuple[str, str | None]] = {
    "openai": ("https://api.openai.com/v1", "OPENAI_API_KEY"),
    "ollama": ("http://127.0.0.1:11434/v1", None),
    "vllm": ("http://127.0.0.1:8000/v1", None),
    "lmstudio": ("http://127.0.0.1:1234/v1", None),
    "llamacpp": ("http://127.0.0.1:8080/v1", None),
}
GENERIC_KEY_ENV = "MHRC_API_KEY"
DEFAULT_TEMPERATURE = 0.5  # the paper's
DEFAULT_MAX_TOKENS = 1024  # the paper's reply format (analysis, reasoning, one command) with room to think
DEFAULT_TIMEOUT = 120.0  # s to the first token (mhrc.run.episode.SERVER_TIMEOUT says why)
DEFAULT_IDLE_TIMEOUT = 30.0  # s between two chunks of a streamed reply: a decoding server sends one every few tokens
MAX_REPLY_CHARS = 16_000  # what a reply may feed into the trace and the parser (about 4x DEFAULT_MAX_TOKENS tokens)
MAX_STREAM_CHARS = 1_000_000  # a streamed reply is read no further (a server that never stops): far beyond any max_tokens
MAX_STREAM_CHUNKS = 200_000  # nor past this many chunks (a server that streams empty deltas forever)


class LLMError(RuntimeError):
    """The model could not be reached, or answered unusably, after the retries."""


class LLMFatalError(LLMError):
    """An answer no retry or later step will change (bad credentials, no such model, a request
    the server refuses): the run stops with this message instead of burning its horizon."""


class LLMTimeout(LLMError):
    """The model did not answer in time (slow or endless generation), as opposed to a server that is down."""


class LLMSilent(LLMTimeout):
    """The server accepted the connection but sent nothing, not even a status line, on every
    attempt, and never answered this process before: from a robot's first step, as good as down."""


_ANSWERED: set[str] = set()  # base URLs that sent this process a status line: slow from then on, never down


class LLMSpecError(ValueError):
    """A model spec that names no usable server (unknown provider, missing API key)."""


@dataclass(frozen=True)
class Completion:
    text: str  # the answer without any reasoning block, at most MAX_REPLY_CHARS
    prompt_tokens: int
    completion_tokens: int
    latency: float  # seconds, the successful attempt only
    finish_reason: str | None = None  # "stop", "length" (cut at max_tokens), ...
    reasoning: str | None = None  # a reasoning model's thoughts, apart from the answer
    reasoning_tokens: int = 0
    truncated: bool = False  # the text was longer than MAX_REPLY_CHARS and was cut
    ttft: float | None = None  # seconds to the first chunk of a streamed reply (prompt processing, mostly); None: not streamed


class LLMClient(Protocol):
    """Anything that answers a chat: the policies need nothing more.

    `schema`, when given, is a JSON Schema the reply must follow (structured decisions)."""

    model: str

    async def complete(
        self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE, schema: dict[str, Any] | None = None
    ) -> Completion: ...


THINK = re.compile(r"<think>(.*?)(?:</think>|\Z)", re.DOTALL | re.IGNORECASE)


def split_reasoning(text: str, reasoning: str | None = None) -> tuple[str, str | None]:
    """(answer, reasoning): `<think>` blocks leave the answer; an unclosed one (a reply cut
    while thinking) takes the rest of the text with it; a closing tag without an opening one
    (chat templates that open the block in the prompt) ends a thought that began the reply.
    A separate reasoning field comes first."""
    thoughts = [reasoning] if reasoning else []
    lowered = text.lower()
    if "</think>" in lowered and "<think>" not in lowered:
        cut = lowered.index("</think>")
        thoughts.append(text[:cut].strip())
        text = text[cut + len("</think>") :]
    thoughts += [m.group(1).strip() for m in THINK.finditer(text)]
    answer = THINK.sub("", text).strip() if THINK.search(text) else text
    return answer, ("\n\n".join(t for t in thoughts if t) or None)


def bounded(text: str, limit: int = MAX_REPLY_CHARS) -> tuple[str, bool]:
    """`text` cut to `limit` characters with a note saying so, and whether it was cut."""
    if len(text) <= limit:
        return text, False
    return text[:limit] + f"\n[... {len(text) - limit} more characters cut by mhrc]", True


def estimate_tokens(text: str) -> int:
    """About four characters a token: for servers that report no usage."""
    return max(1, len(text) // 4)


def prompt_text(messages: Messages) -> str:
    """The messages' contents as one text: what a Thought records and a replay compares."""
    return "\n\n".join(m.get("content", "") for m in messages)


class OpenAIChatClient:
    """POST {base_url}/chat/completions, streamed, with retries, first-token and idle timeouts and a concurrency limit."""

    RETRY_STATUS = frozenset({408, 409, 425, 429, 500, 502, 503, 504})

    def __init__(
        self,
        model: str,
        base_url: str,
        *,
        api_key: str | None = None,
        timeout: float = DEFAULT_TIMEOUT,
        idle_timeout: float = DEFAULT_IDLE_TIMEOUT,
        stream: bool = True,
        retries: int = 4,
        backoff: float = 0.5,
        max_backoff: float = 30.0,
        max_concurrency: int = 4,
        max_tokens: int | None = DEFAULT_MAX_TOKENS,
        seed: int | None = None,
        provider: str = "",
        timeout_retries: int = 1,
        extra_body: dict[str, Any] | None = None,
        transport: httpx.AsyncBaseTransport | None = None,
    ) -> None:
        if retries < 0 or timeout <= 0 or idle_timeout <= 0 or max_concurrency < 1 or timeout_retries < 0:
            raise ValueError("need retries >= 0, timeout_retries >= 0, timeout > 0, idle_timeout > 0 and max_concurrency >= 1")
        if max_tokens is not None and max_tokens < 1:
            raise ValueError(f"max_tokens must be at least 1 (got {max_tokens})")
        self.model = model
        self.base_url = base_url.rstrip("/")
        self.provider = provider
        self.timeout = timeout  # s to the first token (or to a whole reply that is not streamed)
        self.idle_timeout = idle_timeout  # s between chunks of a streamed reply
        self.stream = stream
        self.retries = retries
        self.timeout_retries = timeout_retries
        self.backoff = backoff
        self.max_backoff = max_backoff
        self.max_tokens = max_tokens
        self.seed = seed
        self.extra_body = dict(extra_body or {})
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        # the deadlines of a call are this client's own (asyncio), not httpx's per-read timeout
        self._http = httpx.AsyncClient(timeout=httpx.Timeout(None, connect=timeout), headers=headers, transport=transport, verify=_tls())
        self._limit = asyncio.Semaphore(max_concurrency)
        self.requests = 0  # HTTP attempts, retries included
        self.responses = 0  # status lines received: 0 means the server never answered at all
        self.prompt_tokens = 0  # totals over successful calls
        self.completion_tokens = 0

    @property
    def answered(self) -> bool:
        """Whether the server ever sent a status line to this process (to any client, e.g. in an
        evaluation's earlier episode): a server that answered before and stalls now is slow, not down."""
        return self.responses > 0 or self.base_url in _ANSWERED

    async def aclose(self) -> None:
        await self._http.aclose()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    def body(self, messages: Messages, temperature: float, schema: dict[str, Any] | None = None) -> dict[str, Any]:
        body: dict[str, Any] = {"model": self.model, "messages": messages, "temperature": temperature}
        if self.max_tokens is not None:
            body["max_tokens"] = self.max_tokens
        if self.seed is not None:
            body["seed"] = self.seed
        if self.stream:
            body |= {"stream": True, "stream_options": {"include_usage": True}}
        if schema is not None:
            from .structured import response_format

            body |= response_format(schema, self.provider)
        return body | self.extra_body

    async def complete(
        self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE, schema: dict[str, Any] | None = None
    ) -> Completion:
        url = f"{self.base_url}/chat/completions"
        body = self.body(messages, temperature, schema)
        last = ""
        timeouts = 0
        silent = True  # no attempt of this call got a status line
        for attempt in range(self.retries + 1):
            delay = min(self.max_backoff, self.backoff * 2**attempt)
            answered = self.responses
            try:
                async with self._limit:  # the timeouts start once a slot is free
                    self.requests += 1
                    c = await self._attempt(url, body, messages, schema is not None, delay)
                self.prompt_tokens += c.prompt_tokens
                self.completion_tokens += c.completion_tokens
                return c
            except _Retry as exc:
                last = str(exc)
                delay = exc.delay
            except (TimeoutError, httpx.TimeoutException) as exc:
                silent = silent and self.responses == answered
                last = str(exc) if isinstance(exc, _Stalled) else f"no answer within {self.timeout:g} s" + (
                    f" ({type(exc).__name__})" if isinstance(exc, httpx.TimeoutException) else "")  # fmt: skip
                timeouts += 1
                if timeouts > self.timeout_retries or attempt == self.retries:
                    error = LLMSilent if silent and not self.answered else LLMTimeout
                    what = "no status line (the server accepted the connection and said nothing)" if error is LLMSilent else last
                    raise error(f"{self.model} at {self.base_url}: {what}, {timeouts} time(s); a timeout is retried at most {self.timeout_retries} time(s)") from None
            except httpx.TransportError as exc:
                last = f"{type(exc).__name__}: {exc}"
            except _Unreadable as exc:
                last = str(exc)
            if self.responses != answered:
                silent = False
            if attempt < self.retries:
                log.warning("llm call failed, retrying", model=self.model, attempt=attempt + 1, error=last, delay=delay)
                await asyncio.sleep(delay)
        raise LLMError(f"{self.model} at {self.base_url} failed after {self.retries + 1} attempts: {last}")

    async def _attempt(self, url: str, body: dict[str, Any], messages: Messages, structured: bool, delay: float) -> Completion:
        """One HTTP attempt. Leaving this (a result, an error, a timeout or a cancellation)
        closes the response, and with a body not read to its end, the connection: the server
        sees its client go and stops decoding."""
        loop = asyncio.get_running_loop()
        t0 = time.perf_counter()
        reply = _StreamedReply(t0, PROGRESS.get())
        try:
            async with asyncio.timeout(self.timeout) as deadline:  # to the first token; then rescheduled chunk by chunk
                async with self._http.stream("POST", url, json=body) as resp:
                    self.responses += 1
                    _ANSWERED.add(self.base_url)
                    if resp.status_code in self.RETRY_STATUS:
                        await resp.aread()
                        raise _Retry(f"HTTP {resp.status_code}: {resp.text[:200]}", retry_after(resp, delay, self.max_backoff))
                    if resp.status_code >= 400:
                        await resp.aread()
                        raise self._refusal(resp, url, structured)
                    if "text/event-stream" not in resp.headers.get("content-type", ""):
                        raw = await resp.aread()  # a whole reply (not streamed): within the first-token timeout
                        if not raw.lstrip().startswith(b"data:"):
                            return _completion(resp, messages, time.perf_counter() - t0)
                        lines: AsyncIterator[str] = _lines(resp.text)  # a stream mislabelled as something else
                    else:
                        lines = resp.aiter_lines()
                    async for line in lines:  # after [DONE] too, to the body's end: the connection then serves the next call
                        if reply.add(line):
                            deadline.reschedule(loop.time() + self.idle_timeout)
                        if reply.size > MAX_STREAM_CHARS or reply.chunks > MAX_STREAM_CHUNKS:
                            break
                    return reply.completion(messages, time.perf_counter() - t0)
        except TimeoutError:
            if reply.done:  # a server that keeps the body open after [DONE]: the reply is whole
                return reply.completion(messages, time.perf_counter() - t0)
            if reply.chunks:
                raise _Stalled(f"the stream stalled: no chunk for {self.idle_timeout:g} s after {reply.chunks} chunk(s)") from None
            raise
        raise AssertionError("unreachable")  # pragma: no cover  (for mypy: the context managers could swallow)

    def _refusal(self, resp: httpx.Response, url: str, structured: bool) -> LLMError:
        """The error for a 4xx no retry will fix; fatal where the run cannot succeed at all."""
        code, text = resp.status_code, resp.text[:300]
        if code in (401, 403):
            return LLMFatalError(f"{url} refused the credentials (HTTP {code}): check the API key ({text})")
        if code == 404:
            return LLMFatalError(f"{url} answered HTTP 404: no model {self.model!r} or no chat endpoint there; check the model name and --base-url ({text})")
        if structured and code in (400, 422) and re.search(r"response_format|json_schema|schema|grammar|format", text, re.IGNORECASE):
            return LLMFatalError(
                f"{url} refused the JSON-schema response format that --structured sends (HTTP {code}: {text}); "
                "run without --structured, or use a server that accepts response_format json_schema"
            )
        return LLMError(f"{url} answered HTTP {code} (not retried): {text}")


@functools.cache
def _tls() -> ssl.SSLContext:
    """One TLS context for every client: building one loads the CA bundle (0.02-0.17 s, blocking
    the event loop), which 108 clients of a concurrent evaluation paid one by one."""
    import certifi  # httpx's own CA bundle (a dependency of httpx), so trust is what httpx would use

    return ssl.create_default_context(cafile=certifi.where())


class _Unreadable(ValueError):
    """A 200 answer without a usable completion in it."""


class _Retry(Exception):
    """An answer worth another attempt (429, 5xx) after `delay` seconds."""

    def __init__(self, message: str, delay: float) -> None:
        super().__init__(message)
        self.delay = delay


class _Stalled(TimeoutError):
    """A streamed reply that began and then sent nothing for the idle timeout."""


async def _lines(text: str) -> AsyncIterator[str]:
    for line in text.splitlines():
        yield line


class _StreamedReply:
    """The chunks of a streamed completion (server-sent events), put together: content and
    reasoning deltas, the last finish_reason, and usage where the server sends it (the last chunk,
    with choices empty, when asked with stream_options.include_usage)."""

    def __init__(self, started: float, progress: Progress | None = None) -> None:
        self.started = started  # time.perf_counter() when the request went out
        self.ttft: float | None = None
        self.progress = progress
        if progress is not None:
            progress.attempt += 1
            progress.tokens = 0
        self.content: list[str] = []
        self.reasoning: list[str] = []
        self.finish_reason: str | None = None
        self.usage: dict[str, Any] = {}
        self.chunks = 0
        self.size = 0  # characters of content and reasoning so far
        self.done = False

    def add(self, line: str) -> bool:
        """Take one line of the stream; True when it was a chunk (the server is producing)."""
        if not line.startswith("data:") or self.done:
            return False  # blank separators, `event:` and `:` keep-alive comments; whatever follows [DONE]
        data = line[5:].strip()
        if data == "[DONE]":
            self.done = True
            return True
        try:
            chunk = json.loads(data)
            if not isinstance(chunk, dict):
                raise TypeError("a chunk is not an object")
            if chunk.get("error"):
                raise _Unreadable(f"the server sent an error in the stream: {str(chunk['error'])[:200]}")
            for choice in chunk.get("choices") or []:
                delta = choice.get("delta") or choice.get("message") or {}
                text = delta.get("content")
                thought = delta.get("reasoning_content") or delta.get("reasoning")
                if not isinstance(text, str | None) or not isinstance(thought, str | None):
                    raise TypeError("a delta's content is not text")
                self.content.append(text or "")
                self.reasoning.append(thought or "")
                self.size += len(text or "") + len(thought or "")
                if text or thought:
                    self._token()
                self.finish_reason = choice.get("finish_reason") or self.finish_reason
            if isinstance(chunk.get("usage"), dict):
                self.usage = chunk["usage"]
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            if isinstance(exc, _Unreadable):
                raise
            raise _Unreadable(f"unreadable stream chunk ({type(exc).__name__}: {exc}): {data[:200]}") from None
        self.chunks += 1
        return True

    def _token(self) -> None:
        if self.ttft is None:
            self.ttft = time.perf_counter() - self.started
        if self.progress is not None:
            self.progress.tokens += 1

    def completion(self, messages: Messages, latency: float) -> Completion:
        if not self.chunks:
            raise _Unreadable("the stream ended without a single chunk")
        text, reasoning = "".join(self.content), "".join(self.reasoning) or None
        return _make_completion(text, reasoning, self.usage, self.finish_reason, messages, latency, self.ttft)


def retry_after(resp: httpx.Response, default: float, cap: float) -> float:
    """Seconds to wait as the server's Retry-After says (seconds or HTTP date), else `default`."""
    value = resp.headers.get("retry-after")
    if value is None:
        return default
    try:
        seconds = float(value)
    except ValueError:
        try:
            when = email.utils.parsedate_to_datetime(value)
        except (TypeError, ValueError):
            return default
        seconds = when.timestamp() - time.time()
    return min(cap, max(0.0, seconds))


def _completion(resp: httpx.Response, messages: Messages, latency: float) -> Completion:
    try:
        data = resp.json()
        choice = data["choices"][0]
        message = choice["message"]
        text = message.get("content")
        reasoning = message.get("reasoning_content") or message.get("reasoning")
        if text is None and reasoning:  # a reasoning model that spent its tokens thinking
            text = ""
        if not isinstance(text, str) or not isinstance(reasoning, str | None):
            raise TypeError("message content is not text")
    except (ValueError, KeyError, IndexError, TypeError, AttributeError) as exc:
        raise _Unreadable(f"unreadable completion body ({type(exc).__name__}: {exc}): {resp.text[:200]}") from None
    return _make_completion(text, reasoning, data.get("usage") or {}, choice.get("finish_reason"), messages, latency)


def _make_completion(
    text: str, reasoning: str | None, usage: dict[str, Any], finish_reason: str | None, messages: Messages, latency: float,
    ttft: float | None = None,
) -> Completion:
    """A Completion from a reply's text and reasoning field, whether it came whole or in chunks."""
    answer, thoughts = split_reasoning(text, reasoning)
    answer, cut = bounded(answer)
    if thoughts is not None:
        thoughts = bounded(thoughts)[0]
    details = usage.get("completion_tokens_details") or {}
    reasoning_tokens = int(details.get("reasoning_tokens") or 0) or (estimate_tokens(thoughts) if thoughts else 0)
    return Completion(
        text=answer,
        prompt_tokens=int(usage.get("prompt_tokens") or estimate_tokens(prompt_text(messages))),
        completion_tokens=int(usage.get("completion_tokens") or estimate_tokens(text)),
        latency=latency,
        finish_reason=finish_reason,
        reasoning=thoughts,
        reasoning_tokens=reasoning_tokens,
        truncated=cut,
        ttft=ttft,
    )


Reply = str | BaseException


class ScriptedClient:
    """Answers from a list (then `Command: wait()`), or from a function of the messages.

    A reply that is an exception is raised instead (e.g. an LLMError, to test a model that is down).
    `latency` sleeps that long per call, to exercise concurrency. The prompts it was given are kept.
    """

    EXHAUSTED = "Command: wait()"

    def __init__(
        self, replies: Sequence[Reply] | Callable[[Messages], Reply], *, latency: float = 0.0, model: str = "scripted"
    ) -> None:
        self.model = model
        self._replies: list[Reply] | Callable[[Messages], Reply] = replies if callable(replies) else list(replies)
        self.latency = latency
        self.prompts: list[Messages] = []
        self.schemas: list[dict[str, Any] | None] = []

    @property
    def calls(self) -> int:
        return len(self.prompts)

    async def complete(
        self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE, schema: dict[str, Any] | None = None
    ) -> Completion:
        self.prompts.append([dict(m) for m in messages])
        self.schemas.append(schema)
        t0 = time.perf_counter()
        if self.latency:
            await asyncio.sleep(self.latency)
        if callable(self._replies):
            reply = self._replies(messages)
        else:
            reply = self._replies.pop(0) if self._replies else self.EXHAUSTED
        if isinstance(reply, BaseException):
            raise reply
        answer, thoughts = split_reasoning(reply)
        answer, cut = bounded(answer)
        return Completion(
            answer, estimate_tokens(prompt_text(messages)), estimate_tokens(reply), time.perf_counter() - t0,
            finish_reason="stop", reasoning=thoughts, reasoning_tokens=estimate_tokens(thoughts) if thoughts else 0, truncated=cut,
        )  # fmt: skip


ROBOT_SPEC = re.compile(r"^([a-z][a-z0-9_]*)=(.+)$")


def split_url(spec: str) -> tuple[str, str | None]:
    """`provider:model@http://host:port/v1` -> (provider:model, its own base URL)."""
    at = spec.rfind("@http")
    return (spec[:at], spec[at + 1 :]) if at > 0 else (spec, None)


def robot_specs(text: str, robots: Sequence[str]) -> dict[str, str | None]:
    """Which model drives which robot: `--llm SPEC` drives them all; `alice=SPEC,bob=SPEC` (any
    subset) drives those, a bare SPEC among them the rest, and without one the rest play the
    heuristic policy (None). A spec may end in `@URL` to name its own server. LLMSpecError names
    a robot that is not in the episode, or one given twice."""
    default: str | None = None
    chosen: dict[str, str] = {}
    for item in (i.strip() for i in text.split(",")):
        if not item:
            continue
        m = ROBOT_SPEC.match(item)
        if m is None:
            if default is not None:
                raise LLMSpecError(f"--llm {text!r} gives two default specs ({default!r}, {item!r}); name the robot of each: alice=SPEC")
            default = item
            continue
        robot, spec = m.groups()
        if robot not in robots:
            raise LLMSpecError(f"--llm {text!r} names robot {robot!r}, which is not in this episode (robots: {', '.join(robots)})")
        if robot in chosen:
            raise LLMSpecError(f"--llm {text!r} gives robot {robot!r} two specs")
        chosen[robot] = spec
    if default is None and not chosen:
        raise LLMSpecError("--llm is empty: give a model spec such as openai:gpt-4o, or alice=SPEC,bob=SPEC")
    return {r: chosen.get(r, default) for r in robots}


def check_spec(spec: str, base_url: str | None = None, api_key_env: str | None = None) -> tuple[str, str, str | None]:
    """(model, base URL, API key) for a spec, or LLMSpecError (a ValueError) saying what to fix.

    A spec's own `@URL` wins over `base_url`. `gguf:PATH` is checked as a local model file (its
    URL is known once its server runs)."""
    spec, own_url = split_url(spec)
    base_url = own_url or base_url
    provider, sep, model = spec.partition(":")
    if provider == "replay":
        if not model or not os.path.isfile(model):
            raise LLMSpecError(f"replay trace {model!r} (from LLM spec {spec!r}) does not exist")
        return model, "", None
    if provider == "gguf":
        from .local import GGUFError, check_gguf

        try:
            return str(check_gguf(model)), "", None
        except GGUFError as exc:
            raise LLMSpecError(f"LLM spec {spec!r}: {exc}") from None
    if provider not in PROVIDERS:
        if base_url is None:
            hint = f"known providers: {', '.join(PROVIDERS)}; or pass a base URL for any OpenAI-compatible server"
            if not sep:
                raise LLMSpecError(f"LLM spec {spec!r} must look like provider:model, e.g. openai:gpt-4o; {hint}")
            raise LLMSpecError(f"unknown LLM provider {provider!r} in LLM spec {spec!r}; {hint}")
        provider, model = "", spec  # with a base URL, a spec without a known provider is the model name
    if not model:
        raise LLMSpecError(f"LLM spec {spec!r} names no model, e.g. {provider or 'openai'}:gpt-4o")
    default_url, key_env = PROVIDERS.get(provider, ("", None))
    key_env = api_key_env or key_env
    api_key = (os.environ.get(key_env) if key_env else None) or os.environ.get(GENERIC_KEY_ENV)
    if provider == "openai" and base_url is None and not api_key:
        raise LLMSpecError(
            f"LLM spec {spec!r}: set {key_env} (or {GENERIC_KEY_ENV}) to your API key, or pass a base URL for another server"
        )
    return model, base_url or default_url, api_key


def make_client(spec: str, base_url: str | None = None, *, api_key_env: str | None = None, **options: Any) -> OpenAIChatClient:
    """An OpenAI-compatible client for a model spec; raises LLMSpecError before any request if unusable.

    `options` go to OpenAIChatClient: timeout (to the first token), idle_timeout, stream, retries,
    backoff, max_concurrency, max_tokens, extra_body.
    """
    model, url, api_key = check_spec(spec, base_url, api_key_env)
    if spec.startswith("replay:"):
        raise LLMSpecError(f"{spec!r} is a recorded trace: use mhrc.agents.replay.replay_clients for it")
    if spec.startswith("gguf:"):
        raise LLMSpecError(f"{spec!r} is a local model file: serve it with mhrc.agents.local.LocalModelServer first")
    provider = spec.partition(":")[0]
    return OpenAIChatClient(model, url, api_key=api_key, provider=provider if provider in PROVIDERS else "", **options)


# episodes a worker runs at once against a provider whose parallelism cannot be asked (with no
# answer from llama.cpp's /props): hosted APIs and vLLM batch many requests; Ollama and LM
# Studio serve few at once by default, and a queued request spends its timeout waiting
PROVIDER_EPISODES: dict[str, int] = {"openai": 12, "vllm": 12, "ollama": 1, "lmstudio": 1, "llamacpp": 1}


async def server_slots(base_url: str, timeout: float = 3.0) -> int | None:
    """How many requests the server decodes at once, where it says (llama.cpp's `/props`
    `total_slots`); None when it does not answer that."""
    root = base_url.rstrip("/").removesuffix("/v1")
    try:
        async with httpx.AsyncClient(timeout=timeout) as http:
            resp = await http.get(f"{root}/props")
        slots = resp.json().get("total_slots") if resp.status_code == 200 else None
    except (httpx.HTTPError, ValueError, AttributeError):
        return None
    return slots if isinstance(slots, int) and slots > 0 else None


async def episodes_at_once(specs: Sequence[str | None], base_url: str | None = None) -> int:
    """A worker's default --concurrency for episodes whose robots use `specs`: as many episodes
    as keep the model server's slots busy (one slot a robot), else the provider's usual
    parallelism; 1 for the heuristic (CPU-bound), replays and in-process GGUF models (each
    episode would load its own copy)."""
    llm = [s for s in specs if s is not None]
    if not llm or any(s.startswith(("gguf:", "replay:")) for s in llm):
        return 1
    spec, own = split_url(llm[0])
    url = own or base_url or PROVIDERS.get(spec.partition(":")[0], ("",))[0]
    slots = await server_slots(url) if url and url != PROVIDERS["openai"][0] else None
    if slots is not None:
        return max(1, slots // len(llm))
    return PROVIDER_EPISODES.get(spec.partition(":")[0], 4)
