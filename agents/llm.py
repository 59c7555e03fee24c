"""LLM clients: OpenAI-compatible chat completions over httpx, and a scripted stand-in.

A model spec names the provider and the model: `openai:gpt-4o`, `ollama:llama3.1:8b`,
`vllm:MODEL`, `lmstudio:MODEL`, `llamacpp:MODEL`. With an explicit `base_url` the request goes
to that server, and a spec without a known provider is the model name itself (`qwen2.5:7b`). The API
key comes from the provider's variable (OPENAI_API_KEY for openai), from `api_key_env` if
given, else from MHRC_API_KEY. Transient failures (429, 5xx, timeouts, refused connections,
unreadable bodies) are retried with exponential backoff, honouring Retry-After, a bounded
number of times; then LLMError.
"""

from __future__ import annotations

import asyncio
import email.utils
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, Self

import httpx
import structlog

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


class LLMError(RuntimeError):
    """The model could not be reached, or answered unusably, after the retries."""


class LLMSpecError(ValueError):
    """A model spec that names no usable server (unknown provider, missing API key)."""


@dataclass(frozen=True)
class Completion:
    text: str
    prompt_tokens: int
    completion_tokens: int
    latency: float  # seconds, the successful attempt only


class LLMClient(Protocol):
    """Anything that answers a chat: the policies need nothing more."""

    model: str

    async def complete(self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE) -> Completion: ...


def estimate_tokens(text: str) -> int:
    """About four characters a token: for servers that report no usage."""
    return max(1, len(text) // 4)


def prompt_text(messages: Messages) -> str:
    """The messages' contents as one text: what a Thought records and a replay compares."""
    return "\n\n".join(m.get("content", "") for m in messages)


class OpenAIChatClient:
    """POST {base_url}/chat/completions, with retries, a per-request timeout and a concurrency limit."""

    RETRY_STATUS = frozenset({408, 409, 425, 429, 500, 502, 503, 504})

    def __init__(
        self,
        model: str,
        base_url: str,
        *,
        api_key: str | None = None,
        timeout: float = 60.0,
        retries: int = 4,
        backoff: float = 0.5,
        max_backoff: float = 30.0,
        max_concurrency: int = 4,
        max_tokens: int | None = None,
        extra_body: dict[str, Any] | None = None,
        transport: httpx.AsyncBaseTransport | None = None,
    ) -> None:
        if retries < 0 or timeout <= 0 or max_concurrency < 1:
            raise ValueError("need retries >= 0, timeout > 0 and max_concurrency >= 1")
        self.model = model
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self.retries = retries
        self.backoff = backoff
        self.max_backoff = max_backoff
        self.max_tokens = max_tokens
        self.extra_body = dict(extra_body or {})
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        self._http = httpx.AsyncClient(timeout=timeout, headers=headers, transport=transport)
        self._limit = asyncio.Semaphore(max_concurrency)
        self.requests = 0  # HTTP attempts, retries included
        self.prompt_tokens = 0  # totals over successful calls
        self.completion_tokens = 0

    async def aclose(self) -> None:
        await self._http.aclose()

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    def body(self, messages: Messages, temperature: float) -> dict[str, Any]:
        body: dict[str, Any] = {"model": self.model, "messages": messages, "temperature": temperature}
        if self.max_tokens is not None:
            body["max_tokens"] = self.max_tokens
        return body | self.extra_body

    async def complete(self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE) -> Completion:
        url = f"{self.base_url}/chat/completions"
        body = self.body(messages, temperature)
        last = ""
        for attempt in range(self.retries + 1):
            delay = min(self.max_backoff, self.backoff * 2**attempt)
            try:
                async with self._limit:  # the timeout starts once a slot is free
                    self.requests += 1
                    t0 = time.perf_counter()
                    async with asyncio.timeout(self.timeout):  # whole request, however the bytes trickle
                        resp = await self._http.post(url, json=body)
                    latency = time.perf_counter() - t0
                if resp.status_code in self.RETRY_STATUS:
                    last = f"HTTP {resp.status_code}: {resp.text[:200]}"
                    delay = retry_after(resp, delay, self.max_backoff)
                elif resp.status_code >= 400:
                    raise LLMError(f"{url} answered HTTP {resp.status_code} (not retried): {resp.text[:300]}")
                else:
                    c = _completion(resp, messages, latency)
                    self.prompt_tokens += c.prompt_tokens
                    self.completion_tokens += c.completion_tokens
                    return c
            except TimeoutError:
                last = f"no answer within {self.timeout:g} s"
            except httpx.TimeoutException as exc:
                last = f"{type(exc).__name__}: no answer within {self.timeout:g} s"
            except httpx.TransportError as exc:
                last = f"{type(exc).__name__}: {exc}"
            except _Unreadable as exc:
                last = str(exc)
            if attempt < self.retries:
                log.warning("llm call failed, retrying", model=self.model, attempt=attempt + 1, error=last, delay=delay)
                await asyncio.sleep(delay)
        raise LLMError(f"{self.model} at {self.base_url} failed after {self.retries + 1} attempts: {last}")


class _Unreadable(ValueError):
    """A 200 answer without a usable completion in it."""


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
        text = data["choices"][0]["message"]["content"]
        if not isinstance(text, str):
            raise TypeError("message content is not text")
    except (ValueError, KeyError, IndexError, TypeError) as exc:
        raise _Unreadable(f"unreadable completion body ({type(exc).__name__}: {exc}): {resp.text[:200]}") from None
    usage = data.get("usage") or {}
    return Completion(
        text=text,
        prompt_tokens=int(usage.get("prompt_tokens") or estimate_tokens(prompt_text(messages))),
        completion_tokens=int(usage.get("completion_tokens") or estimate_tokens(text)),
        latency=latency,
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

    @property
    def calls(self) -> int:
        return len(self.prompts)

    async def complete(self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE) -> Completion:
        self.prompts.append([dict(m) for m in messages])
        t0 = time.perf_counter()
        if self.latency:
            await asyncio.sleep(self.latency)
        if callable(self._replies):
            reply = self._replies(messages)
        else:
            reply = self._replies.pop(0) if self._replies else self.EXHAUSTED
        if isinstance(reply, BaseException):
            raise reply
        return Completion(reply, estimate_tokens(prompt_text(messages)), estimate_tokens(reply), time.perf_counter() - t0)


def check_spec(spec: str, base_url: str | None = None, api_key_env: str | None = None) -> tuple[str, str, str | None]:
    """(model, base URL, API key) for a spec, or LLMSpecError (a ValueError) saying what to fix."""
    provider, sep, model = spec.partition(":")
    if provider == "replay":
        if not model or not os.path.isfile(model):
            raise LLMSpecError(f"replay trace {model!r} (from LLM spec {spec!r}) does not exist")
        return model, "", None
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

    `options` go to OpenAIChatClient: timeout, retries, backoff, max_concurrency, max_tokens, extra_body.
    """
    model, url, api_key = check_spec(spec, base_url, api_key_env)
    if spec.startswith("replay:"):
        raise LLMSpecError(f"{spec!r} is a recorded trace: use mhrc.agents.replay.replay_clients for it")
    return OpenAIChatClient(model, url, api_key=api_key, **options)
