"""The leader protocol's messages: one fixed sentence shape per stage, so that a person reading
a trace, or any LLM, can read them, and `parse` reads them back (a sentence of another shape is
None: it is some other message, ignored).

    self-description and bid   "alice here: mobile manipulator; I can navigate, open, pick, place. My bid to lead: 9.0."
    election (when the convener is not the winner)  "Election held by david: bob leads."
    allocation                 "Leader david assigns alice: fetch(book)."
    report (done)              "alice reports: done explore(fridge); found: soap, apple."
    report (failure)           "alice reports: failed fetch(book) (too_far); reflection: no stand pose of table_0 reaches it, another robot should try."
    report (the task)          "bob reports: the targets are bread, tomato, cheese, in this order; I take bread myself."
    report (status)            "alice reports: working on fetch(book)."   /   "alice reports: free."
    making way                 "alice asks erin: make way at counter."
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

__all__ = [
    "Assign",
    "Describe",
    "Elected",
    "Done",
    "Failed",
    "MakeWay",
    "Status",
    "TaskList",
    "assign",
    "describe",
    "done",
    "elected",
    "failed",
    "make_way",
    "parse",
    "status",
    "task_list",
]

Kind = Literal["fetch", "explore"]


@dataclass(frozen=True)
class Describe:
    robot: str
    kind: str
    skills: tuple[str, ...]
    bid: float


@dataclass(frozen=True)
class Elected:
    convener: str
    leader: str


@dataclass(frozen=True)
class Assign:
    leader: str
    robot: str
    kind: Kind
    target: str


@dataclass(frozen=True)
class Done:
    robot: str
    kind: Kind
    target: str
    found: tuple[str, ...]


@dataclass(frozen=True)
class Failed:
    robot: str
    kind: Kind
    target: str
    code: str
    reflection: str


@dataclass(frozen=True)
class TaskList:
    robot: str
    targets: tuple[str, ...]
    ordered: bool
    mine: tuple[str, ...]


@dataclass(frozen=True)
class Status:
    robot: str
    kind: Kind | None  # None: free
    target: str | None


@dataclass(frozen=True)
class MakeWay:
    robot: str  # who asks
    asked: str  # who stands at a stand pose of `furniture` that the asker must reach
    furniture: str


Said = Describe | Elected | Assign | Done | Failed | TaskList | Status | MakeWay


def describe(robot: str, kind: str, skills: list[str], bid: float) -> str:
    can = ", ".join(s for s in skills if s not in ("communicate", "wait"))
    return f"{robot} here: {kind}; I can {can or 'wait'}. My bid to lead: {bid:.1f}."


def elected(convener: str, leader: str) -> str:
    return f"Election held by {convener}: {leader} leads."


def assign(leader: str, robot: str, kind: Kind, target: str) -> str:
    return f"Leader {leader} assigns {robot}: {kind}({target})."


def done(robot: str, kind: Kind, target: str, found: list[str]) -> str:
    tail = f"; found: {', '.join(found)}" if found else ""
    return f"{robot} reports: done {kind}({target}){tail}."


def failed(robot: str, kind: Kind, target: str, code: str, reflection: str) -> str:
    return f"{robot} reports: failed {kind}({target}) ({code}); reflection: {reflection}."


def task_list(robot: str, targets: list[str], ordered: bool, mine: list[str]) -> str:
    order = ", in this order" if ordered else ""
    return f"{robot} reports: the targets are {', '.join(targets)}{order}; I take {', '.join(mine) or 'none'} myself."


def make_way(robot: str, asked: str, furniture: str) -> str:
    return f"{robot} asks {asked}: make way at {furniture}."


def status(robot: str, kind: Kind | None, target: str | None) -> str:
    return f"{robot} reports: working on {kind}({target})." if kind else f"{robot} reports: free."


_W = r"[A-Za-z0-9_]+"
_LIST = r"[A-Za-z0-9_, ]*"
_SHAPES: list[tuple[re.Pattern[str], str]] = [
    (re.compile(rf"^({_W}) here: (.+?); I can ({_LIST})\. My bid to lead: ([0-9.]+)\.$"), "describe"),
    (re.compile(rf"^Election held by ({_W}): ({_W}) leads\.$"), "elected"),
    (re.compile(rf"^Leader ({_W}) assigns ({_W}): (fetch|explore)\(({_W})\)\.$"), "assign"),
    (re.compile(rf"^({_W}) reports: done (fetch|explore)\(({_W})\)(?:; found: ({_LIST}))?\.$"), "done"),
    (re.compile(rf"^({_W}) reports: failed (fetch|explore)\(({_W})\) \(({_W})\); reflection: (.*)\.$"), "failed"),
    (re.compile(rf"^({_W}) reports: the targets are ({_LIST}?)(, in this order)?; I take ({_LIST}) myself\.$"), "task"),
    (re.compile(rf"^({_W}) reports: working on (fetch|explore)\(({_W})\)\.$"), "working"),
    (re.compile(rf"^({_W}) reports: free\.$"), "free"),
    (re.compile(rf"^({_W}) asks ({_W}): make way at ({_W})\.$"), "make_way"),
]


def _names(text: str | None) -> tuple[str, ...]:
    return tuple(n.strip() for n in (text or "").split(",") if n.strip() and n.strip() != "none")


def parse(text: str) -> Said | None:
    """The message `text` says, or None when it has none of the shapes above."""
    for pattern, shape in _SHAPES:
        m = pattern.match(text.strip())
        if m is None:
            continue
        g = m.groups()
        if shape == "describe":
            return Describe(g[0], g[1], _names(g[2]), float(g[3]))
        if shape == "elected":
            return Elected(g[0], g[1])
        if shape == "assign":
            return Assign(g[0], g[1], g[2], g[3])  # type: ignore[arg-type]
        if shape == "done":
            return Done(g[0], g[1], g[2], _names(g[3]))  # type: ignore[arg-type]
        if shape == "failed":
            return Failed(g[0], g[1], g[2], g[3], g[4])  # type: ignore[arg-type]
        if shape == "task":
            return TaskList(g[0], _names(g[1]), g[2] is not None, _names(g[3]))
        if shape == "working":
            return Status(g[0], g[1], g[2])  # type: ignore[arg-type]
        if shape == "make_way":
            return MakeWay(g[0], g[1], g[2])
        return Status(g[0], None, None)
    return None
