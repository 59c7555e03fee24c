"""What robots and observers see of the physical world: each robot's scene graph, its
observation, and the ground truth for viewers and traces.

Each robot's scene graph is its own memory (`Knowledge`): `known[robot]` names the objects in
it and `beliefs[robot]` holds what the robot last saw or was told of each, and of every
container's open state. They change only when the robot looks (`look_at`: on arriving at or
opening furniture; then on every refresh, the furniture it stands at, for Bob his table and its
fixtures), holds or lets go of something, or is told (`tell`). Furniture itself (names, poses,
stand and place poses) is known to every robot.

The rest are views built from the physical world: a robot's `observation`, the full `views`
for state queries, the `poses` of the snapshot event (and `apply_snapshot`, its inverse, for
videos), and `snapshot` for comparing runs.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterable, Mapping
from typing import TypedDict

from mhrc.core.protocol import FurnitureView, ObjectPose, ObjectView, Observation, Pose2D, RobotPose, RobotStatus

from .beliefs import Beliefs
from .briefs import Briefing, brief, detail, either, role_of
from .physics import ObjectState, PhysicalWorld
from .robots import RobotBody
from .tasks import Task


def object_view(world: PhysicalWorld, o: ObjectState) -> ObjectView:
    """An object as it is now."""
    x, y, z = world.position(o)
    return ObjectView(
        name=o.name,
        position=(round(x, 3), round(y, 3), round(z, 3)),
        yaw=round(world.yaw(o), 3),
        on=o.on,
        inside=o.inside,
        held_by=o.held_by,
    )


class Knowledge:
    """Every robot's scene graph over one physical world (see the module docstring)."""

    def __init__(self, world: PhysicalWorld, robots: Iterable[str], aids: frozenset[str]) -> None:
        self.world = world
        self.aids = aids
        self.known: dict[str, set[str]] = {r: set() for r in robots}  # the objects in each robot's scene graph
        # what each robot believes of them and of the containers; a fixed arm stands at its table for good
        self.beliefs: dict[str, Beliefs] = {
            r: Beliefs(at=None if world.bots[r].kind.mobile else world.layout.bob_table) for r in self.known
        }
        self._stamp = 0  # the moments robots look at things, in order (see beliefs.py)

    def _next_stamp(self) -> int:
        self._stamp += 1
        return self._stamp

    def known_objects(self, robot: str) -> set[str]:
        """The objects in `robot`'s scene graph, once it has looked at what it stands at."""
        if robot not in self.beliefs:
            return set()
        self._refresh(robot)
        return set(self.known[robot])

    def belief(self, robot: str, name: str) -> ObjectView | None:
        """`robot`'s view of object `name` (live with the live_state aid); None if it does not know it."""
        if name not in self.known_objects(robot):
            return None
        if "live_state" in self.aids:
            return object_view(self.world, self.world.objects[name])
        return self.beliefs[robot].objects[name].view

    def holds(self, robot: str, obj: ObjectState) -> None:
        """`robot` has just gripped `obj`: a robot knows what it holds."""
        if robot in self.beliefs:
            self.beliefs[robot].note(object_view(self.world, obj), self._next_stamp())
            self.known[robot].add(obj.name)

    def learn(self, robot: str, names: Iterable[str]) -> None:
        """`robot` learns of `names` as they are now (a stand-in for a report, for tests and scripts)."""
        stamp = self._next_stamp()
        for name in names:
            self.known[robot].add(name)
            self.beliefs[robot].note(object_view(self.world, self.world.objects[name]), stamp)

    def look_at(self, robot: str, furniture: str) -> None:
        """`robot` now stands at `furniture` and sees it: whether it is open, and what lies on it
        (or, open, in it). Skills call this when a robot arrives at furniture or opens it; the
        robot keeps seeing it until it looks at other furniture."""
        if robot in self.beliefs and self.world.layout.get(furniture) is not None:
            self.beliefs[robot].at = furniture
            self._see(robot, furniture)

    def _see(self, robot: str, furniture: str) -> None:
        w = self.world
        f = w.layout.get(furniture)
        assert f is not None
        is_open = w.is_open(furniture) if f.container is not None else None
        places = {furniture, *w.fixtures} if furniture == w.layout.bob_table else {furniture}
        visible = [] if is_open is False else [object_view(w, w.objects[n]) for n in w.objects_on(furniture)]
        self.beliefs[robot].see(furniture, places, is_open, visible, self._next_stamp())
        self.known[robot].update(v.name for v in visible)

    def _refresh(self, robot: str) -> None:
        """What `robot` sees without acting: the furniture it stands at, what it holds and what it
        has just let go of. A name put in `known` directly (tests, the team plan) is believed as
        it is now."""
        b = self.beliefs[robot]
        if b.at is not None:
            self._see(robot, b.at)
        stamp = self._next_stamp()
        for o in self.world.objects.values():
            mine = b.objects.get(o.name)
            if (
                o.held_by == robot
                or (mine is None and o.name in self.known[robot])
                or (mine is not None and mine.view.held_by == robot)
            ):
                b.note(object_view(self.world, o), stamp)
                self.known[robot].add(o.name)

    def tell(self, receiver: str, sender: str, text: str) -> None:
        """A message was delivered: objects it names that the sender knows become known to the
        receiver as the sender believes them (unless the receiver knows something newer)."""
        self.message(receiver, sender, text)()

    def message(self, receiver: str, sender: str, text: str) -> Callable[[], None]:
        """A message was sent: what it will tell its receiver, fixed now (the objects it names
        that the sender knows, as the sender believes them now). The receiver learns it when the
        returned call runs: when the message is delivered, not before (`tell` does both at once)."""
        if receiver not in self.beliefs or sender not in self.beliefs:
            return lambda: None
        words = " ".join(re.findall(r"[a-z0-9]+", text.lower().replace("_", " ")))
        named = [
            n for n in sorted(self.known_objects(sender)) if re.search(rf"\b{re.escape(n.replace('_', ' '))}\b", words)
        ]
        then = Beliefs(
            objects={n: b for n, b in self.beliefs[sender].objects.items() if n in named}
        )  # beliefs are frozen values

        def deliver() -> None:
            self.known[receiver].update(named)
            self.beliefs[receiver].told(sender, then, named)

        return deliver


# --------------------------------------------------------------------------- views


def furniture_views(world: PhysicalWorld, believed: Beliefs | None = None) -> list[FurnitureView]:
    """Every piece of furniture and fixture; open states live, or as in `believed` (a robot's beliefs)."""
    out = []
    for f in world.layout.furniture:
        out.append(
            FurnitureView(
                name=f.name,
                kind=f.kind,
                position=(f.center[0], f.center[1], f.top),
                yaw=round(f.yaw, 4),
                openable=f.container is not None,
                is_open=None
                if f.container is None
                else world.is_open(f.name)
                if believed is None
                else believed.is_open(f.name),
                stand_poses=[Pose2D(x=x, y=y, yaw=round(yaw, 4)) for x, y, yaw in f.stand_poses],
                place_pose=(f.place_pose[0], f.place_pose[1], f.top) if f.place_pose else None,
            )
        )
    for fx in world.fixtures.values():
        top = round(world.fixture_top(fx.name), 3)
        x, y = fx.center
        out.append(
            FurnitureView(
                name=fx.name,
                kind=f"{fx.kind} on {world.layout.bob_table}",
                position=(x, y, top),
                place_pose=(x, y, top),
            )
        )
    return out


def robot_status(r: RobotBody) -> RobotStatus:
    ab = r.arm_base()
    return RobotStatus(
        name=r.name,
        kind=r.kind.label,
        skills=list(r.kind.skills),
        base=Pose2D(x=round(r.base[0], 3), y=round(r.base[1], 3), yaw=round(r.base[2], 4)) if r.base else None,
        arm_base=(round(ab[0], 3), round(ab[1], 3), round(ab[2], 3)) if ab else None,
        reach=r.kind.reach,
        holding=r.holding,
    )


def observation(
    world: PhysicalWorld,
    knowledge: Knowledge,
    task: Task,
    targets: list[str],
    goals: dict[str, str],
    robot: str,
    tick: int,
) -> Observation:
    """`robot`'s own partial view; new_messages is left for the world service to fill. Each
    robot gets its role's brief and detail (world/briefs.py); the robot that finishes the task is
    also told the targets, its progress and (goal_map aid) the goals."""
    if robot not in world.bots:
        raise ValueError(f"there is no robot {robot!r} in this episode ({', '.join(world.bots)})")
    known = knowledge.known_objects(robot)
    r = world.bots[robot]
    finisher = r.kind.finishes_task
    aids = knowledge.aids
    live = "live_state" in aids  # the aid: known objects and containers as they are now
    beliefs = knowledge.beliefs[robot].objects
    role = role_of(finisher, r.kind.mobile, r.kind.has_arm)
    crew = briefing(world)
    return Observation(
        robot=robot,
        tick=tick,
        status=robot_status(r),
        furniture=furniture_views(world, None if live else knowledge.beliefs[robot]),
        objects=[
            object_view(world, o) if live else beliefs[o.name].view for o in world.objects.values() if o.name in known
        ],
        task_brief=brief(task, role, crew),
        task_detail=detail(task, role, crew, targets, goals, aids),
        targets=list(targets) if finisher else [],
        goals=dict(goals) if finisher and "goal_map" in aids else {},
        ordered=task.ordered,
        task_status=task.status(targets, world.seen(), aids) if finisher else None,
        teammates={o: list(world.bots[o].kind.skills) for o in world.bots if o != robot},
    )


def briefing(world: PhysicalWorld) -> Briefing:
    """Whom the task texts name: the finisher and the fetchers of this episode's team, by kind
    (the paper's Bob and Alice; several fetchers as "Alice or Carol", in the team's order; the
    finisher stands in for a fetcher the team lacks)."""
    bots = world.bots.values()
    finisher = next((b.name for b in bots if b.kind.finishes_task), "")
    fetchers = [b.name for b in bots if role_of(b.kind.finishes_task, b.kind.mobile, b.kind.has_arm) == "fetcher"]
    return Briefing(
        finisher=finisher.capitalize(),
        fetcher=either([f.capitalize() for f in fetchers or [finisher]]),
        table=world.layout.bob_table,
    )


def views(world: PhysicalWorld) -> tuple[list[FurnitureView], list[ObjectView]]:
    """Full ground truth, for observers."""
    return furniture_views(world), [object_view(world, o) for o in world.objects.values()]


def poses(world: PhysicalWorld) -> tuple[dict[str, RobotPose], dict[str, ObjectPose], dict[str, bool]]:
    """Ground truth for viewers (the `snapshot` event): robots, objects, containers."""
    robots = {}
    for r in world.bots.values():
        x, y, yaw = r.base if r.base is not None else (*(r.fixed_arm or (0.0, 0.0, 0.0))[:2], r.fixed_yaw)
        robots[r.name] = RobotPose(x=round(x, 4), y=round(y, 4), yaw=round(yaw, 4), holding=r.holding)
    objects = {}
    for o in world.objects.values():
        x, y, z = world.position(o)
        objects[o.name] = ObjectPose(
            x=round(x, 4), y=round(y, 4), z=round(z, 4), on=o.on, inside=o.inside, held_by=o.held_by
        )
    return robots, objects, {name: world.is_open(name) for name in world.opening}


def apply_snapshot(
    world: PhysicalWorld, robots: Mapping[str, RobotPose], objects: Mapping[str, ObjectPose], open: Mapping[str, bool]
) -> None:
    """Teleport bodies to a `snapshot` event's poses (for videos; no physics is stepped):
    containers, mobile bases, then objects; a held object hangs under its holder's tool
    tip (the arm as it stands now). Names this episode lacks are skipped."""
    for name, is_open in open.items():
        f = world.layout.get(name)
        if name in world.opening and f is not None and f.container is not None:
            world.set_container(name, f.container.travel if is_open else 0.0)
    for name, rp in robots.items():
        bot = world.bots.get(name)
        if bot is not None:
            if bot.base is not None:
                bot.set_base((rp.x, rp.y, rp.yaw))
            bot.holding = rp.holding
    for name, op in objects.items():
        obj = world.objects.get(name)
        if obj is None:
            continue
        obj.on, obj.inside, obj.held_by = op.on, op.inside, op.held_by
        holder = world.bots.get(op.held_by or "")
        if holder is not None and holder.kind.has_arm:
            x, y, z = holder.tip()
            world.rest(obj, x, y, z - obj.kind.height, holder.tool_yaw())
            continue
        world.rest(obj, op.x, op.y, op.z - obj.kind.height / 2)
        if op.inside and op.on in world.opening:  # keep its spot in the container's frame, to move along
            (cx, cy, _), cyaw = world.container_frame(op.on)
            c, s = math.cos(cyaw), math.sin(cyaw)
            obj.local = (c * (op.x - cx) + s * (op.y - cy), -s * (op.x - cx) + c * (op.y - cy))


class WorldSnapshot(TypedDict):
    """Every body's pose and robot state (`snapshot`)."""

    objects: dict[str, tuple[tuple[float, float, float], str | None, bool, str | None]]  # position, on, inside, held by
    robots: dict[str, tuple[tuple[float, float, float] | None, tuple[float, ...], str | None]]  # base, joints, holding
    containers: dict[str, float]  # container -> its joint's value


def snapshot(world: PhysicalWorld) -> WorldSnapshot:
    """Every body's pose and robot state, for comparing runs (determinism tests)."""
    return {
        "objects": {o.name: (world.position(o), o.on, o.inside, o.held_by) for o in world.objects.values()},
        "robots": {r.name: (r.base, tuple(round(float(v), 9) for v in r.q), r.holding) for r in world.bots.values()},
        "containers": dict(world.opening),
    }
