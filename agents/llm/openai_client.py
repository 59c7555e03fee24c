"""An OpenAI-compatible chat-completions client over httpx (on aiohttp's connections, transport.py):
streamed, timed, retried, bounded.

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
"""

from __future__ import annotations

import asyncio
import email.utils
import functools
import re
import ssl
import time
from collections.abc import AsyncIterator
from typing import Self, TypedDict

import httpx

from mhrc.core.jsontypes import JsonObject
from mhrc.core.logs import get_logger

from ..progress import PROGRESS
from .completion import (
    DEFAULT_IDLE_TIMEOUT,
    DEFAULT_MAX_TOKENS,
    DEFAULT_TEMPERATURE,
    DEFAULT_TIMEOUT,
    Completion,
    LLMError,
    LLMFatalError,
    LLMSilent,
    LLMTimeout,
    Messages,
)
from .reply import StreamedReply, Unreadable, whole_completion

log = get_logger("mhrc.llm")

MAX_STREAM_CHARS = (
    1_000_000  # a streamed reply is read no further (a server that never stops): far beyond any max_tokens
)
MAX_STREAM_CHUNKS = 200_000  # nor past this many chunks (a server that streams empty deltas forever)

_ANSWERED: set[str] = set()  # base URLs that sent this process a status line: slow from then on, never down


class ClientOptions(TypedDict, total=False):
    """OpenAIChatClient's settings besides its model, URL, key and provider (an episode's:
    mhrc.run.config.EpisodeConfig.client_options)."""

    timeout: float
    idle_timeout: float
    stream: bool
    retries: int
    backoff: float
    max_backoff: float
    max_concurrency: int
    max_tokens: int | None
    seed: int | None
    timeout_retries: int
    extra_body: JsonObject | None
    transport: httpx.AsyncBaseTransport | None


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
        extra_body: JsonObject | None = None,
        transport: httpx.AsyncBaseTransport | None = None,
    ) -> None:
        if retries < 0 or timeout <= 0 or idle_timeout <= 0 or max_concurrency < 1 or timeout_retries < 0:
            raise ValueError(
                "need retries >= 0, timeout_retries >= 0, timeout > 0, idle_timeout > 0 and max_concurrency >= 1"
            )
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
        # the deadlines of a call are this client's own (asyncio), not httpx's per-read timeout. The
        # requests go over aiohttp's connections (transport.py: a quarter to two thirds of httpx's own
        # transport's CPU), unless the environment names a proxy: httpx reads it only when it
        # makes its own transports, so those carry the calls then, through the proxy, as before.
        if transport is None and not _proxied():
            from .transport import AiohttpTransport

            transport = AiohttpTransport(_tls())
        self._http = httpx.AsyncClient(
            timeout=httpx.Timeout(None, connect=timeout), headers=headers, transport=transport, verify=_tls()
        )
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

    @property
    def closed(self) -> bool:
        """Whether `aclose` was called (its connections are closed)."""
        return self._http.is_closed

    async def aclose(self) -> None:
        await self._http.aclose()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    def body(self, messages: Messages, temperature: float, schema: JsonObject | None = None) -> JsonObject:
        """The chat-completions request: the call's fields, then `extra_body`'s over them."""
        body: JsonObject = {"model": self.model, "messages": messages, "temperature": temperature}
        if self.max_tokens is not None:
            body["max_tokens"] = self.max_tokens
        if self.seed is not None:
            body["seed"] = self.seed
        if self.stream:
            body |= {"stream": True, "stream_options": {"include_usage": True}}
        if schema is not None:
            from ..structured import (
                response_format,  # lazily: it loads the protocol models, which plain replies never need
            )

            body |= response_format(schema, self.provider)
        return body | self.extra_body

    async def complete(
        self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE, schema: JsonObject | None = None
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
                last = (
                    str(exc)
                    if isinstance(exc, _Stalled)
                    else f"no answer within {self.timeout:g} s"
                    + (f" ({type(exc).__name__})" if isinstance(exc, httpx.TimeoutException) else "")
                )
                timeouts += 1
                if timeouts > self.timeout_retries or attempt == self.retries:
                    error = LLMSilent if silent and not self.answered else LLMTimeout
                    what = (
                        "no status line (the server accepted the connection and said nothing)"
                        if error is LLMSilent
                        else last
                    )
                    raise error(
                        f"{self.model} at {self.base_url}: {what}, {timeouts} time(s); a timeout is retried at most {self.timeout_retries} time(s)"
                    ) from None
            except httpx.TransportError as exc:
                last = f"{type(exc).__name__}: {exc}"
            except Unreadable as exc:
                last = str(exc)
            if self.responses != answered:
                silent = False
            if attempt < self.retries:
                log.warning("llm call failed, retrying", model=self.model, attempt=attempt + 1, error=last, delay=delay)
                await asyncio.sleep(delay)
        raise LLMError(f"{self.model} at {self.base_url} failed after {self.retries + 1} attempts: {last}")

    async def _attempt(
        self, url: str, body: JsonObject, messages: Messages, structured: bool, delay: float
    ) -> Completion:
        """One HTTP attempt. Leaving this (a result, an error, a timeout or a cancellation)
        closes the response, and with a body not read to its end, the connection: the server
        sees its client go and stops decoding."""
        loop = asyncio.get_running_loop()
        t0 = time.perf_counter()
        reply = StreamedReply(t0, PROGRESS.get())
        try:
            async with asyncio.timeout(self.timeout) as deadline:  # to the first token; then rescheduled chunk by chunk
                async with self._http.stream("POST", url, json=body) as resp:
                    self.responses += 1
                    _ANSWERED.add(self.base_url)
                    if resp.status_code in self.RETRY_STATUS:
                        await resp.aread()
                        raise _Retry(
                            f"HTTP {resp.status_code}: {resp.text[:200]}", retry_after(resp, delay, self.max_backoff)
                        )
                    if resp.status_code >= 400:
                        await resp.aread()
                        raise self._refusal(resp, url, structured)
                    if "text/event-stream" not in resp.headers.get("content-type", ""):
                        raw = await resp.aread()  # a whole reply (not streamed): within the first-token timeout
                        if not raw.lstrip().startswith(b"data:"):
                            return whole_completion(resp, messages, time.perf_counter() - t0)
                        lines: AsyncIterator[str] = _lines(resp.text)  # a stream mislabelled as something else
                    else:
                        lines = resp.aiter_lines()
                    async for (
                        line
                    ) in lines:  # after [DONE] too, to the body's end: the connection then serves the next call
                        if reply.add(line):
                            deadline.reschedule(loop.time() + self.idle_timeout)
                        if reply.size > MAX_STREAM_CHARS or reply.chunks > MAX_STREAM_CHUNKS:
                            break
                    return reply.completion(messages, time.perf_counter() - t0)
        except TimeoutError:
            if reply.done:  # a server that keeps the body open after [DONE]: the reply is whole
                return reply.completion(messages, time.perf_counter() - t0)
            if reply.chunks:
                raise _Stalled(
                    f"the stream stalled: no chunk for {self.idle_timeout:g} s after {reply.chunks} chunk(s)"
                ) from None
            raise
        raise AssertionError("unreachable")  # pragma: no cover  (for mypy: the context managers could swallow)

    def _refusal(self, resp: httpx.Response, url: str, structured: bool) -> LLMError:
        """The error for a 4xx no retry will fix; fatal where the run cannot succeed at all."""
        code, text = resp.status_code, resp.text[:300]
        if code in (401, 403):
            return LLMFatalError(f"{url} refused the credentials (HTTP {code}): check the API key ({text})")
        if code == 404:
            return LLMFatalError(
                f"{url} answered HTTP 404: no model {self.model!r} or no chat endpoint there; check the model name and --base-url ({text})"
            )
        if (
            structured
            and code in (400, 422)
            and re.search(r"response_format|json_schema|schema|grammar|format", text, re.IGNORECASE)
        ):
            return LLMFatalError(
                f"{url} refused the JSON-schema response format that --structured sends (HTTP {code}: {text}); "
                "run without --structured, or use a server that accepts response_format json_schema"
            )
        return LLMError(f"{url} answered HTTP {code} (not retried): {text}")


def _proxied() -> bool:
    """Whether the environment names an HTTP(S) proxy (HTTP_PROXY, HTTPS_PROXY, ALL_PROXY: what
    httpx reads, through urllib's getproxies)."""
    import urllib.request

    return any(scheme in urllib.request.getproxies() for scheme in ("http", "https", "all"))


@functools.cache
def _tls() -> ssl.SSLContext:
    """One TLS context for every client: building one loads the CA bundle (0.02-0.17 s, blocking
    the event loop), which 108 clients of a concurrent evaluation paid one by one."""
    import certifi  # httpx's own CA bundle (a dependency of httpx), so trust is what httpx would use

    return ssl.create_default_context(cafile=certifi.where())


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
