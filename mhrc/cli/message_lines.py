"""One line per bus message, as `mhrc bus echo` prints it: every sample decoded with
`mhrc.core.protocol` by its `kind` (`MODELS`, built from the protocol's own message classes, so a
new message is known at once) and summed up by `one_line`; a payload that is not JSON, of no
known kind or not a valid message is said to be so (`describe_sample` never raises). A
participant's text is cleaned of escape sequences and clipped (`clip`) before it reaches the terminal.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from mhrc.core.bus import Sample
from mhrc.core.printable import printable
from mhrc.core.protocol import (
    PROTOCOL_VERSION,
    ActionAck,
    ActionRequest,
    ActionResult,
    AttachReply,
    AttachRequest,
    EpisodeDone,
    EpisodeStarted,
    Message,
    ProtocolError,
    RobotAttached,
    RobotDetached,
    RobotMessage,
    Snapshot,
    Thought,
    TickClosed,
    Turn,
    WorldState,
    decode,
)

SUMMARY_CHARS = 240


def _message_models() -> dict[str, type[Message]]:
    """kind -> model, for every protocol message that has a `kind` (new ones included)."""
    models: dict[str, type[Message]] = {}
    todo: list[type[Message]] = [Message]
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        kind = cls.model_fields.get("kind")
        if kind is not None and isinstance(kind.default, str):
            models.setdefault(kind.default, cls)
    return models


MODELS = _message_models()


def clip(text: str, n: int = SUMMARY_CHARS) -> str:
    text = " ".join(printable(text).split())  # a participant's text: no escape sequence reaches the terminal
    return text if len(text) <= n else text[: n - 1] + "…"


def one_line(msg: BaseModel) -> str:
    """One line about a protocol message: who, what, how it went."""
    if isinstance(msg, ActionRequest):
        return f"{msg.robot} {msg.action.call()} tick {msg.tick} goal {msg.goal_id}"
    if isinstance(msg, ActionAck):
        return f"{msg.robot} goal {msg.goal_id} " + ("accepted" if msg.accepted else f"rejected: {msg.reason}")
    if isinstance(msg, ActionResult):
        o = msg.outcome
        how = "succeeded" if o.succeeded else f"failed ({o.code.value})"
        return f"{msg.robot} {msg.action.call()} {how} tick {msg.tick}{' done' if msg.done else ''}: {o.feedback}"
    if isinstance(msg, RobotMessage):
        return f"{msg.sender} -> {msg.to} tick {msg.tick}: {msg.content}"
    if isinstance(msg, Thought):
        what = msg.action or (f"parse error: {msg.parse_error}" if msg.parse_error else "no action")
        tokens = (
            f", {msg.prompt_tokens}+{msg.completion_tokens} tokens"
            if msg.prompt_tokens or msg.completion_tokens
            else ""
        )
        return f"{msg.robot} tick {msg.tick} ({msg.policy}{tokens}): {what}"
    if isinstance(msg, EpisodeStarted):
        return (
            f"{msg.run}: {msg.task} in {msg.scene}, seed {msg.seed}, {msg.n_objects} objects, robots {', '.join(msg.robots)}, "
            f"{msg.scheduler}, horizon {msg.horizon}, fidelity {msg.fidelity}"
        )
    if isinstance(msg, TickClosed):
        acts = ", ".join(f"{r} {a}{'' if msg.outcomes.get(r, True) else ' (failed)'}" for r, a in msg.actions.items())
        return f"tick {msg.tick}: {acts}; placed {msg.placed}/{msg.total}"
    if isinstance(msg, RobotAttached):
        return f"{msg.robot} attached (agent {msg.agent_id}) at tick {msg.tick}"
    if isinstance(msg, RobotDetached):
        return f"{msg.robot} detached at tick {msg.tick}: {msg.reason}"
    if isinstance(msg, EpisodeDone):
        m = msg.metrics
        return f"{msg.run} ended ({msg.reason}): success={m.success} placed {m.placed}/{m.total} TS {m.temporal_steps} AS {m.action_steps}"
    if isinstance(msg, Snapshot):
        return f"tick {msg.tick}: {len(msg.robots)} robots, {len(msg.objects)} objects, goals {', '.join(msg.goals) or 'none'}"
    if isinstance(msg, WorldState):
        return (
            f"{msg.run}: {msg.task} in {msg.scene}, tick {msg.tick}/{msg.horizon}, placed {msg.placed}/{msg.total}, "
            f"attached {', '.join(msg.attached) or 'none'}"
        )
    if isinstance(msg, AttachRequest):
        return f"{msg.robot} (agent {msg.agent_id})"
    if isinstance(msg, AttachReply):
        return f"{msg.robot} " + ("accepted" if msg.accepted else f"refused: {msg.reason}") + f" at tick {msg.tick}"
    if isinstance(msg, Turn):
        return f"{msg.robot} tick {msg.tick}"
    return clip(msg.model_dump_json())


@dataclass(frozen=True)
class Decoded:
    """One sample as echo shows it."""

    kind: str  # the message kind, or `delete`, `not-json`, `json`, `invalid:<kind>`
    summary: str
    msg: Any  # the payload's JSON (or {"raw": text}); None for a delete
    error: str | None = None


def describe_sample(sample: Sample) -> Decoded:
    """Decode one sample with the protocol; never raises."""
    if not sample.is_put:
        return Decoded("delete", "", None)
    try:
        msg: Any = json.loads(sample.payload)
    except (ValueError, UnicodeDecodeError):
        text = sample.payload.decode("utf-8", "replace")
        return Decoded(
            "not-json",
            f"undecodable payload ({len(sample.payload)} bytes): {clip(repr(sample.payload), 120)}",
            {"raw": text},
            "not JSON",
        )
    kind = msg.get("kind") if isinstance(msg, dict) else None
    model = MODELS.get(kind) if isinstance(kind, str) else None
    if model is None:
        what = f"unknown kind {kind!r}" if kind is not None else "JSON without a protocol kind"
        return Decoded("json", f"{what}: {clip(json.dumps(msg), 160)}", msg)
    try:
        return Decoded(str(kind), clip(one_line(decode(sample.payload, model))), msg)
    except ProtocolError as exc:
        return Decoded(
            f"invalid:{kind}",
            f"not a valid {kind} (protocol v{PROTOCOL_VERSION}): {clip(str(exc), 160)}",
            msg,
            str(exc),
        )
    except Exception as exc:  # a summary that tripped on an odd but valid message: still one line
        return Decoded(str(kind), clip(f"{type(exc).__name__}: {exc}"), msg)
