"""Scripted expert policies, one per role, for every task (pack, sort, sandwich) and any team.

Each sees only its own robot's observation (its partial scene graph, status, new messages and
the feedback of its last action) and coordinates through `communicate` messages, as the
paper's roles do. A robot's role follows from the skills its first observation reports, never
from its name (`role_of`): the **finisher** picks and places without moving (the tabletop arm
at the goal: the paper's Bob), a **fetcher** navigates and picks (a mobile manipulator: Alice),
a **scout** does neither or only navigates (a mobile base, a drone: David). Teammates and their
roles come from `Observation.teammates` (the attached ones, with their skills); messages go to
them by name. In the paper's team every decision is the one the per-name roles made.

- The finisher asks every fetcher for every target he cannot pick himself (each fetcher hears
  the whole list, one message a step, in name order), then puts what is in his reach on its
  goal (the tray, its colour's panel, the cutting board); for an ordered task (a sandwich) only
  the next target in the list, waiting for it if need be. Which panel a solid goes on he reads
  from its colour (the paper's task text does not say). A target that joins the task (his task
  list grows) he asks for like the others; one he saw within his reach that is gone from his
  table without his picking it he asks for again; one brought to his table that lies just
  beyond his reach (a crowded table, seen with a seventh target) he tries to pick anyway. A
  fetcher that attaches (or is replaced) hears the list again.
- The **lead fetcher** (the first by name of the fetchers attached; alone, the only one) hands
  the open surfaces to the scouts, one contiguous share each, explores closed containers,
  fetches what the finisher asked for and puts it on table_0 near him. A grasp that fails for
  distance is fixed with a `move(dx, dy)` worked out from the base-to-object offsets in the
  feedback (the solved move is an aid used only when the world gives it); other grasp failures
  try the next stand pose. A container found closed again is opened again. When every
  container and surface has been seen (and every place another fetcher claimed was reported)
  and something asked for is still nowhere (not seen, or gone from where it was: moved or added
  while the team worked), she starts a search round: every surface again, the nearer part
  herself (2/3 beside one scout), the rest split among the working scouts. While a scout is
  absent or broken down she looks at the surfaces it has not reported on herself, and so when a
  scout has reported nothing for a few steps while some are left (a person or a model playing
  it may never do what was asked: heuristic_fetcher.PATIENCE_TICKS); such a scout gets no more
  surfaces until it reports again. A new scout
  (or a fetcher that becomes the lead) has the unexplored surfaces handed over again.
- **Several fetchers** split the work by claims over messages (heuristic_claims.py): before
  fetching an object, or exploring a container, not claimed yet, a fetcher tells every other
  fetcher ("Carol, I am fetching these: mug, toy_duck." -- every object to fetch it knows on
  that furniture, since two fetchers at one piece of furniture get in each other's way;
  "Carol, I am exploring fridge."), and each skips what an attached teammate claimed; two
  claims that cross are settled by name order (the first keeps it), each fetcher deciding
  alone. Claims lapse with their fetcher's attachment, an object's when the finisher asks for
  it again. A fetcher that does not lead explores only containers nobody claimed (surfaces too
  in a team without scouts), reports each to the lead in a scout's words with its claim of what
  it will fetch from there ("On fridge I found: apple. I am fetching these: apple."), and does
  no search rounds. The lead hands what it knows and will not fetch next (objects on another
  piece of furniture than its own) to the other working fetchers in turn ("Carol, I leave these
  to you to fetch: fork."; the message also tells where it lies). Fetchers take turns at table_0's
  stand pose nearest the goal (one robot per stand pose: heuristic_room.py); one whose place
  there fails (a crowded table) delivers from the next nearest stand pose until a place succeeds.
- A scout explores the surfaces a fetcher hands it (again, if handed over again) and reports
  to that fetcher what lies on each, or that it could not reach one; when that fetcher has left,
  to the lead fetcher.
- Any robot whose action fails with `broken_down` tells each teammate it has seen attached
  once that it broke down and until which tick, then waits until then (heuristic_base.py); a
  breakdown's failures are not counted as failed picks or unreachable poses.

Messages are plain sentences with a fixed shape, so any other agent (an LLM) can read them too.
The fetcher's role lives in heuristic_fetcher.py and heuristic_claims.py, what the roles share
in heuristic_base.py.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

from mhrc.core.protocol import (
    ActionResult,
    Communicate,
    Navigate,
    ObjectView,
    Observation,
    OutcomeCode,
    Pick,
    Place,
    Wait,
)

from .heuristic_base import (
    BREAKDOWN_RE,
    CLAIM_RE,
    EXPLORE_RE,
    EXPLORING_RE,
    HANDOFF_RE,
    HANDOVER,
    REPORT_RE,
    REQUEST_RE,
    UNREACHABLE_RE,
    Role,
    _dist2,
    _furniture,
    _gone,
    _names,
    _object,
    _RoleBase,
    breakdown_sentence,
    corrective_move,
    failed,
    goal_of,
    report_sentence,
    request_sentence,
    role_of,
)
from .heuristic_fetcher import AliceHeuristic
from .heuristic_room import MAKE_ROOM_RE, Room, make_room_sentence
from .policy import Decision

STRETCH = 0.1  # m beyond Bob's (conservative) reach he still tries for a target brought to his table

__all__ = [
    "BREAKDOWN_RE",
    "CLAIM_RE",
    "EXPLORE_RE",
    "EXPLORING_RE",
    "HANDOFF_RE",
    "HANDOVER",
    "MAKE_ROOM_RE",
    "REPORT_RE",
    "REQUEST_RE",
    "ROLES",
    "UNREACHABLE_RE",
    "AliceHeuristic",
    "BobHeuristic",
    "DavidHeuristic",
    "FetcherHeuristic",
    "FinisherHeuristic",
    "Heuristic",
    "ScoutHeuristic",
    "breakdown_sentence",
    "corrective_move",
    "goal_of",
    "heuristic_policy",
    "make_room_sentence",
    "role_of",
]


# --------------------------------------------------------------------------- Bob


@dataclass
class BobHeuristic(_RoleBase):
    """The finisher: packs the targets within his reach; asks every fetcher for the rest."""

    requested: dict[str, set[str]] = field(default_factory=dict)  # fetcher -> what it was asked for
    pick_failures: dict[str, int] = field(default_factory=dict)
    gone: set[str] = field(default_factory=set)  # targets seen in his reach, gone since (asked for again once)
    at_start: set[str] | None = None  # what lay on his table at his first step
    fetchers_here: set[str] = field(default_factory=set)

    async def decide(self, obs: Observation) -> Decision:
        self._meet(obs)
        if self.at_start is None:
            self.at_start = {o.name for o in obs.objects if o.on == HANDOVER}
        if (broken := self._broken_down(obs)) is not None:
            return broken
        fetchers = self._with_role(obs, "fetcher")
        for f in fetchers:
            if f not in self.fetchers_here and self.last is not None:
                self.requested.pop(f, None)  # a new fetcher has not heard what I need: ask it
        self.fetchers_here = set(fetchers)
        if self._last_failed("pick") and isinstance(self.last.action, Pick):  # type: ignore[union-attr]
            name = self.last.action.obj  # type: ignore[union-attr]
            self.pick_failures[name] = self.pick_failures.get(name, 0) + 1
        holding = obs.status.holding
        if holding:
            return self._decision(
                Place(obj=holding, location=goal_of(obs, holding) if holding in obs.targets else HANDOVER)
            )
        done = {o.name for o in obs.objects if o.name in obs.targets and o.on == goal_of(obs, o.name)}
        todo = [t for t in obs.targets if t not in done]
        self._notice_gone(obs, todo)
        candidates = todo[:1] if obs.ordered else todo
        tryable = [t for t in candidates if self.pick_failures.get(t, 0) < 2]
        reachable = [t for t in tryable if self._in_reach(obs, t)] or [t for t in tryable if self._brought_near(obs, t)]
        if reachable:
            return self._decision(Pick(obj=reachable[0]))
        for f in fetchers:  # each hears the whole list; they split it among themselves (heuristic_claims.py)
            asked = self.requested.setdefault(f, set())
            ask = [t for t in todo if t not in asked or (self.pick_failures.get(t, 0) >= 2 and _object(obs, t))]
            if ask:
                asked.update(ask)
                for t in ask:
                    self.pick_failures.pop(t, None)
                return self._decision(Communicate(to=f, content=request_sentence(ask, f)))
        return self._decision(Wait())

    def _notice_gone(self, obs: Observation, todo: list[str]) -> None:
        """A target last seen within his reach on his table, gone from it without his picking it
        (someone moved it): it is to be asked for again, once per time it goes."""
        for t in todo:
            o = _object(obs, t)
            if o is None or not (_gone(o) and o.last_seen_on == HANDOVER and _within_reach(obs, o)):
                self.gone.discard(t)
            elif t not in self.gone:
                self.gone.add(t)
                for asked in self.requested.values():
                    asked.discard(t)

    def _brought_near(self, obs: Observation, name: str) -> bool:
        """Brought to his table since the start (by Alice) and just beyond his reach, as a crowded
        table leaves it (seen: a seventh target 0.629 m away, reach 0.62): worth a pick rather
        than waiting for ever."""
        o = _object(obs, name)
        return (
            o is not None
            and o.on == HANDOVER
            and name not in (self.at_start or set())
            and _within_reach(obs, o, STRETCH)
        )

    @staticmethod
    def _in_reach(obs: Observation, name: str) -> bool:
        o = _object(obs, name)
        return o is not None and o.on == HANDOVER and _within_reach(obs, o)


def _within_reach(obs: Observation, o: ObjectView, margin: float = 0.0) -> bool:
    """Whether `o` lies within this robot's reach (plus `margin` m) of its arm base."""
    s = obs.status
    return s.arm_base is not None and s.reach is not None and _dist2(o.position, s.arm_base) <= s.reach + margin


# --------------------------------------------------------------------------- David


@dataclass
class DavidHeuristic(_RoleBase):
    """A scout: explores the surfaces a fetcher hands over and reports to it what lies on each."""

    assigned: list[str] = field(default_factory=list)
    visited: set[str] = field(default_factory=set)
    pose_try: dict[str, int] = field(default_factory=dict)
    report_to: str = ""  # the fetcher that handed the surfaces over
    slips: int = 0

    async def decide(self, obs: Observation) -> Decision:
        self._meet(obs)
        for m in obs.new_messages:
            if (hit := EXPLORE_RE.search(m.content)) is not None:
                self.report_to = m.sender
                for name in _names(hit.group(1)):
                    if name in self.visited:  # asked again (a search round): look again
                        self.visited.discard(name)
                        self.pose_try.pop(name, None)
                        self.assigned.remove(name)
                    if name not in self.assigned:
                        self.assigned.append(name)
        if (broken := self._broken_down(obs)) is not None:
            return broken
        fetchers = self._with_role(obs, "fetcher")
        if self.report_to not in obs.teammates and fetchers:
            self.report_to = fetchers[0]  # whoever asked has left: the lead fetcher hears instead
        last = self.last
        if last is not None and isinstance(last.action, Navigate) and last.outcome.succeeded:
            target = last.action.target
            self.visited.add(target)
            found = sorted(o.name for o in obs.objects if o.on == target)
            return self._decision(Communicate(to=self.report_to, content=report_sentence(target, found)))
        if last is not None and isinstance(last.action, Navigate) and failed(last):
            target = last.action.target
            f = _furniture(obs, target)
            if last.outcome.code == OutcomeCode.OFF_TARGET and self.slips < 3:
                self.slips += 1  # stopped short: drive there again
                return self._decision(Navigate(target=target, stand_pose=last.action.stand_pose))
            tries = self.pose_try.get(target, 0) + 1
            self.pose_try[target] = tries
            if f is None or tries >= len(f.stand_poses):
                self.visited.add(target)  # unreachable for David: give it up, and say so
                return self._decision(Communicate(to=self.report_to, content=f"I could not reach {target}."))
        for name in self.assigned:
            if name in self.visited:
                continue
            f = _furniture(obs, name)
            if f is None or not f.stand_poses:
                self.visited.add(name)
                continue
            return self._decision(Navigate(target=name, stand_pose=self.pose_try.get(name, 0)))
        return self._decision(Wait())


FinisherHeuristic, FetcherHeuristic, ScoutHeuristic = BobHeuristic, AliceHeuristic, DavidHeuristic
ROLES: dict[Role, type[_RoleBase]] = {"finisher": BobHeuristic, "fetcher": AliceHeuristic, "scout": DavidHeuristic}


@dataclass
class Heuristic:
    """The scripted expert for one robot of any name: its role (ROLES) is chosen from the skills
    its first observation reports (or the skills given), and every step is that role's."""

    robot: str
    skills: tuple[str, ...] | None = None
    role: _RoleBase | None = None
    name: str = "heuristic"
    room: Room = field(default_factory=Room)  # making room at stand poses (heuristic_room.py)

    def __post_init__(self) -> None:
        if self.skills is not None:
            self.role = ROLES[role_of(self.skills)]()

    async def decide(self, obs: Observation) -> Decision:
        if self.role is None:
            self.role = ROLES[role_of(obs.status.skills)]()
        self.room.hear(obs)
        if (instead := self.room.instead(obs)) is not None:
            self.room.hold(obs)
            return instead
        decision = await self.role.decide(self.room.release(obs))
        fetchers = [n for n, skills in obs.teammates.items() if role_of(skills) == "fetcher"]
        turns = bool(fetchers) and role_of(obs.status.skills) == "fetcher"  # they take turns at table_0
        return self.room.check(obs, decision, can_move=obs.tick >= self.role.broken_until, turns=turns)

    def record(self, result: ActionResult) -> None:
        if self.role is not None and (heard := self.room.record(result)) is not None:
            self.role.record(heard)


def heuristic_policy(robot: str, skills: Iterable[str] | None = None) -> Heuristic:
    """The scripted expert for `robot`, of any name: the finisher, a fetcher or a scout by the
    skills its observation reports (or `skills`, when given)."""
    return Heuristic(robot, None if skills is None else tuple(skills))
