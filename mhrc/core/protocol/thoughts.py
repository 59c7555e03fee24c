"""What an agent says about its own mind: a step's thought (prompt, reply, parse) and a long model call's progress."""

from __future__ import annotations

from enum import StrEnum
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, model_serializer

from mhrc.core.protocol.base import MAX_INT, MAX_NAME, Message

# Bounds on what an agent says about its mind (docs/protocol.md, "Limits"): far above any honest
# thought, so that one login cannot make the recorder write megabytes a message.
MAX_TEXT = 1_000_000  # characters of a prompt, a reply or a reasoning: the model client reads no more of a reply
MAX_LINE = 20_000  # characters of the short fields (policy, action, parse_error, ...): a communicate's call, escaped
MAX_THOUGHT_BYTES = 8 * 1024 * 1024  # a thought's payload, checked before it is parsed (three texts, escaped)

# --------------------------------------------------------------------------- thoughts


HUMAN_POLICY = "human"  # a Thought.policy: a person decided (mhrc play); its latency is the time the person took
LLM_ERROR_PREFIX = "llm error: "  # how a Thought.parse_error of a model that did not answer starts, for people (programs read `failure`)


class ReplyFailure(StrEnum):
    """Why a robot's step gave no action (a `Thought`'s `failure`), for programs; its parse_error
    says it for people. Set where the step failed (the LLM policy); read from older traces'
    texts in mhrc.core.upgrade."""

    MODEL_UNREACHABLE = "model_unreachable"  # the model did not answer (down, refused, past the deadline)
    CUT_OFF = "cut_off"  # the reply was cut at the token limit before it gave a command
    UNREADABLE = "unreadable"  # the reply came whole but did not parse into one command

    @property
    def unparsed(self) -> bool:
        """A reply came and did not parse (the metrics' parse_failures), as against a model that did not answer."""
        return self is not ReplyFailure.MODEL_UNREACHABLE


def fit(text: str | None, limit: int = MAX_TEXT) -> str | None:
    """`text` cut to `limit` characters, for an agent building its Thought (the bound is never met in practice)."""
    return text if text is None or len(text) <= limit else text[:limit]


class Coordination(BaseModel):
    """What a coordination protocol decided for a robot at a step (a `Thought`'s `coordination`):
    whom the robot follows and the job it was given. Set by the protocols other than the paper's
    (docs/protocols.md); the paper's robots decide alone and send none."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    leader: str | None = Field(
        None, max_length=MAX_NAME, description="the robot this one believes leads the team (a leader protocol)"
    )
    job: str | None = Field(
        None,
        max_length=MAX_LINE,
        description="the job allocated to this robot, as a call: fetch(book), explore(fridge)",
    )
    by: str | None = Field(
        None, max_length=MAX_NAME, description="who allocated it: the leader's name, or 'planner' (centralized)"
    )


class Thought(Message):
    """What an agent considered before acting: for observers and the recorder."""

    kind: Literal["thought"] = "thought"
    robot: str = Field(max_length=MAX_NAME)
    tick: int = Field(ge=0, le=MAX_INT)
    policy: str = Field(max_length=MAX_LINE)
    prompt: str | None = Field(None, max_length=MAX_TEXT)
    reply: str | None = Field(None, max_length=MAX_TEXT)
    action: str | None = Field(None, max_length=MAX_LINE)
    parse_error: str | None = Field(None, max_length=MAX_LINE)
    failure: ReplyFailure | None = Field(
        None, description="why the step gave no action (with parse_error, the sentence): none when it gave one"
    )
    prompt_tokens: int = Field(0, ge=0, le=MAX_INT)
    completion_tokens: int = Field(0, ge=0, le=MAX_INT)
    latency: float = Field(0.0, ge=0.0, allow_inf_nan=False)
    reasoning: str | None = Field(
        None,
        max_length=MAX_TEXT,
        description="a reasoning model's thoughts (reasoning field or <think> block), apart from the reply",
    )
    reasoning_tokens: int = Field(0, ge=0, le=MAX_INT)
    finish_reason: str | None = Field(
        None, max_length=MAX_LINE, description="the server's: stop, length (cut at max_tokens), ..."
    )
    schema_hash: str | None = Field(
        None, max_length=MAX_LINE, description="with --structured: hash of the JSON Schema the reply had to follow"
    )
    ttft: float | None = Field(
        None,
        ge=0.0,
        allow_inf_nan=False,
        description="seconds to the reply's first token (prompt processing, mostly), where it was streamed",
    )
    coordination: Coordination | None = Field(
        None, description="what the team's protocol decided for this robot (absent under the paper's protocol)"
    )

    @model_serializer(mode="wrap")
    def _no_empty_coordination(self, handler: SerializerFunctionWrapHandler) -> Any:
        """A thought without coordination is written as before the field existed, byte for byte."""
        data = handler(self)
        if isinstance(data, dict) and data.get("coordination") is None:
            data.pop("coordination", None)
        return data


class Generating(Message):
    """A robot's model call that is taking a while, as the server has answered it so far: live
    status for the console (`mhrc up`), sent every few seconds of a long call; not recorded."""

    kind: Literal["generating"] = "generating"
    robot: str = Field(max_length=MAX_NAME)
    tick: int = Field(ge=0, le=MAX_INT)
    elapsed: float = Field(ge=0.0, allow_inf_nan=False, description="seconds since the call began, retries included")
    tokens: int = Field(
        0,
        ge=0,
        le=MAX_INT,
        description="tokens streamed so far in this attempt (0: the server is still reading the prompt)",
    )
    attempt: int = Field(1, ge=0, le=MAX_INT, description="HTTP attempt of this call (retries included)")
