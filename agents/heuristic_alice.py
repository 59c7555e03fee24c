"""Alice's scripted role (heuristic.py states every role's behaviour): explore the closed
containers, hand the open surfaces to David, fetch what Bob asks for, and search again for what
nobody knows the place of once everything has been looked at (a target moved or added while the
team worked)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mhrc.core.protocol import (
    Communicate,
    FurnitureView,
    Move,
    Navigate,
    ObjectView,
    Observation,
    Open,
    OutcomeCode,
    Pick,
    Place,
    Wait,
)

from .heuristic_base import (
    BREAKDOWN_RE,
    HANDOVER,
    MAX_GRASP_TRIES,
    REPORT_RE,
    REQUEST_RE,
    UNREACHABLE_RE,
    _at_stand_pose,
    _dist2,
    _furniture,
    _gone,
    _names,
    _nearest_stand_pose,
    _object,
    _on_fixture,
    _RoleBase,
    corrective_move,
    explore_sentence,
    failed,
)
from .policy import Decision

ON_POSE = 0.03  # m: a navigation that succeeded stops this close to its stand pose (one that counts as there within AT_POSE_TOL may not)
ALICE_SHARE = 2 / 3  # of a search round's surfaces: she looks on arriving, David also has to report each


@dataclass
class AliceHeuristic(_RoleBase):
    """Explores containers, delegates surfaces to David, fetches what Bob needs, searches again."""

    needed: list[str] = field(default_factory=list)
    delivered: set[str] = field(default_factory=set)
    explored: set[str] = field(default_factory=set)
    delegated: bool = False
    grasp_tries: dict[str, int] = field(default_factory=dict)
    given_up: set[str] = field(default_factory=set)
    pose_choice: dict[str, int] = field(default_factory=dict)  # object -> stand pose to use
    david_here: bool = False
    david_todo: set[str] = field(default_factory=set)  # surfaces handed to David he has not reported on
    david_broken_until: int = 0  # from David's breakdown message
    mine: list[str] = field(default_factory=list)  # surfaces Alice searches herself in the current round
    late: set[str] = field(default_factory=set)  # asked for after Bob's first request
    searched_for: set[str] = field(default_factory=set)  # what earlier search rounds looked for

    async def decide(self, obs: Observation) -> Decision:
        self._read_messages(obs)
        if (broken := self._broken_down(obs)) is not None:
            return broken
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
                self.david_todo = set(surfaces)
                return self._decision(Communicate(to="david", content=explore_sentence(surfaces)))
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
                first = not self.needed
                for name in _names(hit.group(1)):
                    if name not in self.needed:
                        if not first:
                            self.late.add(name)  # not in Bob's first list: it joined the task
                        self.needed.append(name)
                    self.delivered.discard(name)
                    self.given_up.discard(name)
                    self.grasp_tries.pop(name, None)
            for hit in REPORT_RE.finditer(m.content):
                self.explored.add(hit.group(1))
                self.david_todo.discard(hit.group(1))
            for hit in UNREACHABLE_RE.finditer(m.content):
                self.david_todo.discard(hit.group(1))  # left for Alice's own search
            if m.sender == "david" and (hit := BREAKDOWN_RE.search(m.content)) is not None:
                self.david_broken_until = int(hit.group(1))

    def _learn_from_last(self, obs: Observation) -> None:
        last = self.last
        if last is None or last.outcome.code == OutcomeCode.BROKEN_DOWN:
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
        return [
            f.name
            for f in obs.furniture
            if not f.openable and f.stand_poses and f.name != HANDOVER and f.place_pose is not None
        ]

    def _david_works(self, obs: Observation) -> bool:
        """David is attached and not broken down (as far as his messages say)."""
        return "david" in obs.teammates and obs.tick >= self.david_broken_until

    def _moved(self, obs: Observation) -> list[str]:
        """What Bob asked for that was seen gone from where it was, or that he asked for late
        (a target that joined the task) and nobody has seen yet."""
        out = []
        for n in self._lost(obs):
            o = _object(obs, n)
            if (o is not None and o.last_seen_on is not None) or (o is None and n in self.late):
                out.append(n)
        return out

    def _lost(self, obs: Observation) -> list[str]:
        """What Bob asked for that Alice has no place for: never seen, or gone from where it was."""
        return [n for n in self.needed if n not in self.delivered and n not in self.given_up and _gone(_object(obs, n))]

    def _next_target(self, obs: Observation) -> ObjectView | None:
        here = obs.status.base
        candidates = []
        for name in self.needed:
            if name in self.delivered or name in self.given_up:
                continue
            o = _object(obs, name)
            if o is None or _gone(o) or _on_fixture(obs, o) or o.held_by not in (None, obs.robot):
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
            return self._open(obs, f)  # still closed, or closed again since she saw inside: open it (again)
        last = self.last
        if (
            last is not None
            and isinstance(last.action, Pick)
            and last.action.obj == o.name
            and last.outcome.code == OutcomeCode.TOO_FAR
        ):
            d = last.outcome.details
            if "dx" in d and "dy" in d:  # the solved_move aid
                return self._decision(Move(dx=float(d["dx"]), dy=float(d["dy"])))
            if "offset_x" in d and "offset_y" in d:
                fix = corrective_move(obs, (float(d["offset_x"]), float(d["offset_y"])))
                if fix is not None:
                    return self._decision(Move(dx=fix[0], dy=fix[1]))
        if last is not None and isinstance(last.action, Pick) and last.action.obj == o.name and failed(last):
            # after a failure that moving cannot fix, the next nearest stand pose to the object (not the next by
            # number: that can be the table's far side)
            order = sorted(
                range(len(f.stand_poses)), key=lambda i: _dist2((f.stand_poses[i].x, f.stand_poses[i].y), o.position)
            )
            tried = self.pose_choice.get(o.name, order[0]) % len(f.stand_poses)
            if not _at_stand_pose(
                obs, f, tried, tol=ON_POSE
            ):  # she had stopped off target there: that pose again, exactly
                return self._decision(Navigate(target=f.name, stand_pose=tried))
            self.pose_choice[o.name] = order[(order.index(tried) + 1) % len(order)]
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
        """Open the closed containers nobody has looked into yet (nearest first); then the
        surfaces David cannot cover (he is absent or broken down) or that are hers in a search
        round. A search round starts once every surface was seen and a target is still nowhere;
        before the containers if it moved or joined the task late (what moves or appears while
        the team works lands on a surface)."""
        here = obs.status.base
        containers = [
            f for f in obs.furniture if f.openable and not f.is_open and f.name not in self.explored and f.stand_poses
        ]
        if not self.needed and not containers:
            return None
        moved = set(self._moved(obs))
        early = bool(moved - self.searched_for)  # worth a round before the containers: not searched for yet
        names = [s for s in self.mine if s not in self.explored]
        if not names:
            david = [s for s in self.david_todo if s not in self.explored]
            if david and self._david_works(obs):
                if not containers:
                    return None  # David has not reported everything yet
            else:
                names = david or [s for s in self._open_surfaces(obs) if s not in self.explored]
                if not names and (early or (not containers and self._lost(obs))):
                    self.searched_for |= moved
                    return self._search_round(obs)
        todo = [f for f in obs.furniture if f.name in names] if names and (moved or not containers) else containers
        if todo is containers and not self._david_works(
            obs
        ):  # David is down: his surfaces count as much as the containers
            todo = containers + [f for f in obs.furniture if f.name in self.david_todo and f.name not in self.explored]
        if here is not None:
            todo.sort(key=lambda f: _dist2(f.position, (here.x, here.y)))
        for f in todo:
            if f.openable:
                return self._open(obs, f)
            idx = _nearest_stand_pose(f, f.position)
            if not _at_stand_pose(obs, f, idx):
                return self._decision(Navigate(target=f.name, stand_pose=idx))
            self.explored.add(f.name)  # standing there already: seen
        return None

    def _search_round(self, obs: Observation) -> Decision | None:
        """Every container and surface has been seen and a target Bob asked for is still
        nowhere (moved or added while the team worked): look at every surface again, Alice the
        nearer ones, David (if he works) the rest."""
        surfaces = self._open_surfaces(obs)
        if not surfaces:
            return None
        self.explored -= set(surfaces)
        here = obs.status.base
        if here is not None:
            surfaces.sort(key=lambda s: _dist2(_furniture(obs, s).position, (here.x, here.y)))  # type: ignore[union-attr]
        if not self._david_works(obs):
            self.mine = surfaces
            return self._next_exploration(obs)
        cut = max(1, math.ceil(len(surfaces) * ALICE_SHARE))
        self.mine, rest = surfaces[:cut], surfaces[cut:]
        if not rest:
            return self._next_exploration(obs)
        self.david_todo = set(rest)
        return self._decision(Communicate(to="david", content=explore_sentence(rest)))

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
