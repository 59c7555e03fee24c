"""A fetcher's scripted role, the paper's Alice (heuristic.py states every role's behaviour and
the team protocol): explore the closed containers, hand the open surfaces to the scouts, fetch
what the finisher asks for, and search again for what nobody knows the place of once everything
has been looked at (a target moved or added while the team worked). With other fetchers, what
each fetches or explores is claimed over messages first (heuristic_claims.py); the lead fetcher
(the first by name) alone hands surfaces to the scouts, hears their reports, hands objects on
and starts search rounds."""

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
    corrective_move,
    explore_sentence,
    failed,
    split,
)
from .heuristic_claims import Claims
from .policy import Decision

ON_POSE = 0.03  # m: a navigation that succeeded stops this close to its stand pose (one that counts as there within AT_POSE_TOL may not)
PATIENCE_TICKS = 8  # a scout that has reported nothing for this many ticks since it was handed surfaces (or last
PATIENCE_SECONDS = 64.0  # reported), and this many simulated seconds where the clock is known (async: a step is
# 8 s, and a long drive is one step), has let them lapse: the lead looks at them herself. A person (or a model)
# playing the scout may never do what was asked; the heuristic scout reports after every drive (a few ticks).
SHARE = 2  # a search round's surfaces: the lead takes SHARE parts to each working scout's one (2/3 beside one scout):
# she looks on arriving, a scout also has to report each


@dataclass
class AliceHeuristic(Claims):
    """A fetcher: explores containers, delegates surfaces to the scouts, fetches what the finisher
    needs, searches again."""

    needed: list[str] = field(default_factory=list)
    delivered: set[str] = field(default_factory=set)
    explored: set[str] = field(default_factory=set)
    delegated: bool = False
    grasp_tries: dict[str, int] = field(default_factory=dict)
    given_up: set[str] = field(default_factory=set)
    pose_choice: dict[str, int] = field(default_factory=dict)  # object -> stand pose to use
    scouts_here: set[str] = field(default_factory=set)
    scout_todo: dict[str, set[str]] = field(default_factory=dict)  # surfaces handed to a scout it has not reported on
    was_lead: bool = False
    place_shift: int = 0  # beside other fetchers: failed places at table_0 since the last that succeeded (_place_pose)
    mine: list[str] = field(default_factory=list)  # surfaces the lead searches herself in the current round
    late: set[str] = field(default_factory=set)  # asked for after Bob's first request
    searched_for: set[str] = field(default_factory=set)  # what earlier search rounds looked for
    heard: dict[str, tuple[int, float | None]] = field(
        default_factory=dict
    )  # scout -> (tick, clock) handed or heard from
    lapsed: set[str] = field(default_factory=set)  # scouts that let their surfaces lapse, until they report again

    async def decide(self, obs: Observation) -> Decision:
        self._meet(obs)
        self._read_messages(obs)
        if (broken := self._broken_down(obs)) is not None:
            return broken
        self._learn_from_last(obs)
        lead = self._lead(obs)
        scouts = self._with_role(obs, "scout")
        if (set(scouts) - self.scouts_here and self.last is not None) or (lead and not self.was_lead):
            self.delegated = False  # a new scout knows nothing of its surfaces (or I now lead): hand them over
        self.scouts_here, self.was_lead = set(scouts), lead
        if not lead and (report := self._report_explored(obs)) is not None:
            return report
        self.just_explored = None
        if (queued := self._flush(obs)) is not None:
            return queued
        if lead and (handoff := self._handoff(obs)) is not None:
            return handoff
        holding = obs.status.holding
        if holding:
            return self._deliver(obs, holding)
        if lead and not self.delegated and scouts:
            surfaces = [f for f in self._open_surfaces(obs) if f not in self.explored and not self._place_taken(obs, f)]
            self.delegated = True
            if surfaces and (handed := self._hand_to_scouts(obs, surfaces, scouts)) is not None:
                return handed
        target = self._next_target(obs)
        if target is not None:
            return self._claim(obs, target) or self._fetch(obs, target)
        explore = self._next_exploration(obs) if lead else self._next_place(obs, bool(scouts))
        if explore is not None:
            return explore
        return self._decision(Wait())

    def _hand_to_scouts(self, obs: Observation, surfaces: list[str], scouts: list[str]) -> Decision | None:
        """Split `surfaces` among `scouts` (in order, one contiguous share each) and tell each its share."""
        shares = [(s, share) for s, share in zip(scouts, split(surfaces, len(scouts)), strict=True) if share]
        self.scout_todo = {s: set(share) for s, share in shares}
        for scout, _ in shares:
            self.heard[scout] = (obs.tick, self._clock())
        return self._send(obs, [Communicate(to=s, content=explore_sentence(share, s)) for s, share in shares])

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
                    else:
                        self.objects.pop(name, None)  # asked for again: whoever claimed it, it is anyone's
                    self.delivered.discard(name)
                    self.given_up.discard(name)
                    self.grasp_tries.pop(name, None)
            for hit in REPORT_RE.finditer(m.content):
                self.explored.add(hit.group(1))
                self._reported(hit.group(1))
                self._heard_from(obs, m.sender)
            for hit in UNREACHABLE_RE.finditer(m.content):
                self._reported(hit.group(1))  # left for the lead's own search
                self._heard_from(obs, m.sender)
        self._read_claims(obs)

    def _clock(self) -> float | None:
        """The world's clock at the end of this robot's last action, where known."""
        return None if self.last is None else self.last.ended

    def _heard_from(self, obs: Observation, scout: str) -> None:
        if scout in self.heard:
            self.heard[scout] = (obs.tick, self._clock())
        self.lapsed.discard(scout)

    def _lapsed(self, obs: Observation, scout: str) -> bool:
        """`scout` has let the surfaces handed to it lapse: nothing reported for PATIENCE_TICKS
        ticks and PATIENCE_SECONDS simulated seconds while some are left."""
        if scout in self.lapsed:
            return True
        if scout not in self.heard or not any(s not in self.explored for s in self.scout_todo.get(scout, ())):
            return False
        tick, clock = self.heard[scout]
        now = self._clock()
        if obs.tick - tick > PATIENCE_TICKS and (clock is None or now is None or now - clock > PATIENCE_SECONDS):
            self.lapsed.add(scout)
            return True
        return False

    def _reported(self, surface: str) -> None:
        for todo in self.scout_todo.values():
            todo.discard(surface)

    def _learn_from_last(self, obs: Observation) -> None:
        last = self.last
        if last is None or last.outcome.code == OutcomeCode.BROKEN_DOWN:
            return
        a = last.action
        if isinstance(a, Navigate) and last.outcome.succeeded:
            f = _furniture(obs, a.target)
            if f is not None and not (f.openable and not f.is_open):
                self._saw(a.target)
        if isinstance(a, Open) and (last.outcome.succeeded or last.outcome.code == OutcomeCode.ALREADY_OPEN):
            self._saw(a.target)
        if isinstance(a, Place) and last.outcome.succeeded and a.location == HANDOVER:
            self.delivered.add(a.obj)
            self.place_shift = 0
        if isinstance(a, Place) and not last.outcome.succeeded and a.location == HANDOVER:
            self.place_shift += 1
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

    def _scout_todo(self, obs: Observation, working: bool) -> list[str]:
        """The surfaces handed to scouts that work (or, `working` False, that do not: absent or
        broken down) they have not reported on."""
        return [
            s
            for scout, todo in self.scout_todo.items()
            if self._works(obs, scout) == working
            for s in sorted(todo)
            if s not in self.explored
        ]

    def _lapsed_todo(self, obs: Observation) -> list[str]:
        """The surfaces handed to working scouts that let them lapse (_lapsed), not reported on."""
        return [
            s
            for scout, todo in self.scout_todo.items()
            if self._works(obs, scout) and self._lapsed(obs, scout)
            for s in sorted(todo)
            if s not in self.explored
        ]

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

    def _fetchable(self, obs: Observation, o: ObjectView) -> bool:
        """Asked for, not delivered nor given up, where this robot knows, not on a goal fixture,
        not held by another, not claimed by another fetcher."""
        return (
            o.name in self.needed
            and o.name not in self.delivered
            and o.name not in self.given_up
            and not _gone(o)
            and not _on_fixture(obs, o)
            and o.held_by in (None, obs.robot)
            and not self._taken(obs, o.name)
        )

    def _next_target(self, obs: Observation) -> ObjectView | None:
        here = obs.status.base
        candidates = [o for name in self.needed if (o := _object(obs, name)) is not None and self._fetchable(obs, o)]
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
        if self._fetchers(obs):
            idx = self._place_pose(table, goal)
        elif self._last_failed("place"):
            idx = (idx + 1) % len(table.stand_poses)
        if not _at_stand_pose(obs, table, idx):
            return self._decision(Navigate(target=HANDOVER, stand_pose=idx))
        return self._decision(Place(obj=holding, location=HANDOVER))

    def _place_pose(self, table: FurnitureView, goal: tuple[float, ...]) -> int:
        """Beside other fetchers (a world of one robot per stand pose: they take turns at table_0,
        heuristic_room.py): the stand pose nearest the goal, or, after a place failed from it
        (a crowded table: no spot the arm can reach from there), the next nearest, kept until a
        place succeeds."""
        order = sorted(
            range(len(table.stand_poses)), key=lambda i: _dist2((table.stand_poses[i].x, table.stand_poses[i].y), goal)
        )
        return order[self.place_shift % len(order)]

    def _next_exploration(self, obs: Observation) -> Decision | None:
        """The lead's: open the closed containers nobody has looked into yet (nearest first); then
        the surfaces no working scout covers (the scouts are absent or broken down) or that are
        hers in a search round. A search round starts once every surface was seen (and every
        place another fetcher claimed was reported) and a target is still nowhere; before the
        containers if it moved or joined the task late (what moves or appears while the team
        works lands on a surface)."""
        here = obs.status.base
        containers = [
            f
            for f in obs.furniture
            if f.openable
            and not f.is_open
            and f.name not in self.explored
            and f.stand_poses
            and not self._place_taken(obs, f.name)
        ]
        if not self.needed and not containers:
            return None
        moved = set(self._moved(obs))
        early = bool(moved - self.searched_for)  # worth a round before the containers: not searched for yet
        names = [s for s in self.mine if s not in self.explored]
        down = self._scout_todo(obs, working=False)
        if not names:
            if self._scout_todo(obs, working=True) and not down:
                if not containers:
                    names = self._lapsed_todo(obs)  # what a scout let lapse she looks at herself, the rest she awaits
                    if not names:
                        return None  # the scouts have not reported everything yet
            else:
                names = down or [
                    s for s in self._open_surfaces(obs) if s not in self.explored and not self._place_taken(obs, s)
                ]
                if not names and not self._others_exploring(obs) and (early or (not containers and self._lost(obs))):
                    self.searched_for |= moved
                    return self._search_round(obs)
        todo = [f for f in obs.furniture if f.name in names] if names and (moved or not containers) else containers
        if todo is containers and down:  # a scout is down: its surfaces count as much as the containers
            todo = containers + [f for f in obs.furniture if f.name in down]
        if here is not None:
            todo.sort(key=lambda f: _dist2(f.position, (here.x, here.y)))
        return self._explore_first(obs, todo)

    def _next_place(self, obs: Observation, scouted: bool) -> Decision | None:
        """A fetcher that does not lead: the closed containers nobody else claimed (nearest first),
        and, in a team without scouts, the open surfaces too."""
        if not self.needed:
            return None
        here = obs.status.base
        todo = [
            f
            for f in obs.furniture
            if f.name not in self.explored
            and f.stand_poses
            and not self._place_taken(obs, f.name)
            and ((f.openable and not f.is_open) or (not scouted and f.name in self._open_surfaces(obs)))
        ]
        if here is not None:
            todo.sort(key=lambda f: _dist2(f.position, (here.x, here.y)))
        return self._explore_first(obs, todo)

    def _explore_first(self, obs: Observation, todo: list[FurnitureView]) -> Decision | None:
        """Go and look at the first of `todo` not seen yet (claimed first, beside other fetchers)."""
        for f in todo:
            if f.openable:
                return self._claim_place(obs, f.name) or self._open(obs, f)
            idx = _nearest_stand_pose(f, f.position)
            if not _at_stand_pose(obs, f, idx):
                return self._claim_place(obs, f.name) or self._decision(Navigate(target=f.name, stand_pose=idx))
            self.explored.add(f.name)  # standing there already: seen
        return None

    def _search_round(self, obs: Observation) -> Decision | None:
        """Every container and surface has been seen and a target the finisher asked for is still
        nowhere (moved or added while the team worked): look at every surface again, the lead
        the nearer ones, the working scouts (if any) the rest, split among them."""
        surfaces = self._open_surfaces(obs)
        if not surfaces:
            return None
        self.explored -= set(surfaces)
        here = obs.status.base
        if here is not None:
            surfaces.sort(key=lambda s: _dist2(_furniture(obs, s).position, (here.x, here.y)))  # type: ignore[union-attr]
        scouts = [s for s in self._with_role(obs, "scout") if self._works(obs, s) and s not in self.lapsed]
        if not scouts:
            self.mine = surfaces
            return self._next_exploration(obs)
        cut = max(1, math.ceil(len(surfaces) * (SHARE / (SHARE + len(scouts)))))
        self.mine, rest = surfaces[:cut], surfaces[cut:]
        if not rest:
            return self._next_exploration(obs)
        return self._hand_to_scouts(obs, rest, scouts[: len(rest)])

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
