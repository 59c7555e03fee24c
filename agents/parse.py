"""Turning a model's reply into exactly one action.

Replies come in the paper's format (Command, Analysis, Reasoning, in any order: the command
line first or last), as `**Command:** navigate(table_1, stand pose 0).`, in code fences,
quoted, with trailing periods. The parser takes the first skill call after the last "Command"
label (or, without a label, the only skill call in the reply) and raises `ReplyFormatError`
with a reason the robot can act on when the reply is ambiguous or names no skill.
"""

from __future__ import annotations

import re

from mhrc.core.protocol import Action, Communicate, Move, Navigate, Open, Pick, Place, Wait

SKILL_CALL = re.compile(r"\b(navigate|move|open|pick|place|communicate|wait)\s*\(", re.IGNORECASE)
LABEL = re.compile(r"\bcommand\s*\**\s*:\s*\**\s*", re.IGNORECASE)  # "Command:", "**Command:**"
LOOSE_LABEL = re.compile(r"command\s*[:*]*\s*", re.IGNORECASE)  # "Command pick(x)", for want of a colon
KEYWORD = re.compile(
    r"^(?:furniture|target|obj|object|stand_pose_id|stand_pose|location|dx|dy|content|message|robot|to)\s*=\s*",
    re.IGNORECASE,
)

# Each skill's call form, exactly as parse_command accepts it (the prompts quote these).
SIGNATURES = {
    "navigate": "navigate(furniture, stand_pose_id)",
    "move": "move(dx, dy)",
    "open": "open(furniture)",
    "pick": "pick(object)",
    "place": "place(object, location)",
    "communicate": "communicate(content, robot)",
    "wait": "wait()",
}


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
    a = KEYWORD.sub("", a.strip().strip("`").strip())  # navigate(furniture=table_1, ...)
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
    calls = list(SKILL_CALL.finditer(scope))
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
    def need(n: int, sig: str) -> None:
        if len(args) != n:
            raise ReplyFormatError(f"{skill} takes {n} argument(s): {sig}; got {len(args)}")

    if skill == "wait":
        need(0, "wait()")
        return Wait()
    if skill == "navigate":
        if len(args) == 1:
            args.append("0")
        need(2, "navigate(furniture, stand_pose_id)")
        return Navigate(target=_name(args[0]), stand_pose=int(_number(args[1], "stand_pose_id")))
    if skill == "move":
        need(2, "move(dx, dy)")
        return Move(dx=_number(args[0], "dx"), dy=_number(args[1], "dy"))
    if skill == "open":
        need(1, "open(furniture)")
        return Open(target=_name(args[0]))
    if skill == "pick":
        need(1, "pick(object)")
        return Pick(obj=_name(args[0]))
    if skill == "place":
        need(2, "place(object, location)")
        return Place(obj=_name(args[0]), location=_name(args[1]))
    if len(args) < 2:
        raise ReplyFormatError("communicate takes 2 arguments: communicate(content, robot)")
    content = ", ".join(args[:-1]).strip()
    if not content:
        raise ReplyFormatError("communicate needs a non-empty message")
    return Communicate(content=content, to=_name(args[-1]).lower())
