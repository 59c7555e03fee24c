"""What an agent says about its own mind: a step's thought (prompt, reply, parse) and a long model call's progress."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from mhrc.core.protocol.base import Message

# --------------------------------------------------------------------------- thoughts


HUMAN_POLICY = "human"  # a Thought.policy: a person decided (mhrc play); its latency is the time the person took
LLM_ERROR_PREFIX = "llm error: "  # a Thought.parse_error that starts so: the model was unreachable, not misunderstood


class Thought(Message):
    """What an agent considered before acting: for observers and the recorder."""

    kind: Literal["thought"] = "thought"
    robot: str
    tick: int
    policy: str
    prompt: str | None = None
    reply: str | None = None
    action: str | None = None
    parse_error: str | None = None
    prompt_tokens: int = 0
    completion_tokens: int = 0
    latency: float = 0.0
    reasoning: str | None = Field(
        None, description="a reasoning model's thoughts (reasoning field or <think> block), apart from the reply"
    )
    reasoning_tokens: int = 0
    finish_reason: str | None = Field(None, description="the server's: stop, length (cut at max_tokens), ...")
    schema_hash: str | None = Field(
        None, description="with --structured: hash of the JSON Schema the reply had to follow"
    )
    ttft: float | None = Field(
        None, description="seconds to the reply's first token (prompt processing, mostly), where it was streamed"
    )


class Generating(Message):
    """A robot's model call that is taking a while, as the server has answered it so far: live
    status for the console (`mhrc up`), sent every few seconds of a long call; not recorded."""

    kind: Literal["generating"] = "generating"
    robot: str
    tick: int
    elapsed: float = Field(description="seconds since the call began, retries included")
    tokens: int = Field(
        0, description="tokens streamed so far in this attempt (0: the server is still reading the prompt)"
    )
    attempt: int = Field(1, description="HTTP attempt of this call (retries included)")
