"""Partial observability, checked from a trace alone: no robot's observation names an object the
robot had no way of knowing.

The world keeps each robot's memory (world/observe.py); this module does not ask it. It rebuilds,
from what the trace shows, every way a robot can come to know an object, and reports each object
in an observation that none of them explains (a `Leak`):

- it saw it: the object lay, by the world's snapshots, on the furniture the robot stands at (the
  target of its last navigation, also one that stopped off target beside it, or of the container
  it opened; a fixed arm's table and the fixtures on it), not inside a closed container; or the
  robot held it;
- it was told: the object is named in a message delivered to the robot, or in the feedback of
  one of its own actions (what it found on arriving, what an opened container held).

An observation is checked against the snapshots just before and just after it (a tick's actions
and its snapshot may reach the trace in either order). Episodes with the `live_state` aid give
every robot the truth and are not checked. Old traces without snapshots cannot be checked
either: `check` says so rather than passing them."""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

from mhrc.core.protocol import ActionResult, EpisodeStarted, Observation, OutcomeCode, RobotMessage, Snapshot, Turn
from mhrc.core.records import TraceLine


class Unchecked(StrEnum):
    """Why a trace was not checked."""

    LIVE_STATE = "live_state"  # the aid shows every robot the truth
    NO_SNAPSHOTS = "no_snapshots"  # nothing to tell what lay where


@dataclass(frozen=True)
class Leak:
    """`obj` was in `robot`'s observation for `tick` (from its action's result, or its turn) though
    nothing in the trace lets the robot know it."""

    robot: str
    tick: int
    obj: str
    source: str  # "result" or "turn"


@dataclass(frozen=True)
class Report:
    leaks: list[Leak]
    observations: int  # how many observations were checked
    unchecked: Unchecked | None = None


def _names_in(text: str, names: Iterable[str]) -> set[str]:
    """The object names `text` mentions, written with underscores or spaces, in any case."""
    flat = re.sub(r"[\s_]+", "_", text.lower())
    return {n for n in names if re.search(rf"(?<![a-z0-9]){re.escape(n.lower())}(?![a-z0-9])", flat)}


@dataclass
class _Robot:
    at: str | None = None
    known: set[str] = field(default_factory=set)


def _arm_table(obs: Observation) -> str | None:
    """A fixed arm's table: the furniture its fixtures lie on ("tray on table_0")."""
    if obs.status.base is not None:
        return None
    for f in obs.furniture:
        if " on " in f.kind:
            return f.kind.rsplit(" on ", 1)[1]
    return None


def _looks(result: ActionResult) -> bool:
    """Whether the robot now stands at its action's target and sees it: it arrived (on target, or
    stopped off target beside it: the world lets it look, world/skills/navigation.py), or it
    opened a container."""
    skill, code = result.action.skill, result.outcome.code
    return (skill == "navigate" and (result.outcome.succeeded or code is OutcomeCode.OFF_TARGET)) or (
        skill == "open" and result.outcome.succeeded
    )


def _visible(snap: Snapshot | None, places: set[str]) -> set[str]:
    if snap is None:
        return set()
    out = set()
    for name, o in snap.objects.items():
        if o.on in places and (not o.inside or snap.open.get(o.on, False)):
            out.add(name)
    return out


def check(lines: Sequence[TraceLine]) -> Report:
    """Every observation in the trace against what its robot could know (module docstring)."""
    started = next((ln.msg for ln in lines if isinstance(ln.msg, EpisodeStarted)), None)
    if started is not None and "live_state" in started.aids:
        return Report([], 0, Unchecked.LIVE_STATE)
    snaps = [ln.msg for ln in lines if isinstance(ln.msg, Snapshot)]
    if not snaps:
        return Report([], 0, Unchecked.NO_SNAPSHOTS)
    everything = {n for snap in snaps for n in snap.objects}
    fixtures: dict[str, set[str]] = {}  # table -> the fixtures on it
    robots: dict[str, _Robot] = {}
    leaks: list[Leak] = []
    checked = 0
    last: Snapshot | None = None
    passed = 0  # snapshots before the current line
    for ln in lines:
        msg = ln.msg
        if isinstance(msg, Snapshot):
            last, passed = msg, passed + 1
            continue
        if isinstance(msg, RobotMessage):
            robots.setdefault(msg.to, _Robot()).known |= _names_in(msg.content, everything)
            continue
        if isinstance(msg, ActionResult):
            obs, source = msg.observation, "result"
            me = robots.setdefault(msg.robot, _Robot())
            me.known |= _names_in(msg.outcome.feedback, everything)
            if _looks(msg):
                me.at = getattr(msg.action, "target", None)
        elif isinstance(msg, Turn):
            obs, source = msg.observation, "turn"
            me = robots.setdefault(msg.robot, _Robot())
        else:
            continue
        if obs is None:
            continue
        table = _arm_table(obs)
        if table is not None:
            me.at = table
            fixtures[table] = {f.name for f in obs.furniture if f.kind.endswith(f" on {table}")}
        for m in obs.new_messages:
            me.known |= _names_in(m.content, everything)
        if obs.status.holding:
            me.known.add(obs.status.holding)
        after = snaps[passed] if passed < len(snaps) else None  # the first snapshot after this line
        places = {me.at, *fixtures.get(me.at, set())} if me.at is not None else set()
        me.known |= _visible(last, places) | _visible(after, places)
        checked += 1
        leaks.extend(Leak(obs.robot, obs.tick, o.name, source) for o in obs.objects if o.name not in me.known)
    return Report(leaks, checked)
