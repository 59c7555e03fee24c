"""What a language model answers and how a call to it fails: the vocabulary every client shares.

A reply is kept to MAX_REPLY_CHARS; reasoning models' thoughts (a `reasoning_content` or
`reasoning` field, or `<think>...</think>` in the text) are split off into `Completion.reasoning`
so that they never reach the command parser.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Protocol

from mhrc.core.jsontypes import JsonObject

Messages = list[dict[str, str]]

DEFAULT_TEMPERATURE = 0.5  # the paper's
DEFAULT_MAX_TOKENS = 1024  # the paper's reply format (analysis, reasoning, one command) with room to think
MAX_REPLY_CHARS = 16_000  # what a reply may feed into the trace and the parser (about 4x DEFAULT_MAX_TOKENS tokens)
DEFAULT_TIMEOUT = 120.0  # s to the first token (mhrc.run.config.SERVER_TIMEOUT says why)
DEFAULT_IDLE_TIMEOUT = 30.0  # s between two chunks of a streamed reply: a decoding server sends one every few tokens


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


@dataclass(frozen=True)
class Completion:
    """One answer of a model: its text apart from its reasoning, token counts and timing."""

    text: str  # the answer without any reasoning block, at most MAX_REPLY_CHARS
    prompt_tokens: int
    completion_tokens: int
    latency: float  # seconds, the successful attempt only
    finish_reason: str | None = None  # "stop", "length" (cut at max_tokens), ...
    reasoning: str | None = None  # a reasoning model's thoughts, apart from the answer
    reasoning_tokens: int = 0
    truncated: bool = False  # the text was longer than MAX_REPLY_CHARS and was cut
    ttft: float | None = (
        None  # seconds to the first chunk of a streamed reply (prompt processing, mostly); None: not streamed
    )


class LLMClient(Protocol):
    """Anything that answers a chat: the policies need nothing more.

    `schema`, when given, is a JSON Schema the reply must follow (structured decisions)."""

    model: str

    async def complete(
        self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE, schema: JsonObject | None = None
    ) -> Completion: ...


async def close_client(client: LLMClient | None) -> None:
    """Close `client` where it holds something to close (an HTTP client's connections: its
    `aclose`); a scripted or replayed client holds nothing."""
    close = getattr(client, "aclose", None)
    if close is not None:
        await close()


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
