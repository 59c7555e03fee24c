"""Each robot's task text by its role, as the paper's appendix gives Alice, Bob and David each
their own brief and detail: the finisher (Bob) gets the list and whom to ask, the fetcher
(Alice) and the scout (David) their part in bringing the list's things to the finisher. The
words are ours; the content is the appendix's, nothing more.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol

Role = Literal["finisher", "fetcher", "scout"]


@dataclass(frozen=True)
class Briefing:
    """Who a robot's task text names: the robot that finishes the task (the paper's Bob), the
    one that fetches for it (Alice; a team's several fetchers as one of them, `either`: "Alice
    or Carol"), and the finisher's table."""

    finisher: str
    fetcher: str
    table: str


def either(names: Sequence[str]) -> str:
    """`Alice`, `Alice or Carol`, `Alice, Carol or Frank`: whom the task texts send a robot to
    when any of several will do."""
    names = list(names)
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def role_of(finishes_task: bool, mobile: bool, has_arm: bool) -> Role:
    """A robot kind's part in the paper's team: the finisher (Bob), a fetcher that navigates and
    manipulates (Alice) or a scout that only navigates (David)."""
    if finishes_task:
        return "finisher"
    return "fetcher" if mobile and has_arm else "scout"


class Briefed(Protocol):
    """What the role texts read of a task (world.tasks.Task has it)."""

    @property
    def things(self) -> str: ...
    def finisher_brief(self) -> str: ...
    def finisher_detail(
        self, b: Briefing, targets: list[str], goals: dict[str, str], aids: frozenset[str] = frozenset()
    ) -> str: ...


def brief(task: Briefed, role: Role, b: Briefing) -> str:
    """A robot's brief, as the appendix gives each role its own."""
    if role == "finisher":
        return task.finisher_brief()
    if role == "fetcher":
        return f"Explore the whole house and hand {b.finisher} the {task.things} the task needs."
    return f"Search the whole house for the {task.things} the task needs."


def detail(
    task: Briefed,
    role: Role,
    b: Briefing,
    targets: list[str],
    goals: dict[str, str],
    aids: frozenset[str] = frozenset(),
) -> str:
    """A robot's detailed task: the finisher's list and whom to ask; the fetcher's and the
    scout's part in getting the list's things to the finisher (the appendix's Task sections)."""
    if role == "finisher":
        return task.finisher_detail(b, targets, goals, aids)
    t, f = task.things, b.finisher
    if role == "fetcher":
        return (
            f"1. Ask {f} which {t} are needed; then search the house for them, pick them up and put them on {b.table} close to {f}. "
            f"2. When {f} asks, move {t} that lie on the table to where {f}'s arm reaches them; "
            f"do not move anything on the table unless {f} asks you to."
        )
    return f"Do as {b.fetcher} arranges: search the house, find the {t} the task needs, and tell {b.fetcher} about each new find without delay."


def ask(b: Briefing, t: str) -> str:
    """The finisher's two reasons to ask the fetcher for help (the appendix's Bob detail)."""
    return (
        f"When you cannot pick up one of them lying on the table, ask {b.fetcher} to move it for you; "
        f"when {t} on the list are missing, ask {b.fetcher} to search for them and bring them."
    )
