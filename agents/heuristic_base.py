"""What the scripted roles (heuristic.py) share: a robot's role from its skills, the fixed
shapes of their messages, geometry read from an observation, who of the team is attached and
working, and the routine of a robot that has broken down (it tells each teammate once, in a
fixed sentence, then waits until it works again).

A broken-down robot's failed actions (outcome `broken_down`) say nothing about the world, so
no role counts them as a failed pick, an unreachable stand pose or a lost object.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Literal

from mhrc.core.protocol import (
    Action,
    ActionResult,
    Communicate,
    FurnitureView,
    ObjectView,
    Observation,
    OutcomeCode,
    Wait,
)

from .policy import Decision

HANDOVER = "table_0"  # Bob's table: where fetched objects go
_NAMES = r"([A-Za-z0-9_]+(?:\s*,\s*[A-Za-z0-9_]+)*)"
REQUEST_RE = re.compile(r"bring these to table_0 within my reach:\s*" + _NAMES)
EXPLORE_RE = re.compile(r"explore these surfaces and tell me what lies on them:\s*" + _NAMES)
REPORT_RE = re.compile(r"On ([A-Za-z0-9_]+) I found")
UNREACHABLE_RE = re.compile(r"I could not reach ([A-Za-z0-9_]+)")
BREAKDOWN_RE = re.compile(r"I broke down: I can only communicate and wait until tick (\d+)")
CLAIM_RE = re.compile(r"I am fetching these:\s*" + _NAMES)
EXPLORING_RE = re.compile(r"I am exploring ([A-Za-z0-9_]+)")
HANDOFF_RE = re.compile(r"I leave these to you to fetch:\s*" + _NAMES)
MAX_GRASP_TRIES = 4
ARM_FORWARD = 0.2  # Alice's arm base sits this far ahead of her base centre (her system prompt says so)
GOOD_PICK = 0.45  # m from the arm base: the middle of the good picking range her prompt gives
MAX_MOVE = 1.0
AT_POSE_TOL = 0.15  # m: counts as standing at a stand pose (navigation may stop a little off)


Role = Literal["finisher", "fetcher", "scout"]


def role_of(skills: Iterable[str]) -> Role:
    """A robot's part in the team from what it can do: a fetcher navigates and picks (a mobile
    manipulator, the paper's Alice), the finisher picks and places without moving (the tabletop
    arm at the goal, Bob), a scout does neither or only navigates (a mobile base, a drone: David)."""
    s = set(skills)
    if {"navigate", "pick"} <= s:
        return "fetcher"
    if {"pick", "place"} <= s:
        return "finisher"
    return "scout"


def title(name: str) -> str:
    """A robot's name as a sentence addresses it (alice -> Alice)."""
    return name[:1].upper() + name[1:]


def explore_sentence(surfaces: list[str], to: str = "david") -> str:
    """What a fetcher asks a scout (EXPLORE_RE reads it back)."""
    return f"{title(to)}, please explore these surfaces and tell me what lies on them: {', '.join(surfaces)}."


def request_sentence(targets: list[str], to: str = "alice") -> str:
    """What the finisher asks a fetcher (REQUEST_RE reads it back)."""
    return f"{title(to)}, please bring these to table_0 within my reach: {', '.join(targets)}."


def report_sentence(place: str, found: list[str]) -> str:
    """What a scout (or a fetcher that explored a place it claimed) reports (REPORT_RE reads it back)."""
    return f"On {place} I found: {', '.join(found)}." if found else f"On {place} I found nothing."


def claim_sentence(objs: list[str], to: str = "") -> str:
    """A fetcher tells another that it fetches `objs` (CLAIM_RE reads it back): the other skips them."""
    return (f"{title(to)}, " if to else "") + f"I am fetching these: {', '.join(objs)}."


def exploring_sentence(place: str, to: str) -> str:
    """A fetcher tells another that it explores `place` (EXPLORING_RE reads it back): the other skips it."""
    return f"{title(to)}, I am exploring {place}."


def handoff_sentence(objs: list[str], to: str) -> str:
    """The lead fetcher hands objects it knows the place of to another fetcher (HANDOFF_RE)."""
    return f"{title(to)}, I leave these to you to fetch: {', '.join(objs)}."


def breakdown_sentence(until: int) -> str:
    """What a broken-down robot tells its teammates (BREAKDOWN_RE reads it back)."""
    return f"I broke down: I can only communicate and wait until tick {until}."


def split(items: list[str], parts: int) -> list[list[str]]:
    """`items` cut into `parts` contiguous shares, in order, as even as can be."""
    n = len(items)
    return [items[i * n // parts : (i + 1) * n // parts] for i in range(parts)]


def _names(text: str) -> list[str]:
    return [n.strip() for n in text.split(",") if n.strip()]


def _dist2(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def _furniture(obs: Observation, name: str) -> FurnitureView | None:
    return next((f for f in obs.furniture if f.name == name), None)


def _object(obs: Observation, name: str) -> ObjectView | None:
    return next((o for o in obs.objects if o.name == name), None)


def _gone(o: ObjectView | None) -> bool:
    """Not in this robot's scene graph, or looked for where it was and not there: where it is is unknown."""
    return o is None or (o.on is None and o.held_by is None)


def _on_fixture(obs: Observation, o: ObjectView) -> bool:
    """Whether `o` lies on one of the task's fixtures on Bob's table (a tray, a panel, a board):
    furniture one cannot stand at."""
    f = _furniture(obs, o.on or "")
    return f is not None and not f.stand_poses and o.on != HANDOVER


def _nearest_stand_pose(f: FurnitureView, point: tuple[float, ...]) -> int:
    return min(range(len(f.stand_poses)), key=lambda i: _dist2((f.stand_poses[i].x, f.stand_poses[i].y), point))


def goal_of(obs: Observation, target: str) -> str:
    """Where `target` must end: the observation's goal map if the world gives one (an aid),
    else the only goal fixture on Bob's table (tray, cutting board), or the panel whose colour
    the target's name carries (red_cube -> red_panel)."""
    if target in obs.goals:
        return obs.goals[target]
    fixtures = [f.name for f in obs.furniture if not f.stand_poses and f.name != HANDOVER]
    if len(fixtures) == 1:
        return fixtures[0]
    words = set(target.lower().split("_"))
    return next((f for f in fixtures if f.split("_")[0] in words), HANDOVER)


def corrective_move(obs: Observation, offset: tuple[float, float]) -> tuple[float, float] | None:
    """The base shift that puts the arm base GOOD_PICK from an object `offset` (x, y) away from
    the base centre, along the line between them; None if none is needed or it is too long."""
    b = obs.status.base
    if b is None:
        return None
    ax, ay = ARM_FORWARD * math.cos(b.yaw), ARM_FORWARD * math.sin(b.yaw)  # arm base, from the base centre
    rx, ry = offset[0] - ax, offset[1] - ay  # object from the arm base
    d = math.hypot(rx, ry)
    if d < 1e-6:
        return None
    shift = d - GOOD_PICK
    dx, dy = rx / d * shift, ry / d * shift
    if math.hypot(dx, dy) > MAX_MOVE or math.hypot(dx, dy) < 0.02:
        return None
    return round(dx, 2), round(dy, 2)


def _at_stand_pose(obs: Observation, f: FurnitureView, idx: int, tol: float = AT_POSE_TOL) -> bool:
    base = obs.status.base
    if base is None or idx >= len(f.stand_poses):
        return False
    sp = f.stand_poses[idx]
    return math.hypot(base.x - sp.x, base.y - sp.y) <= tol


def failed(result: ActionResult | None) -> bool:
    """Whether `result` is a failure that says something about the world (not a breakdown's)."""
    return result is not None and not result.outcome.succeeded and result.outcome.code != OutcomeCode.BROKEN_DOWN


@dataclass
class _RoleBase:
    """Shared bookkeeping: the last result this policy got, and its own breakdown."""

    name: str = "heuristic"
    last: ActionResult | None = None
    broken_until: int = 0  # the tick this robot works again after a breakdown
    to_tell: list[str] = field(default_factory=list)  # teammates not yet told of the breakdown
    team: list[str] = field(default_factory=list)  # every teammate seen attached, in the order first seen
    down_until: dict[str, int] = field(default_factory=dict)  # a teammate -> the tick it works again (its message)
    outbox: list[Communicate] = field(default_factory=list)  # messages decided on, sent one a step

    async def decide(self, obs: Observation) -> Decision:
        raise NotImplementedError  # each role decides its own way

    def record(self, result: ActionResult) -> None:
        self.last = result
        if result.outcome.code == OutcomeCode.BROKEN_DOWN:
            ticks = result.outcome.details.get("ticks")
            until = result.tick + (
                int(ticks) if isinstance(ticks, (int, float)) else 1
            )  # without the count: try again next tick
            if self.broken_until <= result.tick:  # a new breakdown: everyone is to hear of it
                self.to_tell = list(self.team)
            self.broken_until = max(self.broken_until, until)

    def _broken_down(self, obs: Observation) -> Decision | None:
        """While this robot is broken down: tell each teammate once, then wait it out."""
        if obs.tick >= self.broken_until:
            return None
        while self.to_tell:
            to = self.to_tell.pop(0)
            if to != obs.robot and to in obs.teammates:
                return self._decision(Communicate(to=to, content=breakdown_sentence(self.broken_until)))
        return self._decision(Wait())

    def _decision(self, action: Action) -> Decision:
        return Decision(action=action)

    # ---- the team, as this robot's observations and messages show it
    def _meet(self, obs: Observation) -> None:
        """Note the teammates attached now (in the world's order: the team's execution order) and
        the breakdowns they told of."""
        for name in obs.teammates:
            if name not in self.team:
                self.team.append(name)
        for m in obs.new_messages:
            if (hit := BREAKDOWN_RE.search(m.content)) is not None:
                self.down_until[m.sender] = int(hit.group(1))

    @staticmethod
    def _with_role(obs: Observation, role: Role) -> list[str]:
        """The attached teammates of `role`, in name order (the team's tie-break)."""
        return sorted(n for n, skills in obs.teammates.items() if role_of(skills) == role)

    def _works(self, obs: Observation, name: str) -> bool:
        """`name` is attached and not broken down (as far as its messages say)."""
        return name in obs.teammates and obs.tick >= self.down_until.get(name, 0)

    def _send(self, obs: Observation, messages: list[Communicate]) -> Decision | None:
        """Send the first of `messages` now, the rest at the next steps (one action a step)."""
        self.outbox.extend(messages)
        return self._flush(obs)

    def _flush(self, obs: Observation) -> Decision | None:
        """The next message decided on earlier, if any (one to a robot no longer attached is dropped)."""
        while self.outbox:
            message = self.outbox.pop(0)
            if message.to in obs.teammates:
                return self._decision(message)
        return None

    def _last_failed(self, skill: str) -> bool:
        return failed(self.last) and self.last is not None and self.last.action.skill == skill
