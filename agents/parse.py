"""Turning a model's reply into exactly one action.

Replies come in the paper's format (Command, Analysis, Reasoning, in any order: the command
line first or last), as `**Command:** navigate(table_1, stand pose 0).`, in code fences,
quoted, with trailing periods. The parser takes the first skill call after the last "Command"
label (or, without a label, the only skill call in the reply) and raises `ReplyFormatError`
with a reason the robot can act on when the reply is ambiguous or names no skill.
"""

from __future__ import annotations

import re

from mhrc.core.protocol import Action
from mhrc.core.protocol.actions import CALLS, Arg, ArgKind, build, signature

__all__ = ["ReplyFormatError", "parse_command", "signature"]

LABEL = re.compile(r"\bcommand\s*\**\s*:\s*\**\s*", re.IGNORECASE)  # "Command:", "**Command:**"
LOOSE_LABEL = re.compile(r"command\s*[:*]*\s*", re.IGNORECASE)  # "Command pick(x)", for want of a colon
MESSAGE_WORDS = ("message",)  # a text argument may also be written message=...


def skill_call() -> re.Pattern[str]:
    """A call of any declared skill (mhrc.core.protocol.actions.CALLS), up to its '('."""
    return re.compile(rf"\b({'|'.join(CALLS)})\s*\(", re.IGNORECASE)


def keyword() -> re.Pattern[str]:
    """An argument written with its name (``target=table_1``): any name of any declared argument."""
    words = {w for m in CALLS.values() for a in m.ARGS for w in (a.field, a.name, a.spoken)}
    words |= set(MESSAGE_WORDS)
    return re.compile(rf"^(?:{'|'.join(sorted(words, key=lambda w: (-len(w), w)))})\s*=\s*", re.IGNORECASE)


class ReplyFormatError(ValueError):
    """The reply does not name exactly one well-formed command."""


def _call_args(text: str, start: int) -> tuple[str, int]:
    """The raw argument text of the call whose '(' is at `start`, honouring quotes and nesting."""
    depth, quote, i = 0, "", start
    while i < len(text):
        ch = text[i]
        if quote:
            if ch == quote:
                quote = ""
        elif ch in "\"'" and (i == start + 1 or text[i - 1] in " ,(="):
            quote = ch
        elif ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
            if depth == 0:
                return text[start + 1 : i], i
        i += 1
    raise ReplyFormatError("the command's parentheses are not closed")


def _split(args: str) -> list[str]:
    out, cur, quote = [], "", ""
    for ch in args:
        if quote:
            cur += ch
            if ch == quote:
                quote = ""
        elif ch in "\"'" and (not cur.strip() or re.fullmatch(r"\s*\w+\s*=\s*", cur)):
            quote = ch
            cur += ch
        elif ch == ",":
            out.append(cur)
            cur = ""
        else:
            cur += ch
    if cur.strip() or out:
        out.append(cur)
    return [_unquote(a) for a in out]


def _unquote(a: str) -> str:
    a = keyword().sub("", a.strip().strip("`").strip())  # navigate(furniture=table_1, ...)
    if len(a) >= 2 and a[0] == a[-1] and a[0] in "\"'":
        a = a[1:-1]
    return a.strip()


def _name(a: str) -> str:
    return re.sub(r"^(the|object|furniture)\s+", "", a.strip(), flags=re.IGNORECASE).replace(" ", "_")


def _number(a: str, what: str) -> float:
    m = re.search(r"[-+]?\d+(?:\.\d+)?", a)
    if m is None:
        raise ReplyFormatError(f"{what} must be a number, got {a!r}")
    return float(m.group())


def parse_command(reply: str) -> Action:
    """The one action a reply commands, or ReplyFormatError saying what is wrong."""
    labels = list(LABEL.finditer(reply)) or list(LOOSE_LABEL.finditer(reply))
    scope = reply[labels[-1].end() :] if labels else reply
    calls = list(skill_call().finditer(scope))
    if not calls:
        raise ReplyFormatError("no command found: give one command, such as Command: pick(apple)")
    if not labels and len(calls) > 1:
        names = ", ".join(c.group(1) for c in calls)
        raise ReplyFormatError(f"several commands found ({names}): give exactly one, after 'Command:'")
    call = calls[0]
    skill = call.group(1).lower()
    raw, _ = _call_args(scope, call.end() - 1)
    args = _split(raw)
    try:
        return _build(skill, args)
    except (IndexError, ValueError) as exc:
        if isinstance(exc, ReplyFormatError):
            raise
        raise ReplyFormatError(f"{skill} got arguments {args}: {exc}") from None


def _build(skill: str, args: list[str]) -> Action:
    """The action of a call of `skill` with `args` (the written arguments, in order), by its declared form."""
    form = CALLS[skill].ARGS
    sig, n = signature(skill), len(form)
    text = next((i for i, a in enumerate(form) if a.kind is ArgKind.TEXT), None)
    if text is not None:  # a message takes the commas written in it
        if len(args) < n:
            raise ReplyFormatError(f"{skill} takes {n} arguments: {sig}")
        after = n - text - 1
        message = ", ".join(args[text : len(args) - after]).strip()
        if not message:
            raise ReplyFormatError(f"{skill} needs a non-empty message")
        args = [*args[:text], message, *args[len(args) - after :]]  # (the caller's list, as written, is kept)
    while len(args) < n and not CALLS[skill].model_fields[form[len(args)].field].is_required():
        args.append(str(CALLS[skill].model_fields[form[len(args)].field].default))  # navigate(table_1): stand pose 0
    if len(args) != n:
        raise ReplyFormatError(f"{skill} takes {n} argument(s): {sig}; got {len(args)}")
    return build(skill, {a.field: _value(a, v) for a, v in zip(form, args)})


def _value(arg: Arg, written: str) -> str | int | float:
    if arg.kind is ArgKind.STAND_POSE:
        return int(_number(written, arg.spoken))
    if arg.kind is ArgKind.OFFSET:
        return _number(written, arg.spoken)
    if arg.kind is ArgKind.TEXT:
        return written
    if arg.kind is ArgKind.TEAMMATE:
        return _name(written).lower()
    return _name(written)
