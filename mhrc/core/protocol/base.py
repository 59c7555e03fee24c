"""The base of every payload: the protocol version, `Message`, the codec (`encode`, `decode`) and
`ProtocolError`, the one error a malformed payload raises."""

from __future__ import annotations

from typing import Literal, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

PROTOCOL_VERSION = 2  # 2: the world's `snapshot` event; every version-1 message is still valid
SUPPORTED_VERSIONS = (1, 2)


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


def decode(data: bytes | str, model: type[M]) -> M:
    """Parse `data` as `model`, raising ProtocolError with a readable reason."""
    try:
        return model.model_validate_json(data)
    except ValidationError as exc:
        raise ProtocolError(_reason(exc)) from None


def _reason(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors()[:5]:
        loc = ".".join(str(p) for p in err["loc"]) or "payload"
        parts.append(f"{loc}: {err['msg']}")
    return "; ".join(parts)
