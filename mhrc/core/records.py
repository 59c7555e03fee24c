"""A trace read back as typed records: each line decoded once, its message into the protocol's model.

A trace (mhrc.core.trace, the recorder) is JSONL, one line per bus sample: `{"t", "key", "kind",
"msg"}`. `read_records` turns each line into a `TraceLine`: its kind a `LineKind`, and for a
`put` its message decoded into the protocol's model its `kind` names (`action_result`: an
`ActionResult`, as on `.../action/result`; `snapshot`: a `Snapshot`, as on `.../world/event`; ...). What machines branch on is decided here, once, as codes:
a thought's `failure` (`ReplyFailure`, as the thought carries it) and a junk line's count (`JunkCount`,
with its `RejectCode`). Lines of older traces are brought to today's shape first
(mhrc.core.upgrade).

A line that is not a trace line raises `TraceLineError` (a code, the file and the line number). A
`put` whose message does not fit its model (anything may be published under a run's keys) is kept, with `msg`
None, the kind it names in `named` and the reason in `problem`: a trace records the bus, junk included.
A line's JSON is not kept: readers read the decoded (and upgraded) message, never the text as written.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar, Union, get_args

from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, ValidationError

from mhrc.core.protocol import (
    ActionAck,
    ActionRequest,
    ActionResult,
    EpisodeDone,
    EpisodeStarted,
    ProtocolError,
    RejectCode,
    RobotAttached,
    RobotDetached,
    RobotMessage,
    ScenarioEvent,
    Snapshot,
    Thought,
    TickClosed,
    Turn,
)
from mhrc.core.protocol.base import PROTOCOL_VERSION, loads
from mhrc.core.protocol.thoughts import ReplyFailure
from mhrc.core.upgrade import upgrade

Payload = Union[
    ActionRequest,
    ActionAck,
    ActionResult,
    Turn,
    RobotMessage,
    Thought,
    EpisodeStarted,
    TickClosed,
    RobotAttached,
    RobotDetached,
    EpisodeDone,
    Snapshot,
    ScenarioEvent,
]
M = TypeVar("M", bound=BaseModel)


class LineKind(StrEnum):
    """What a trace line records (mhrc.core.trace)."""

    PUT = "put"  # a message published
    DELETE = "delete"  # a key deleted
    ALIVE = "alive"  # a liveliness token declared
    GONE = "gone"  # a liveliness token gone
    JUNK = "junk"  # malformed requests or rejections, counted, not copied
    INCOMPLETE = "incomplete"  # the recording stopped (a failed write): the trace is cut short


class NotCopied(StrEnum):
    """Why the recorder counted well-formed payloads instead of copying them (beside the world's
    RejectCode for requests it rejected)."""

    THOUGHTS_AHEAD = "thoughts_ahead"  # a robot's thoughts far beyond its action requests (mhrc.core.trace)


class JunkCount(BaseModel):
    """A `junk` line: the malformed requests (or rejections past the ones copied in full) of one key
    and interval, counted by the recorder."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    count: int
    bytes: int
    reason: str
    code: RejectCode | NotCopied | None = None  # the rejection's code (malformed for a malformed request), or NotCopied
    excerpt: str | None = None  # the start of the first malformed payload


class LineError(StrEnum):
    """Why a line is not a trace line."""

    NOT_JSON = "not_json"
    NOT_A_LINE = "not_a_line"  # JSON, but not an object with t, key, kind and msg
    UNKNOWN_KIND = "unknown_kind"


class TraceLineError(ValueError):
    """A line of a trace file that is not a trace line: `code` says why, the message names the line."""

    def __init__(self, code: LineError, line: int, detail: str, path: Path | None = None) -> None:
        self.code, self.line, self.detail, self.path = code, line, detail, path
        where = f"{path}, line {line}" if path is not None else f"line {line}"
        super().__init__(f"{where} is not a trace line ({code.value}): {detail}")


@dataclass(frozen=True)
class TraceLine:
    """One line of a trace, decoded (module docstring)."""

    number: int  # 1-based, in the file (blank lines counted)
    t: float  # seconds since the recording started
    key: str
    kind: LineKind
    msg: Payload | None = None  # a put's message, as its key's model
    failure: ReplyFailure | None = None  # a thought's, when its step gave no action
    junk: JunkCount | None = None  # a junk line's count
    problem: str | None = None  # why a put's message did not decode as the model its kind names (msg is then None)
    named: str | None = None  # the protocol kind (a key of MODELS) the line's message names, decoded or not


MODELS: dict[str, type[Payload]] = {  # a message's `kind` -> its model (the key it travels on says the same)
    m.model_fields["kind"].default: m for m in get_args(Payload)
}


def _model_of(msg: Any) -> type[Payload] | None:
    """The model a message names by its `kind`, or None for one that names none of the recorded kinds."""
    kind = msg.get("kind") if isinstance(msg, dict) else None
    return MODELS.get(kind) if isinstance(kind, str) else None


def _reason(exc: ValidationError, msg: Any = None) -> str:
    """What did not fit, and for a message of a newer protocol version than this mhrc's, that it is newer."""
    first = exc.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "msg"
    more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
    v = msg.get("v") if isinstance(msg, dict) else None
    newer = (
        f" (protocol version {v}, newer than this mhrc's {PROTOCOL_VERSION}: upgrade mhrc to read it)"
        if isinstance(v, int) and not isinstance(v, bool) and v > PROTOCOL_VERSION
        else ""
    )
    return f"{where}: {first['msg'][:200]}{more}{newer}"


def _decode(decoder: Callable[[Any], Payload], msg: Any) -> Payload:
    """`decoder(msg)`, reading strings longer than today's bounds as they were: the bounds (docs/protocol.md,
    "Limits") are what the world admits now, and an older world executed what it was sent. Such a string is
    cut to fit for validation, then put back into the model."""
    try:
        return decoder(msg)
    except ValidationError as exc:
        long = [e["loc"] for e in exc.errors() if e["type"] == "string_too_long"]
        if not long or len(long) < exc.error_count():
            raise
    fitted = copy.deepcopy(msg)
    restore: list[tuple[tuple[str | int, ...], str]] = []
    for loc in long:
        holder: Any = fitted
        for part in loc[:-1]:
            if isinstance(part, int) or part in holder:  # a union's tag is no key
                holder = holder[part]
        restore.append((loc, holder[loc[-1]]))
        holder[loc[-1]] = holder[loc[-1]][:1]
    payload = decoder(fitted)
    for loc, value in restore:
        payload = _put_back(payload, [p for p in loc], value)
    return payload


def _put_back(model: Any, loc: list[str | int], value: str) -> Any:
    """`model` with the field at `loc` (a validation error's location) set to `value`, unvalidated."""
    while loc and isinstance(model, BaseModel) and not (isinstance(loc[0], str) and loc[0] in type(model).model_fields):
        loc = loc[1:]  # a union's tag
    if not loc:
        return value
    head, rest = loc[0], loc[1:]
    if isinstance(model, BaseModel):
        assert isinstance(head, str)
        return model.model_copy(update={head: _put_back(getattr(model, head), rest, value)})
    if isinstance(model, list):
        assert isinstance(head, int)
        return [_put_back(v, rest, value) if i == head else v for i, v in enumerate(model)]
    if isinstance(model, dict):
        return {**model, head: _put_back(model[head], rest, value)}
    return model


def decode_row(row: Any, number: int) -> TraceLine:
    """One trace line from its JSON (a dict as `json.loads` reads it); TraceLineError if it is none."""
    if not isinstance(row, Mapping) or not isinstance(row.get("key"), str) or "msg" not in row:
        raise TraceLineError(LineError.NOT_A_LINE, number, "not an object with a string `key` and a `msg`")
    t = row.get("t")
    if isinstance(t, bool) or not isinstance(t, (int, float)):
        raise TraceLineError(LineError.NOT_A_LINE, number, f"`t` is {t!r}, not a number of seconds")
    try:
        t = float(t)
    except OverflowError:  # an integer of 309 digits or more: no float holds it
        raise TraceLineError(LineError.NOT_A_LINE, number, "`t` is too large for a number of seconds") from None
    try:
        kind = LineKind(str(row.get("kind")))
    except ValueError:
        raise TraceLineError(LineError.UNKNOWN_KIND, number, f"`kind` is {str(row.get('kind'))[:40]!r}") from None
    key, msg = row["key"], upgrade(kind.value, row["msg"])
    if kind is LineKind.JUNK:
        try:
            return TraceLine(number, float(t), key, kind, junk=JunkCount.model_validate(msg))
        except ValidationError as exc:
            return TraceLine(number, float(t), key, kind, problem=_reason(exc))
    model = _model_of(msg)
    named = model.model_fields["kind"].default if model is not None else None
    if model is None or kind is not LineKind.PUT:
        return TraceLine(number, float(t), key, kind, named=named)
    try:
        payload = _decode(model.model_validate, msg)
    except ValidationError as exc:
        return TraceLine(number, float(t), key, kind, problem=_reason(exc, msg), named=named)
    failure = payload.failure if isinstance(payload, Thought) else None
    return TraceLine(number, float(t), key, kind, msg=payload, failure=failure, named=named)


class _Put(BaseModel):
    """A `put` line as this mhrc's recorder writes it, validated from its text in one pass
    (`parse_line`'s fast path): what `decode_row` reads of it, nothing more."""

    t: StrictFloat | StrictInt  # a number, never a boolean (decode_row's rule)
    key: str
    kind: Literal["put"]
    msg: Annotated[Payload, Field(discriminator="kind")]


# an integer of 309 digits or more is no float: Python's validation refuses it, pydantic's JSON parser reads inf;
# a line's bytes with every digit a 0 and any other byte a space hold such a run where they hold _HUGE
_DIGITS = bytes(0x30 if 0x30 <= b <= 0x39 else 0x20 for b in range(256))
_HUGE = b"0" * 309


def _put(text: str, number: int) -> TraceLine | None:
    """The line `decode_row` would make of `text`, when it is a put of today's shape whose message fits
    its model; None for any other line (read the long way). A message `upgrade` would change (an older
    trace's), or whose model is a start's, is left to the long way too, and so is a line with a run of
    digits too long for a float (the two validators read it differently)."""
    if _HUGE in text.encode("utf-8", "surrogatepass").translate(_DIGITS):  # a regular expression costs 7x
        return None
    try:
        line = _Put.model_validate_json(text)
    except ValidationError:
        return None
    msg = line.msg
    if isinstance(msg, EpisodeStarted):
        return None
    if isinstance(msg, Thought) and "failure" not in msg.model_fields_set and msg.parse_error:
        return None
    if isinstance(msg, ActionAck) and msg.accepted is False and msg.code is None:
        return None
    failure = msg.failure if isinstance(msg, Thought) else None
    return TraceLine(number, float(line.t), line.key, LineKind.PUT, msg=msg, failure=failure, named=msg.kind)


def parse_line(text: str, number: int) -> TraceLine:
    """One line of a trace file; TraceLineError if it is not a trace line. A put of today's shape is
    validated from its text (`_put`, the same TraceLine in about half the time), any other the long way."""
    if (fast := _put(text, number)) is not None:
        return fast
    try:
        row = loads(text)
    except ProtocolError as exc:
        raise TraceLineError(LineError.NOT_JSON, number, str(exc).removeprefix("payload: ")) from None
    return decode_row(row, number)


def read_records(path: str | Path) -> list[TraceLine]:
    """Every line of the trace file `path`, decoded (blank lines skipped). Raises TraceLineError
    naming the file and line for a line that is not a trace line, OSError if it cannot be read."""
    p = Path(path)
    out = []
    with p.open(encoding="utf-8") as f:
        for number, text in enumerate(f, 1):
            if not text.strip():
                continue
            try:
                out.append(parse_line(text, number))
            except TraceLineError as exc:
                raise TraceLineError(exc.code, exc.line, exc.detail, p) from None
    return out


def messages(lines: Iterable[TraceLine], model: type[M]) -> list[M]:
    """The messages of type `model` published in `lines`, in trace order."""
    return [line.msg for line in lines if line.kind is LineKind.PUT and isinstance(line.msg, model)]
