"""An OpenAI-compatible chat completion's body read into a `Completion`: a whole JSON answer,
or server-sent events put together chunk by chunk."""

from __future__ import annotations

import json
import time
from collections.abc import Mapping

import httpx

from mhrc.core.jsontypes import JsonValue

from ..progress import Progress
from .completion import Completion, Messages, bounded, estimate_tokens, prompt_text, split_reasoning

Usage = Mapping[str, JsonValue]  # a completion's `usage` object as the server sent it, read field by field


class Unreadable(ValueError):
    """A 200 answer without a usable completion in it."""


class StreamedReply:
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
        self.usage: Usage = {}
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
                raise Unreadable(f"the server sent an error in the stream: {str(chunk['error'])[:200]}")
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
            if isinstance(exc, Unreadable):
                raise
            raise Unreadable(f"unreadable stream chunk ({type(exc).__name__}: {exc}): {data[:200]}") from None
        self.chunks += 1
        return True

    def _token(self) -> None:
        if self.ttft is None:
            self.ttft = time.perf_counter() - self.started
        if self.progress is not None:
            self.progress.tokens += 1

    def completion(self, messages: Messages, latency: float) -> Completion:
        if not self.chunks:
            raise Unreadable("the stream ended without a single chunk")
        text, reasoning = "".join(self.content), "".join(self.reasoning) or None
        return make_completion(text, reasoning, self.usage, self.finish_reason, messages, latency, self.ttft)


def whole_completion(resp: httpx.Response, messages: Messages, latency: float) -> Completion:
    """A reply that came whole (one JSON body, not streamed), or Unreadable saying why not."""
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
        raise Unreadable(f"unreadable completion body ({type(exc).__name__}: {exc}): {resp.text[:200]}") from None
    return make_completion(text, reasoning, data.get("usage") or {}, choice.get("finish_reason"), messages, latency)


def make_completion(
    text: str,
    reasoning: str | None,
    usage: Usage,
    finish_reason: str | None,
    messages: Messages,
    latency: float,
    ttft: float | None = None,
) -> Completion:
    """A Completion from a reply's text and reasoning field, whether it came whole or in chunks."""
    answer, thoughts = split_reasoning(text, reasoning)
    answer, cut = bounded(answer)
    if thoughts is not None:
        thoughts = bounded(thoughts)[0]
    details = usage.get("completion_tokens_details") or {}
    if not isinstance(details, Mapping):
        raise TypeError(f"usage.completion_tokens_details is {type(details).__name__}, not an object")
    reasoning_tokens = _count(details.get("reasoning_tokens") or 0) or (estimate_tokens(thoughts) if thoughts else 0)
    return Completion(
        text=answer,
        prompt_tokens=_count(usage.get("prompt_tokens") or estimate_tokens(prompt_text(messages))),
        completion_tokens=_count(usage.get("completion_tokens") or estimate_tokens(text)),
        latency=latency,
        finish_reason=finish_reason,
        reasoning=thoughts,
        reasoning_tokens=reasoning_tokens,
        truncated=cut,
        ttft=ttft,
    )


def _count(value: JsonValue) -> int:
    """A token count as the server sent it: a number, or a number's text."""
    if not isinstance(value, int | float | str):
        raise TypeError(f"a token count is {type(value).__name__}, not a number")
    return int(value)
