"""The base of every payload: the protocol version, `Message`, the codec (`encode`, `decode`) and
`ProtocolError`, the one error a malformed payload raises."""

from __future__ import annotations

import json
from typing import Any, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError
from pydantic_core import from_json

PROTOCOL_VERSION = 2  # 2: the world's `snapshot` event; every version-1 message is still valid
SUPPORTED_VERSIONS = (1, 2)

# Bounds on what participants send (docs/protocol.md, "Limits"): a login may not make the world
# echo, log or record more than these, however much it sends.
MAX_NAME = 64  # characters of a name (robot, furniture, object, recipient) and of a goal id: the shipped layouts' longest is 13
MAX_AGENT_ID = 128  # characters of an agent id: room for a prefix and a whole uuid, twice
MAX_INT = 2**31 - 1  # ticks and stand-pose indices: a horizon is at most 1000; fits a 32-bit int in any language
MAX_MOVE = 100.0  # metres a move may ask along each axis: ten times any house's span (a longer one could only fail), and printable
MAX_REQUEST_BYTES = (
    64 * 1024
)  # an action or attach request: the longest well-formed one (a 4,000-character message, every character escaped) is under 50 kB
_MAX_MSG = (
    200  # characters of each error in a ProtocolError's reason: pydantic quotes the input in some (a union's tag)
)


class ProtocolError(ValueError):
    """A payload that is not a valid message of the expected kind."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Message(_Model):
    """Base of every top-level bus payload: carries the protocol version."""

    v: Literal[1, 2] = 2  # PROTOCOL_VERSION; a version-1 message reads as it always did


M = TypeVar("M", bound=BaseModel)


def encode(model: BaseModel) -> bytes:
    return model.model_dump_json().encode()


def decode(data: bytes | str, model: type[M], *, max_bytes: int | None = None) -> M:
    """Parse `data` as `model`, raising ProtocolError with a readable reason; with `max_bytes`, a
    longer payload is refused before it is parsed. pydantic's parser bounds the nesting itself
    (a few hundred levels: deeper is a ProtocolError, not a RecursionError)."""
    if max_bytes is not None and len(data) > max_bytes:
        raise ProtocolError(f"payload: {len(data)} bytes, more than the {max_bytes} this message may have")
    try:
        return model.model_validate_json(data)
    except ValidationError as exc:
        raise ProtocolError(_reason(exc)) from None


def loads(data: bytes | str) -> Any:
    """Any JSON document, for readers that take every kind (the recorder), or ProtocolError: never
    a RecursionError (Python's parser raises it on a deeply nested document) nor another error.
    pydantic's parser reads it first (about twice as fast); what it refuses, Python's reads or
    refuses (it takes a little more: nesting past 200 levels, an unpaired surrogate's escape), so
    what this accepts is what json.loads accepts, as json.loads reads it."""
    try:
        return from_json(data)
    except ValueError:
        pass
    try:
        return json.loads(data)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise ProtocolError(f"payload: not JSON ({type(exc).__name__}: {str(exc)[:_MAX_MSG]})") from None


def _reason(exc: ValidationError, within: str | None = None) -> str:
    """The errors of `exc`, readably; `within`: the union's tag the model was validated under (its errors
    read as the union's would)."""
    parts = []
    for err in exc.errors()[:5]:
        loc = ".".join(str(p) for p in ((within,) if within else ()) + tuple(err["loc"]))[:_MAX_MSG] or "payload"
        msg = err["msg"] if len(err["msg"]) <= _MAX_MSG else err["msg"][:_MAX_MSG] + "..."
        parts.append(f"{loc}: {msg}")
    return "; ".join(parts)
