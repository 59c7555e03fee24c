"""Scripted expert policies, one per role, for every task (pack, sort, sandwich).

Each sees only its own robot's observation (its partial scene graph, status, new messages and
the feedback of its last action) and coordinates through `communicate` messages, as the
paper's roles do:

- Bob asks Alice for every target he cannot pick himself, then puts what is in his reach on
  its goal (the tray, its colour's panel, the cutting board); for an ordered task (a sandwich)
  only the next target in the list, waiting for it if need be. Which panel a solid goes on he
  reads from its colour (the paper's task text does not say).
- Alice hands the open surfaces to David, explores the closed containers herself, fetches what
  Bob asked for and puts it on table_0 near him. A grasp that fails for distance is fixed with a
  `move(dx, dy)` she works out from the base-to-object offsets in the feedback (the solved move
  is an aid she uses only when the world gives it); other grasp failures try the next stand pose.
- David explores the surfaces Alice hands him and reports what lies on each.

Messages are plain sentences with a fixed shape, so any other agent (an LLM) can read them too.
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
    Move,
    Navigate,
    Observation,
    ObjectView,
    Open,
    OutcomeCode,
    Pick,
    Place,
    Wait,
)

from .policy import Decision

HANDOVER = "table_0"  # Bob's table: where fetched objects go
_NAMES = r"([A-Za-z0-9_]+(?:\s*,\s*[A-Za-z0-9_]+)*)"
REQUEST_RE = re.compile(r"bring these to table_0 within my reach:\s*" + _NAMES)
EXPLORE_RE = re.compile(r"explore these surfaces and tell me what lies on them:\s*" + _NAMES)
REPORT_RE = re.compile(r"On ([A-Za-z0-9_]+) I found")
MAX_GRASP_TRIES = 4
ARM_FORWARD = 0.2  # Alice's arm base sits this far ahead of her base centre (her system prompt says so)
GOOD_PICK = 0.45  # m from the arm base: the middle of the good picking range her prompt gives
MAX_MOVE = 1.0
AT_POSE_TOL = 0.15  # m: counts as standing at a stand pose (navigation may stop a little off)


def _names(text: str) -> list[str]:
    return [n.strip() for n in text.split(",") if n.strip()]


def _dist2(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def _furniture(obs: Observation, name: str) -> FurnitureView | None:
    return next((f for f in obs.furniture if f.name == name), None)


def _object(obs: Observation, name: str) -> ObjectView | None:
    return next((o for o in obs.objects if o.name == name), None)


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


@dataclass
class _RoleBase:
    """Shared bookkeeping: the last result this policy got."""

    name: str = "heuristic"
    last: ActionResult | None = None

    async def decide(self, obs: Observation) -> Decision:
        raise NotImplementedError  # each role decides its own way

    def record(self, result: ActionResult) -> None:
        self.last = result

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
        return self.last is not None and self.last.action.skill == skill and not self.last.outcome.succeeded


# --------------------------------------------------------------------------- Bob


@dataclass
class BobHeuristic(_RoleBase):
    """Packs the targets within his reach; asks Alice for the rest."""

    requested: set[str] = field(default_factory=set)
    pick_failures: dict[str, int] = field(default_factory=dict)
    alice_here: bool = False

    async def decide(self, obs: Observation) -> Decision:
        if self._arrived(obs, "alice"):
            self.requested.clear()  # a new Alice has not heard what I need: ask again
        if self._last_failed("pick") and isinstance(self.last.action, Pick):  # type: ignore[union-attr]
            name = self.last.action.obj  # type: ignore[union-attr]
            self.pick_failures[name] = self.pick_failures.get(name, 0) + 1
        holding = obs.status.holding
        if holding:
            return self._decision(Place(obj=holding, location=goal_of(obs, holding) if holding in obs.targets else HANDOVER))
        done = {o.name for o in obs.objects if o.name in obs.targets and o.on == goal_of(obs, o.name)}
        todo = [t for t in obs.targets if t not in done]
        candidates = todo[:1] if obs.ordered else todo
        reachable = [t for t in candidates if self._in_reach(obs, t) and self.pick_failures.get(t, 0) < 2]
        if reachable:
            return self._decision(Pick(obj=reachable[0]))
        ask = [t for t in todo if t not in self.requested or (self.pick_failures.get(t, 0) >= 2 and _object(obs, t))]
        if ask and "alice" in obs.teammates:
            self.requested.update(ask)
            for t in ask:
                self.pick_failures.pop(t, None)
            return self._decision(
                Communicate(to="alice", content=f"Alice, please bring these to table_0 within my reach: {', '.join(ask)}.")
            )
        return self._decision(Wait())

    @staticmethod
    def _in_reach(obs: Observation, name: str) -> bool:
        o = _object(obs, name)
        s = obs.status
        if o is None or o.on != HANDOVER or s.arm_base is None or s.reach is None:
            return False
        return _dist2(o.position, s.arm_base) <= s.reach


# --------------------------------------------------------------------------- Alice


@dataclass
class AliceHeuristic(_RoleBase):
    """Explores containers, delegates surfaces to David, fetches what Bob needs."""

    needed: list[str] = field(default_factory=list)
    delivered: set[str] = field(default_factory=set)
    explored: set[str] = field(default_factory=set)
    delegated: bool = False
    grasp_tries: dict[str, int] = field(default_factory=dict)
    given_up: set[str] = field(default_factory=set)
    pose_choice: dict[str, int] = field(default_factory=dict)  # object -> stand pose to use
    david_here: bool = False

    async def decide(self, obs: Observation) -> Decision:
        self._read_messages(obs)
        self._learn_from_last(obs)
        if self._arrived(obs, "david"):
            self.delegated = False  # a new David knows nothing of his surfaces: hand them over again
        holding = obs.status.holding
        if holding:
            return self._deliver(obs, holding)
        if not self.delegated and "david" in obs.teammates:
            surfaces = [f for f in self._open_surfaces(obs) if f not in self.explored]
            self.delegated = True
            if surfaces:
                return self._decision(
                    Communicate(
                        to="david",
                        content=f"David, please explore these surfaces and tell me what lies on them: {', '.join(surfaces)}.",
                    )
                )
        target = self._next_target(obs)
        if target is not None:
            return self._fetch(obs, target)
        explore = self._next_exploration(obs)
        if explore is not None:
            return explore
        return self._decision(Wait())

    # ---- knowledge
    def _read_messages(self, obs: Observation) -> None:
        for m in obs.new_messages:
            if (hit := REQUEST_RE.search(m.content)) is not None:
                for name in _names(hit.group(1)):
                    if name not in self.needed:
                        self.needed.append(name)
                    self.delivered.discard(name)
                    self.given_up.discard(name)
                    self.grasp_tries.pop(name, None)
            for hit in REPORT_RE.finditer(m.content):
                self.explored.add(hit.group(1))

    def _learn_from_last(self, obs: Observation) -> None:
        last = self.last
        if last is None:
            return
        a = last.action
        if isinstance(a, Navigate) and last.outcome.succeeded:
            f = _furniture(obs, a.target)
            if f is not None and not (f.openable and not f.is_open):
                self.explored.add(a.target)
        if isinstance(a, Open) and (last.outcome.succeeded or last.outcome.code == OutcomeCode.ALREADY_OPEN):
            self.explored.add(a.target)
        if isinstance(a, Place) and last.outcome.succeeded and a.location == HANDOVER:
            self.delivered.add(a.obj)
        if isinstance(a, Pick) and not last.outcome.succeeded:
            self._count_try(a.obj)
        if isinstance(a, Navigate) and not last.outcome.succeeded and last.outcome.code != OutcomeCode.OFF_TARGET:
            # a stand pose we cannot reach (stopping off target is worth another try): the next fetch of an object there tries another
            for name, idx in list(self.pose_choice.items()):
                if idx == a.stand_pose:
                    self.pose_choice[name] = idx + 1
            for o in obs.objects:
                if o.on == a.target and o.name in self.needed:
                    self.pose_choice.setdefault(o.name, a.stand_pose + 1)
                    self._count_try(o.name)

    def _count_try(self, name: str) -> None:
        self.grasp_tries[name] = self.grasp_tries.get(name, 0) + 1
        if self.grasp_tries[name] >= MAX_GRASP_TRIES:
            self.given_up.add(name)

    def _open_surfaces(self, obs: Observation) -> list[str]:
        return [f.name for f in obs.furniture if not f.openable and f.stand_poses and f.name != HANDOVER and f.place_pose is not None]

    def _next_target(self, obs: Observation) -> ObjectView | None:
        here = obs.status.base
        candidates = []
        for name in self.needed:
            if name in self.delivered or name in self.given_up:
                continue
            o = _object(obs, name)
            if o is None or _on_fixture(obs, o) or o.held_by not in (None, obs.robot):
                continue
            candidates.append(o)
        if not candidates:
            return None
        if here is None:
            return candidates[0]
        return min(candidates, key=lambda o: _dist2(o.position, (here.x, here.y)))

    # ---- acting
    def _fetch(self, obs: Observation, o: ObjectView) -> Decision:
        f = _furniture(obs, o.on or "")
        if f is None or not f.stand_poses:
            self.given_up.add(o.name)
            return self._decision(Wait())
        if f.openable and not f.is_open:
            return self._open(obs, f)
        last = self.last
        if last is not None and isinstance(last.action, Pick) and last.action.obj == o.name and last.outcome.code == OutcomeCode.TOO_FAR:
            d = last.outcome.details
            if "dx" in d and "dy" in d:  # the solved_move aid
                return self._decision(Move(dx=float(d["dx"]), dy=float(d["dy"])))
            if "offset_x" in d and "offset_y" in d:
                fix = corrective_move(obs, (float(d["offset_x"]), float(d["offset_y"])))
                if fix is not None:
                    return self._decision(Move(dx=fix[0], dy=fix[1]))
        if last is not None and isinstance(last.action, Pick) and last.action.obj == o.name and not last.outcome.succeeded:
            # another stand pose after a failure that moving cannot fix
            self.pose_choice[o.name] = (self.pose_choice.get(o.name, _nearest_stand_pose(f, o.position)) + 1) % len(f.stand_poses)
        idx = self.pose_choice.get(o.name, _nearest_stand_pose(f, o.position)) % len(f.stand_poses)
        near = obs.status.base is not None and _dist2(o.position, (obs.status.base.x, obs.status.base.y)) <= 1.6
        moved_here = last is not None and isinstance(last.action, Move) and last.outcome.succeeded
        if not _at_stand_pose(obs, f, idx) and not (moved_here and near):
            return self._decision(Navigate(target=f.name, stand_pose=idx))
        return self._decision(Pick(obj=o.name))

    def _deliver(self, obs: Observation, holding: str) -> Decision:
        table = _furniture(obs, HANDOVER)
        if table is None or not table.stand_poses:
            return self._decision(Wait())
        goal = table.place_pose or table.position
        idx = _nearest_stand_pose(table, goal)
        if self._last_failed("place"):
            idx = (idx + 1) % len(table.stand_poses)
        if not _at_stand_pose(obs, table, idx):
            return self._decision(Navigate(target=HANDOVER, stand_pose=idx))
        return self._decision(Place(obj=holding, location=HANDOVER))

    def _next_exploration(self, obs: Observation) -> Decision | None:
        """Open the closed containers nobody has looked into yet (nearest first)."""
        here = obs.status.base
        todo = [f for f in obs.furniture if f.openable and not f.is_open and f.name not in self.explored and f.stand_poses]
        if not self.needed and not todo:
            return None
        if not todo:
            # David has not reported everything yet: check surfaces nobody explored, if any are left
            if "david" in obs.teammates:
                return None
            todo = [f for f in obs.furniture if f.name in self._open_surfaces(obs) and f.name not in self.explored]
            if not todo:
                return None
        if here is not None:
            todo.sort(key=lambda f: _dist2(f.position, (here.x, here.y)))
        f = todo[0]
        if f.openable:
            return self._open(obs, f)
        idx = _nearest_stand_pose(f, f.position)
        if not _at_stand_pose(obs, f, idx):
            return self._decision(Navigate(target=f.name, stand_pose=idx))
        self.explored.add(f.name)
        return None

    def _open(self, obs: Observation, f: FurnitureView) -> Decision:
        """Open `f` from a stand pose. After a failed open (the arm could not follow the handle
        from where the base stopped, within the stand pose's tolerance) approach again first,
        from the next stand pose: opening again from the same spot fails the same way (seen:
        34 failed opens in a row, the episode lost)."""
        idx = self.pose_choice.get(f.name, _nearest_stand_pose(f, f.position)) % len(f.stand_poses)
        if self._last_failed("open") and self.last is not None and getattr(self.last.action, "target", None) == f.name:
            idx = (idx + 1) % len(f.stand_poses)
            self.pose_choice[f.name] = idx
            return self._decision(Navigate(target=f.name, stand_pose=idx))
        if not _at_stand_pose(obs, f, idx):
            return self._decision(Navigate(target=f.name, stand_pose=idx))
        return self._decision(Open(target=f.name))


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
                    if name not in self.assigned:
                        self.assigned.append(name)
        last = self.last
        if last is not None and isinstance(last.action, Navigate):
            target = last.action.target
            if last.outcome.succeeded:
                self.visited.add(target)
                found = sorted(o.name for o in obs.objects if o.on == target)
                text = f"On {target} I found: {', '.join(found)}." if found else f"On {target} I found nothing."
                return self._decision(Communicate(to=self.report_to, content=text))
            f = _furniture(obs, target)
            if last.outcome.code == OutcomeCode.OFF_TARGET and self.slips < 3:
                self.slips += 1  # stopped short: drive there again
                return self._decision(Navigate(target=target, stand_pose=last.action.stand_pose))
            tries = self.pose_try.get(target, 0) + 1
            self.pose_try[target] = tries
            if f is None or tries >= len(f.stand_poses):
                self.visited.add(target)  # unreachable for David: give it up
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
