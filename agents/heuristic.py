"""Scripted expert policies, one per role, for every task (pack, sort, sandwich).

Each sees only its own robot's observation (its partial scene graph, status, new messages and
the feedback of its last action) and coordinates through `communicate` messages, as the
paper's roles do:

- Bob asks Alice for every target he cannot pick himself, then puts what is in his reach on
  its goal (the tray, its colour's panel, the cutting board); for an ordered task (a sandwich)
  only the next target in the list, waiting for it if need be. Which panel a solid goes on he
  reads from its colour (the paper's task text does not say). A target that joins the task
  (his task list grows) he asks for like the others; one he saw within his reach that is gone
  from his table without his picking it he asks for again; one brought to his table that lies
  just beyond his reach (a crowded table, seen with a seventh target) he tries to pick anyway.
- Alice hands the open surfaces to David, explores the closed containers herself, fetches what
  Bob asked for and puts it on table_0 near him. A grasp that fails for distance is fixed with a
  `move(dx, dy)` she works out from the base-to-object offsets in the feedback (the solved move
  is an aid she uses only when the world gives it); other grasp failures try the next stand pose.
  A container she finds closed again she opens again. When every container and surface has
  been seen and something Bob asked for is still nowhere (not seen, or gone from where it was:
  moved or added while the team worked), she starts a search round: every surface again, the
  nearer two thirds herself, the rest handed to David. While David is broken down she looks
  at the surfaces he has not reported on herself.
- David explores the surfaces Alice hands him (again, if she hands them over again) and reports
  what lies on each, or that he could not reach one.
- Any robot whose action fails with `broken_down` tells each teammate once that it broke down
  and until which tick, then waits until then (heuristic_base.py); a breakdown's failures are
  not counted as failed picks or unreachable poses.

Messages are plain sentences with a fixed shape, so any other agent (an LLM) can read them too.
Alice's role lives in heuristic_alice.py, what the roles share in heuristic_base.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mhrc.core.protocol import Communicate, Navigate, ObjectView, Observation, OutcomeCode, Pick, Place, Wait

from .heuristic_alice import AliceHeuristic
from .heuristic_base import (
    BREAKDOWN_RE,
    EXPLORE_RE,
    HANDOVER,
    REPORT_RE,
    REQUEST_RE,
    UNREACHABLE_RE,
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
)
from .policy import Decision

STRETCH = 0.1  # m beyond Bob's (conservative) reach he still tries for a target brought to his table

__all__ = [
    "BREAKDOWN_RE",
    "EXPLORE_RE",
    "HANDOVER",
    "REPORT_RE",
    "REQUEST_RE",
    "ROLES",
    "UNREACHABLE_RE",
    "AliceHeuristic",
    "BobHeuristic",
    "DavidHeuristic",
    "breakdown_sentence",
    "corrective_move",
    "goal_of",
    "heuristic_policy",
]


# --------------------------------------------------------------------------- Bob


@dataclass
class BobHeuristic(_RoleBase):
    """Packs the targets within his reach; asks Alice for the rest."""

    requested: set[str] = field(default_factory=set)
    pick_failures: dict[str, int] = field(default_factory=dict)
    gone: set[str] = field(default_factory=set)  # targets seen in his reach, gone since (asked for again once)
    at_start: set[str] | None = None  # what lay on his table at his first step
    alice_here: bool = False

    async def decide(self, obs: Observation) -> Decision:
        if self.at_start is None:
            self.at_start = {o.name for o in obs.objects if o.on == HANDOVER}
        if (broken := self._broken_down(obs)) is not None:
            return broken
        if self._arrived(obs, "alice"):
            self.requested.clear()  # a new Alice has not heard what I need: ask again
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
        ask = [t for t in todo if t not in self.requested or (self.pick_failures.get(t, 0) >= 2 and _object(obs, t))]
        if ask and "alice" in obs.teammates:
            self.requested.update(ask)
            for t in ask:
                self.pick_failures.pop(t, None)
            return self._decision(
                Communicate(
                    to="alice", content=f"Alice, please bring these to table_0 within my reach: {', '.join(ask)}."
                )
            )
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
                self.requested.discard(t)

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
    """Explores the surfaces Alice hands over and reports what lies on each."""

    assigned: list[str] = field(default_factory=list)
    visited: set[str] = field(default_factory=set)
    pose_try: dict[str, int] = field(default_factory=dict)
    report_to: str = "alice"
    slips: int = 0

    async def decide(self, obs: Observation) -> Decision:
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
        last = self.last
        if last is not None and isinstance(last.action, Navigate) and last.outcome.succeeded:
            target = last.action.target
            self.visited.add(target)
            found = sorted(o.name for o in obs.objects if o.on == target)
            text = f"On {target} I found: {', '.join(found)}." if found else f"On {target} I found nothing."
            return self._decision(Communicate(to=self.report_to, content=text))
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


ROLES = {"alice": AliceHeuristic, "bob": BobHeuristic, "david": DavidHeuristic}


def heuristic_policy(robot: str) -> _RoleBase:
    """The scripted expert for `robot` (alice, bob or david)."""
    try:
        return ROLES[robot]()
    except KeyError:
        raise ValueError(f"no heuristic policy for robot {robot!r}; known roles: {', '.join(ROLES)}") from None
