"""What the scripted roles (heuristic.py) share: the fixed shapes of their messages, geometry
read from an observation, and the routine of a robot that has broken down (it tells each
teammate once, in a fixed sentence, then waits until it works again).

A broken-down robot's failed actions (outcome `broken_down`) say nothing about the world, so
no role counts them as a failed pick, an unreachable stand pose or a lost object.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

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
ORDER = ("alice", "bob", "david")  # whom a broken-down robot tells first
_NAMES = r"([A-Za-z0-9_]+(?:\s*,\s*[A-Za-z0-9_]+)*)"
REQUEST_RE = re.compile(r"bring these to table_0 within my reach:\s*" + _NAMES)
EXPLORE_RE = re.compile(r"explore these surfaces and tell me what lies on them:\s*" + _NAMES)
REPORT_RE = re.compile(r"On ([A-Za-z0-9_]+) I found")
UNREACHABLE_RE = re.compile(r"I could not reach ([A-Za-z0-9_]+)")
BREAKDOWN_RE = re.compile(r"I broke down: I can only communicate and wait until tick (\d+)")
MAX_GRASP_TRIES = 4
ARM_FORWARD = 0.2  # Alice's arm base sits this far ahead of her base centre (her system prompt says so)
GOOD_PICK = 0.45  # m from the arm base: the middle of the good picking range her prompt gives
MAX_MOVE = 1.0
AT_POSE_TOL = 0.15  # m: counts as standing at a stand pose (navigation may stop a little off)


def explore_sentence(surfaces: list[str]) -> str:
    """What Alice asks David (EXPLORE_RE reads it back)."""
    return f"David, please explore these surfaces and tell me what lies on them: {', '.join(surfaces)}."


def breakdown_sentence(until: int) -> str:
    """What a broken-down robot tells its teammates (BREAKDOWN_RE reads it back)."""
    return f"I broke down: I can only communicate and wait until tick {until}."


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
                self.to_tell = list(ORDER)
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

    def _arrived(self, obs: Observation, teammate: str) -> bool:
        """Whether `teammate` is present now and was not at this robot's previous step (it
        joined, or its agent was replaced); tracks presence in `<teammate>_here`."""
        here = teammate in obs.teammates
        before = getattr(self, f"{teammate}_here")
        setattr(self, f"{teammate}_here", here)
        return here and not before and self.last is not None

    def _last_failed(self, skill: str) -> bool:
        return failed(self.last) and self.last is not None and self.last.action.skill == skill
