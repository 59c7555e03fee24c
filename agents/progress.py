"""A model call under way, as far as its server has answered it: the client fills in a
`Progress` that the caller put in `PROGRESS` (a context variable of the caller's task), so that
an agent can tell its console "generating, 312 tokens" while a long call runs, without the
policy or the client knowing about the bus. Any client may fill it in; none has to."""

from __future__ import annotations

import time
from contextvars import ContextVar
from dataclasses import dataclass, field


@dataclass
class Progress:
    """One call: when it began, which HTTP attempt is under way, and that attempt's tokens so far
    (0: the server is still reading the prompt)."""

    started: float = field(default_factory=time.monotonic)  # when the call began (time.monotonic)
    attempt: int = 0  # HTTP attempts so far, retries included
    tokens: int = 0  # chunks of text or reasoning this attempt (llama.cpp, vLLM and OpenAI send about a token a chunk)

    def elapsed(self) -> float:
        return time.monotonic() - self.started


PROGRESS: ContextVar[Progress | None] = ContextVar("mhrc_llm_progress", default=None)
