"""LLM clients: OpenAI-compatible chat completions over httpx, and a scripted stand-in.

A model spec names the provider and model: `openai:gpt-4o`, `ollama:llama3.1:8b`,
`vllm:MODEL`, `lmstudio:MODEL`, `llamacpp:MODEL`, or `openai:MODEL` with `base_url` pointing at
any OpenAI-compatible server. Transient failures (429, 5xx, timeouts, refused connections,
unreadable bodies) are retried with exponential backoff, honouring Retry-After; then LLMError.
"""

from __future__ import annotations

import asyncio
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import httpx
import structlog

log = structlog.get_logger("mhrc.llm")

Messages = list[dict[str, str]]

# provider -> (default base URL, environment variable holding the API key or None)
# `replay:TRACE` is handled by mhrc.agents.replay (one client per robot)
PROVIDERS: dict[str, tuple[str, str | None]] = {
    "openai": ("https://api.openai.com/v1", "OPENAI_API_KEY"),
    "ollama": ("http://127.0.0.1:11434/v1", None),
    "vllm": ("http://127.0.0.1:8000/v1", None),
    "lmstudio": ("http://127.0.0.1:1234/v1", None),
    "llamacpp": ("http://127.0.0.1:8080/v1", None),
}
GENERIC_KEY_ENV = "MHRC_API_KEY"


class LLMError(RuntimeError):
    """The model could not be reached or answered unusably, after retries."""


@dataclass(frozen=True)
class Completion:
    text: str
    prompt_tokens: int
    completion_tokens: int
    latency: float


class LLMClient(Protocol):
    model: str

    async def complete(self, messages: Messages, *, temperature: float) -> Completion: ...


def estimate_tokens(text: str) -> int:
    """About four characters a token: for servers that report no usage."""
    return max(1, len(text) // 4)


class OpenAIChatClient:
    """POST {base_url}/chat/completions, with retries and a concurrency limit."""

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
        max_backoff: float = 20.0,
        max_concurrency: int = 8,
        transport: httpx.AsyncBaseTransport | None = None,
    ) -> None:
        self.model = model
        self.base_url = base_url.rstrip("/")
        self.retries = retries
        self.backoff = backoff
        self.max_backoff = max_backoff
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        self._http = httpx.AsyncClient(timeout=timeout, headers=headers, transport=transport)
        self._limit = asyncio.Semaphore(max_concurrency)
        self.calls = 0

    async def aclose(self) -> None:
        await self._http.aclose()

    async def complete(self, messages: Messages, *, temperature: float = 0.5) -> Completion:
        body = {"model": self.model, "messages": messages, "temperature": temperature}
        url = f"{self.base_url}/chat/completions"
        last = ""
        for attempt in range(self.retries + 1):
            delay = min(self.max_backoff, self.backoff * 2**attempt)
            t0 = time.perf_counter()
            try:
                async with self._limit:
                    self.calls += 1
                    resp = await self._http.post(url, json=body)
                if resp.status_code in self.RETRY_STATUS:
                    last = f"HTTP {resp.status_code}: {resp.text[:200]}"
                    delay = _retry_after(resp, delay, self.max_backoff)
                elif resp.status_code >= 400:
                    raise LLMError(f"{url} answered HTTP {resp.status_code}: {resp.text[:300]}")
                else:
                    return _completion(resp, messages, time.perf_counter() - t0)
            except (httpx.TimeoutException, httpx.TransportError) as exc:
                last = f"{type(exc).__name__}: {exc}"
            except _Unreadable as exc:
                last = str(exc)
            if attempt < self.retries:
                log.info("llm call failed, retrying", model=self.model, attempt=attempt + 1, error=last, delay=delay)
                await asyncio.sleep(delay)
        raise LLMError(f"{self.model} at {self.base_url} failed after {self.retries + 1} attempts: {last}")


class _Unreadable(ValueError):
    pass


def _retry_after(resp: httpx.Response, default: float, cap: float) -> float:
    try:
        return min(cap, max(0.0, float(resp.headers.get("retry-after", default))))
    except ValueError:
        return default


def _completion(resp: httpx.Response, messages: Messages, latency: float) -> Completion:
    try:
        data = resp.json()
        text = data["choices"][0]["message"]["content"]
        if not isinstance(text, str):
            raise TypeError("content is not text")
    except (ValueError, KeyError, IndexError, TypeError) as exc:
        raise _Unreadable(f"unreadable completion body ({exc}): {resp.text[:200]}") from None
    usage = data.get("usage") or {}
    prompt_chars = "".join(m.get("content", "") for m in messages)
    return Completion(
        text=text,
        prompt_tokens=int(usage.get("prompt_tokens") or estimate_tokens(prompt_chars)),
        completion_tokens=int(usage.get("completion_tokens") or estimate_tokens(text)),
        latency=latency,
    )


class ScriptedClient:
    """Replies from a list (or a function of the messages), optionally after a fixed delay."""

    def __init__(self, replies: Sequence[str] | Callable[[Messages], str], *, latency: float = 0.0, model: str = "scripted") -> None:
        self.model = model
        self._replies = replies if callable(replies) else list(replies)
        self.latency = latency
        self.calls = 0

    async def complete(self, messages: Messages, *, temperature: float = 0.5) -> Completion:
        t0 = time.perf_counter()
        self.calls += 1
        if self.latency:
            await asyncio.sleep(self.latency)
        if callable(self._replies):
            text = self._replies(messages)
        else:
            text = self._replies.pop(0) if self._replies else "Command: wait()"
        prompt = "".join(m["content"] for m in messages)
        return Completion(text, estimate_tokens(prompt), estimate_tokens(text), time.perf_counter() - t0)


def check_spec(spec: str, base_url: str | None = None, api_key_env: str | None = None) -> tuple[str, str, str | None]:
    """(model, base URL, API key) for a spec, or ValueError saying what is wrong."""
    provider, sep, model = spec.partition(":")
    if provider == "replay" and model:
        if not os.path.isfile(model):
            raise ValueError(f"replay trace {model!r} does not exist")
        return model, "", None
    if not sep or not model:
        raise ValueError(f"LLM spec {spec!r} must look like provider:model, e.g. openai:gpt-4o or ollama:llama3.1:8b")
    if provider not in PROVIDERS:
        raise ValueError(f"unknown LLM provider {provider!r} in {spec!r}; known: {', '.join(PROVIDERS)}")
    default_url, key_env = PROVIDERS[provider]
    key_env = api_key_env or key_env
    api_key = os.environ.get(key_env) if key_env else None
    api_key = api_key or os.environ.get(GENERIC_KEY_ENV)
    if provider == "openai" and base_url is None and not api_key:
        raise ValueError(f"{spec}: set {key_env} (or {GENERIC_KEY_ENV}) to your API key, or pass --base-url for another server")
    return model, base_url or default_url, api_key


def make_client(spec: str, *, base_url: str | None = None, api_key_env: str | None = None, **options: object) -> OpenAIChatClient:
    """An OpenAI-compatible client for `provider:model`; fails before any request if unusable."""
    model, url, api_key = check_spec(spec, base_url, api_key_env)
    return OpenAIChatClient(model, url, api_key=api_key, **options)  # type: ignore[arg-type]
