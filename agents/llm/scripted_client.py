"""A scripted stand-in for a model, in process: its answers are the test's "judgement"."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Sequence

from mhrc.core.jsontypes import JsonObject

from .completion import (
    DEFAULT_TEMPERATURE,
    Completion,
    Messages,
    bounded,
    estimate_tokens,
    prompt_text,
    split_reasoning,
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
        self.schemas: list[JsonObject | None] = []  # each call's JSON Schema (None: a plain reply)

    @property
    def calls(self) -> int:
        return len(self.prompts)

    async def complete(
        self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE, schema: JsonObject | None = None
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
            answer,
            estimate_tokens(prompt_text(messages)),
            estimate_tokens(reply),
            time.perf_counter() - t0,
            finish_reason="stop",
            reasoning=thoughts,
            reasoning_tokens=estimate_tokens(thoughts) if thoughts else 0,
            truncated=cut,
        )
