"""One robot per stand pose (a world rule of every team but the paper's): how the scripted roles
(heuristic.py) make room for each other, over messages only, as a real team would.

A robot whose `navigate` is refused because another robot stands at the stand pose (outcome
`occupied`, the occupant named in its details) does not give up on it at once. It asks the
occupant by name to make room, in one fixed sentence:

    "Erin, please make room at table_2 stand pose 0."

then waits a step and navigates there again; refused again, it waits a little longer each time
and asks again every other refusal (the occupant may have left and come back, or another robot
taken its place). After `MAX_REFUSALS` refusals, or at once when the occupant is not an attached
teammate (nobody could move it), the role hears of the refusal as of any failed navigation and
does what it does then (another stand pose). Until then the role does not see those steps at
all: the messages that arrive meanwhile reach it with its next decision, and the refusal is not
counted as an unreachable stand pose or a failed fetch.

A robot asked to make room at the stand pose it stands at leaves it as soon as it is idle (its
role would `wait`), or while it itself waits for room elsewhere (two robots that each stand
where the other must go). A fetcher beside other fetchers leaves table_0 as soon as it is idle,
unasked: the fetchers take turns at its stand pose nearest the goal, and a base stopped a little
off its stand pose (which does not make the pose occupied) is still in the way of the next
fetcher's arm there; it first backs straight away from the table (`move`, BACK_OFF), and
navigates elsewhere only if that fails or leaves it still by the table. Leaving, it navigates to a stand pose nobody is likely to need -- one of a
piece of furniture with nothing known on it (those it has stood at first, then the nearest),
never Bob's table, a container or the furniture it was asked to leave -- and tries the next such
pose if that one is taken. The request holds while it stands there; its role, which decided to
wait, hears that it waited. A request for a stand pose it does not stand at is dropped.

In the paper's team nobody is ever refused (its world lets robots share a stand pose) and Alice
is the only fetcher, so none of this acts and every decision is the role's own."""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Literal

from mhrc.core.protocol import (
    ActionResult,
    Communicate,
    Move,
    Navigate,
    Observation,
    OutcomeCode,
    RobotMessage,
    SkillOutcome,
    Wait,
)

from .heuristic_base import HANDOVER, _at_stand_pose, _furniture, title
from .policy import Decision

MAKE_ROOM_RE = re.compile(r"please make room at ([A-Za-z0-9_]+) stand pose (\d+)")
MAX_REFUSALS = 6  # refusals of one stand pose before the role hears of it (and tries another)
NEAR_HANDOVER = 0.5  # m: an idle fetcher this close to a stand pose of table_0 leaves it to the others
BACK_OFF = 0.7  # m: how far it backs away from table_0 (a `move`), before it would navigate elsewhere
ASK_TOL = 0.15  # m: standing this close to a stand pose one was asked to leave (the world's rule: 0.1)

Step = Literal["role", "ask", "wait", "retry", "park", "park_aside", "back"]


def make_room_sentence(place: str, pose: int, to: str) -> str:
    """What a refused robot asks the occupant (MAKE_ROOM_RE reads it back)."""
    return f"{title(to)}, please make room at {place} stand pose {pose}."


@dataclass
class Refusal:
    """A navigation of the role's that the world refused: another robot stands there."""

    action: Navigate
    occupant: str
    refusals: int = 1
    asked: bool = False  # the occupant was asked since the last refusal
    wait: int = 1  # steps still to wait before navigating there again


@dataclass
class Room:
    """A robot's side of making room: its refused navigation, and the stand poses it was asked to leave."""

    pending: Refusal | None = None
    asked_of_me: set[tuple[str, int]] = field(default_factory=set)
    held: list[RobotMessage] = field(default_factory=list)  # messages the role has not seen yet
    step: Step = "role"  # whose the last decision was: the role's, or one of this layer's
    parked_out: set[tuple[str, int]] = field(default_factory=set)  # park poses that failed
    stood_at: set[str] = field(default_factory=set)  # furniture this robot reached
    backed: bool = False  # backed away from table_0 since the role last navigated

    # ---- hearing
    def hear(self, obs: Observation) -> None:
        """Note the requests to make room addressed to this robot; drop those for stand poses
        it does not stand at (any more)."""
        for m in obs.new_messages:
            if m.to == obs.robot and (hit := MAKE_ROOM_RE.search(m.content)) is not None:
                self.asked_of_me.add((hit.group(1), int(hit.group(2))))
        self.asked_of_me = {(f, i) for f, i in self.asked_of_me if self._standing_at(obs, f, i)}

    @staticmethod
    def _standing_at(obs: Observation, place: str, pose: int) -> bool:
        f = _furniture(obs, place)
        return f is not None and _at_stand_pose(obs, f, pose, tol=ASK_TOL)

    # ---- deciding
    def instead(self, obs: Observation) -> Decision | None:
        """This layer's action while a navigation of the role's waits for room: leave where this
        robot was asked to make room, ask the occupant, wait, or navigate there again."""
        p = self.pending
        if p is None:
            return None
        if self.asked_of_me and (park := self._park(obs, "park_aside")) is not None:
            return park
        if not p.asked and p.occupant in obs.teammates:
            p.asked = True
            self.step = "ask"
            place, pose = p.action.target, p.action.stand_pose
            return Decision(action=Communicate(to=p.occupant, content=make_room_sentence(place, pose, p.occupant)))
        if p.wait > 0:
            p.wait -= 1
            self.step = "wait"
            return Decision(action=Wait())
        self.step = "retry"
        return Decision(action=p.action)

    def hold(self, obs: Observation) -> None:
        """The role does not decide this step: keep its messages for its next decision."""
        self.held.extend(obs.new_messages)

    def release(self, obs: Observation) -> Observation:
        """`obs` with the messages held back for the role."""
        if not self.held:
            return obs
        held, self.held = self.held, []
        return obs.model_copy(update={"new_messages": [*held, *obs.new_messages]})

    def check(self, obs: Observation, decision: Decision, *, can_move: bool = True, turns: bool = False) -> Decision:
        """The role's decision, unless it would wait where it was asked to make room, or (`turns`:
        a fetcher beside other fetchers) by Bob's table, and can move (not broken down): then leave."""
        self.step = "role"
        if not (isinstance(decision.action, Wait) and can_move):
            return decision
        if (
            turns
            and not self.asked_of_me
            and not self.backed
            and "move" in obs.status.skills
            and self._by_handover(obs)
        ):
            return self._back_off(obs)
        if self.asked_of_me or (turns and self._by_handover(obs)):
            park = self._park(obs, "park")
            if park is not None:
                return park
        return decision

    def _back_off(self, obs: Observation) -> Decision:
        """Back straight away from the table it faces (a `move`: no second look anywhere); if
        that fails, or leaves it still by table_0, it navigates elsewhere next."""
        base = obs.status.base
        assert base is not None
        self.backed, self.step = True, "back"
        dx, dy = -BACK_OFF * math.cos(base.yaw), -BACK_OFF * math.sin(base.yaw)
        return Decision(action=Move(dx=round(dx, 2), dy=round(dy, 2)))

    @staticmethod
    def _by_handover(obs: Observation) -> bool:
        """Standing at, or near, one of table_0's stand poses (a base stopped a little off its
        stand pose does not make it occupied, but its body is in the way of the next arm there)."""
        table, base = _furniture(obs, HANDOVER), obs.status.base
        return (
            table is not None
            and base is not None
            and any(math.hypot(sp.x - base.x, sp.y - base.y) <= NEAR_HANDOVER for sp in table.stand_poses)
        )

    def _park(self, obs: Observation, step: Step) -> Decision | None:
        """Navigate to a stand pose nobody is likely to need: of furniture with nothing known on
        it, not Bob's table, not a container, not the furniture asked about; those this robot
        has stood at first, then the nearest."""
        here = obs.status.base
        if here is None:
            return None
        avoid = {f for f, _ in self.asked_of_me}
        if self.pending is not None:
            avoid.add(self.pending.action.target)
        occupied = {o.on for o in obs.objects if o.on is not None}
        spots = [
            (f.name not in self.stood_at, math.hypot(sp.x - here.x, sp.y - here.y), f.name, i)
            for f in obs.furniture
            if f.stand_poses and f.name != HANDOVER and not f.openable and f.name not in avoid | occupied
            for i, sp in enumerate(f.stand_poses)
            if (f.name, i) not in self.parked_out
        ]
        if not spots:
            return None
        _, _, place, pose = min(spots)
        self.step = step
        return Decision(action=Navigate(target=place, stand_pose=pose))

    # ---- results
    def record(self, result: ActionResult) -> ActionResult | None:
        """What the role is to hear of `result` (None: nothing, the step was this layer's)."""
        step, self.step = self.step, "role"
        a, outcome = result.action, result.outcome
        if isinstance(a, Navigate) and outcome.succeeded:
            self.stood_at.add(a.target)
            self.backed = False
        if outcome.code == OutcomeCode.BROKEN_DOWN:
            self.pending = None  # the role hears of it (only a navigation fails so), waits it out, decides afresh
            return result
        refused = isinstance(a, Navigate) and outcome.code == OutcomeCode.OCCUPIED
        occupant = outcome.details.get("occupant") if refused else None
        if step == "role":
            if isinstance(a, Navigate) and isinstance(occupant, str) and occupant in result.observation.teammates:
                self.pending = Refusal(action=a, occupant=occupant)
                return None
            return result
        if step == "retry":
            p = self.pending
            assert p is not None
            if not isinstance(occupant, str) or occupant not in result.observation.teammates:
                self.pending = None
                return result  # there (or refused for another reason, or by a robot nobody can ask): the role's
            p.refusals += 1
            if p.refusals >= MAX_REFUSALS:
                self.pending = None
                return result  # the role tries another stand pose
            if occupant != p.occupant or p.refusals % 2 == 1:
                p.asked = False  # ask again: every other refusal, and whoever stands there now
            p.occupant = occupant
            p.wait = min(p.refusals, 3)
            return None
        if step in ("park", "park_aside") and isinstance(a, Navigate) and not outcome.succeeded:
            if outcome.code != OutcomeCode.OFF_TARGET:
                self.parked_out.add((a.target, a.stand_pose))
        return _waited(result) if step in ("park", "back") else None


def _waited(result: ActionResult) -> ActionResult:
    """`result` as the role, which decided to wait, is to hear it."""
    return result.model_copy(update={"action": Wait(), "outcome": SkillOutcome.ok("You waited.")})
