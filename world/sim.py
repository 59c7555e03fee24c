"""The PyBullet world of one episode: scene, robots, objects, skills and each robot's partial view.

Robots move kinematically (bases set along A* paths, arms set along OMPL plans); a held
object follows the suction cup. Every skill returns a `SkillOutcome` whose feedback sentence
comes from what the planners and checks measured.

Skills act on the real world; what a robot observes is its own memory (world/beliefs.py):
objects where it last saw them or was told they are, containers open or closed as it last saw
them. Furniture itself (names, poses, stand and place poses) is known to every robot.
"""

from __future__ import annotations

import math
import re
import zlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from mhrc.world.quiet import pybullet as p  # no C banner on stdout
import structlog

from mhrc.core.fidelity import parse_aids

from mhrc.core.protocol import (
    Action,
    Communicate,
    FurnitureView,
    Move,
    Navigate,
    ObjectView,
    ObjectPose,
    Observation,
    Open,
    OutcomeCode,
    Pick,
    Place,
    Pose2D,
    RobotPose,
    RobotStatus,
    SkillOutcome,
    Wait,
)

from . import assets, skills
from . import feedback as fb
from .arm import ArmPlanner
from .assets import AssetDir
from .beliefs import Beliefs
from .bound import lower_bound, symbolic_episode
from .robots import KINDS, ROBOTS, TEAM, RobotBody, spawn
from .scene import Fixture, Layout, build_scene, get_layout
from .tasks import ObjectKind, Seen, TaskResult, get_task

log = structlog.get_logger("mhrc.world.sim")

N_OBJECTS = (3, 6)


def check_episode(*, task: str, scene: str, n_objects: int) -> None:
    """Raise ValueError naming the problem, without building anything."""
    get_task(task)
    get_layout(scene)
    if not N_OBJECTS[0] <= n_objects <= N_OBJECTS[1]:
        raise ValueError(f"n_objects must be between {N_OBJECTS[0]} and {N_OBJECTS[1]}, not {n_objects}")


@dataclass
class ObjectState:
    name: str
    kind: ObjectKind
    body: int
    on: str | None  # furniture or a fixture (tray, panel, cutting board)
    inside: bool  # in a container (a drawer, a chest) rather than on a surface
    target: bool
    local: tuple[float, float] | None = None  # position in the container's frame while inside
    held_by: str | None = None


class Sim:
    """The PyBullet world of one episode (p.DIRECT unless gui=True)."""

    def __init__(
        self,
        *,
        task: str = "pack_objects",
        scene: str = "kitchen",
        seed: int = 0,
        n_objects: int = 4,
        gui: bool = False,
        robots: tuple[str, ...] = ROBOTS,
        aids: tuple[str, ...] | frozenset[str] = (),
    ) -> None:
        check_episode(task=task, scene=scene, n_objects=n_objects)
        self.aids: frozenset[str] = frozenset(parse_aids(aids))
        # motion noise: its own stream, apart from the generator's, and different for every episode of a seed
        self.rng = np.random.default_rng([seed, zlib.crc32(f"{task}/{scene}/{n_objects}".encode()), 0x4D485243])
        if not {"alice", "bob"} <= set(robots) or not set(robots) <= set(ROBOTS):
            raise ValueError(f"robots must include alice and bob and come from {', '.join(ROBOTS)}, not {robots}")
        self.robots: tuple[str, ...] = tuple(r for r in ROBOTS if r in robots)
        self.task_id, self.scene_id, self.seed, self.n_objects = task, scene, seed, n_objects
        self.task = get_task(task)
        self.layout: Layout = get_layout(scene)
        self.cid = p.connect(p.GUI if gui else p.DIRECT)
        self.assets = AssetDir()
        try:
            if gui:
                p.configureDebugVisualizer(p.COV_ENABLE_RENDERING, 0, physicsClientId=self.cid)
            self._build()
            if gui:
                p.configureDebugVisualizer(p.COV_ENABLE_RENDERING, 1, physicsClientId=self.cid)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ building
    def _build(self) -> None:
        lay = self.layout
        margin = max(KINDS[TEAM[r]].footprint for r in self.robots)
        self.fixtures: dict[str, Fixture] = {fx.name: fx for fx in self.task.fixtures(lay)}
        self.scene = build_scene(self.cid, lay, self.assets, margin, list(self.fixtures.values()))
        self.grid = self.scene.grid
        self.planner = ArmPlanner(self.scene.statics, seed=self.seed)
        self.opening: dict[str, float] = {name: 0.0 for name in self.scene.joints}  # container -> joint value
        self.bots: dict[str, RobotBody] = {}
        for name in self.robots:
            kind = KINDS[TEAM[name]]
            if kind.mobile:
                self.bots[name] = spawn(self.cid, name, kind, self.assets, pose=lay.starts[name])
            else:
                self.bots[name] = spawn(self.cid, name, kind, self.assets, arm_base=lay.bob_base, arm_yaw=lay.bob_yaw)
        self.objects: dict[str, ObjectState] = {}
        self.targets: list[str] = []
        self.goals: dict[str, str] = {}  # target -> the fixture it must end on
        self.known: dict[str, set[str]] = {r: set() for r in self.robots}  # the objects in each robot's scene graph
        # what each robot believes of them and of the containers; a fixed arm stands at its table for good
        self.beliefs: dict[str, Beliefs] = {r: Beliefs(at=None if KINDS[TEAM[r]].mobile else lay.bob_table) for r in self.robots}
        self._stamp = 0  # the moments robots look at things, in order (see beliefs.py)
        for pl in self.task.generate(lay, self.seed, self.n_objects):
            k = pl.kind
            path = assets.write_object(self.assets, k.name, k.shape, k.color)
            body = p.loadURDF(path, (0, 0, -5), physicsClientId=self.cid)
            obj = ObjectState(k.name, k, body, pl.furniture, pl.inside, pl.target, local=pl.xy if pl.inside else None)
            self.objects[k.name] = obj
            if pl.target:
                self.targets.append(k.name)
                self.goals[k.name] = self.task.goal(k)
            if pl.inside:
                self._follow_container(obj)
            else:
                f = lay.get(pl.furniture)
                assert f is not None
                self._rest(obj, pl.xy[0], pl.xy[1], f.top)
        log.debug("episode built", task=self.task_id, scene=self.scene_id, seed=self.seed, objects=list(self.objects))

    def close(self) -> None:
        """Disconnect every PyBullet client and remove the generated assets (idempotent)."""
        if self.cid >= 0:
            p.disconnect(self.cid)
            self.cid = -1
        planner: ArmPlanner | None = getattr(self, "planner", None)
        if planner is not None:
            planner.close()
        self.assets.close()

    def __enter__(self) -> Sim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ object and container state
    def position(self, obj: ObjectState) -> tuple[float, float, float]:
        pos, _ = p.getBasePositionAndOrientation(obj.body, physicsClientId=self.cid)
        return (float(pos[0]), float(pos[1]), float(pos[2]))

    _pos = position  # the name the team plan uses

    def yaw(self, obj: ObjectState) -> float:
        _, orn = p.getBasePositionAndOrientation(obj.body, physicsClientId=self.cid)
        return float(p.getEulerFromQuaternion(orn)[2])

    def _rest(self, obj: ObjectState, x: float, y: float, surface_z: float, yaw: float = 0.0) -> None:
        orn = p.getQuaternionFromEuler((0, 0, yaw))
        p.resetBasePositionAndOrientation(obj.body, (x, y, surface_z + obj.kind.height / 2), orn, physicsClientId=self.cid)

    def _container_frame(self, name: str) -> tuple[tuple[float, float, float], float]:
        """World position and yaw of where a container's contents lie: a drawer link's origin (the
        centre of its floor surface), the centre of a chest's inside floor or of a cupboard's
        cavity floor (neither moves with its lid or door)."""
        f = self.layout.get(name)
        assert f is not None
        body = self.scene.bodies[name]
        if f.lid is not None:
            pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=self.cid)
            return (float(pos[0]), float(pos[1]), f.lid.floor), float(p.getEulerFromQuaternion(orn)[2])
        if f.door is not None:
            pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=self.cid)
            cavity, _ = f.cupboard_geometry().cavity
            world, _ = p.multiplyTransforms(pos, orn, cavity, (0, 0, 0, 1))
            return (float(world[0]), float(world[1]), float(world[2])), float(p.getEulerFromQuaternion(orn)[2])
        st = p.getLinkState(body, self.scene.joints[name], computeForwardKinematics=True, physicsClientId=self.cid)
        yaw = p.getEulerFromQuaternion(st[5])[2]
        return (float(st[4][0]), float(st[4][1]), float(st[4][2])), float(yaw)

    def _to_world(self, name: str, local: tuple[float, float, float]) -> tuple[float, float, float]:
        (x, y, z), yaw = self._container_frame(name)
        c, s = math.cos(yaw), math.sin(yaw)
        return (x + c * local[0] - s * local[1], y + s * local[0] + c * local[1], z + local[2])

    def _follow_container(self, obj: ObjectState) -> None:
        assert obj.on is not None and obj.local is not None
        x, y, z = self._to_world(obj.on, (obj.local[0], obj.local[1], 0.0))
        self._rest(obj, x, y, z)

    def is_open(self, name: str) -> bool:
        return self.opening.get(name, 0.0) > 0.0

    def set_container(self, name: str, value: float) -> None:
        """Slide a drawer to `value` metres open, or swing a lid to `value` rad; what lies in a
        drawer moves along. The planner's copy is moved too."""
        p.resetJointState(self.scene.bodies[name], self.scene.joints[name], value, physicsClientId=self.cid)
        self.opening[name] = value
        self.planner.set_joint(name, self.scene.joints[name], value)
        for o in self.objects.values():
            if o.on == name and o.inside and o.held_by is None:
                self._follow_container(o)

    def handle_position(self, name: str) -> tuple[float, float, float]:
        """Top centre of a container's handle, wherever its drawer, lid or door now is."""
        f = self.layout.get(name)
        assert f is not None
        if f.lid is not None or f.door is not None:
            st = p.getLinkState(self.scene.bodies[name], self.scene.joints[name], computeForwardKinematics=True, physicsClientId=self.cid)
            handle = f.chest_geometry().handle if f.lid is not None else f.cupboard_geometry().handle
            pos, _ = p.multiplyTransforms(st[4], st[5], handle, (0, 0, 0, 1))
            return (float(pos[0]), float(pos[1]), float(pos[2]))
        return self._to_world(name, f.drawer_geometry().handle)

    def table_top(self) -> float:
        f = self.layout.get(self.layout.bob_table)
        assert f is not None
        return f.top

    def fixture_top(self, name: str, without: ObjectState | None = None) -> float:
        """The z where the next object set on fixture `name` rests (the top of the stack, for a stacking fixture)."""
        fx = self.fixtures[name]
        top = self.table_top() + fx.thickness
        if fx.stack:
            top += sum(o.kind.height for o in self.objects.values() if o.on == name and o.held_by is None and o is not without)
        return top

    def fixture_at(self, x: float, y: float) -> Fixture | None:
        return next((fx for fx in self.fixtures.values() if fx.contains_xy(x, y)), None)

    def on_bob_table(self, on: str | None) -> bool:
        """Whether `on` is Bob's table or one of the fixtures lying on it."""
        return on == self.layout.bob_table or on in self.fixtures

    def grasp(self, r: RobotBody, obj: ObjectState) -> None:
        r.attach(obj.name, obj.body)
        obj.held_by, obj.on, obj.inside, obj.local = r.name, None, False, None
        if r.name in self.beliefs:  # a robot knows what it holds
            self.beliefs[r.name].note(self._object_view(obj), self._next_stamp())
            self.known[r.name].add(obj.name)

    def release(
        self, r: RobotBody, obj: ObjectState, spot: tuple[float, float, float], yaw: float, location: str | None = None, error: tuple[float, float] = (0.0, 0.0)
    ) -> None:
        """Let go of `obj` over `spot` (x, y, surface z), turned to `yaw`, placing it on `location`.

        With the exact_motion aid it is set down upright on the spot. Otherwise it falls from
        where the tool holds it, shifted by the release `error` (x, y; kept over the furniture
        that bears `location`, so it never drops off the edge), and settles under gravity
        (`skills.settle`): it may tip off a stack, catch a rim or slide off a panel."""
        r.release()
        obj.held_by = None
        if "exact_motion" in self.aids:
            self._rest(obj, spot[0], spot[1], spot[2], yaw)
            return
        x, y, z = self.position(obj)
        x, y = x + error[0], y + error[1]
        bearer = self.layout.get(self.layout.bob_table if location in self.fixtures else location or "")
        if bearer is not None:
            hx, hy = skills.half_extent(obj.kind, yaw, gap=0.0)
            (cx, cy), (sx, sy) = bearer.center, bearer.size[:2]
            x = min(max(x, cx - sx / 2 + hx), cx + sx / 2 - hx)
            y = min(max(y, cy - sy / 2 + hy), cy + sy / 2 - hy)
        orn = p.getQuaternionFromEuler((0, 0, yaw))
        p.resetBasePositionAndOrientation(obj.body, (x, y, max(z, spot[2] + obj.kind.height / 2)), orn, physicsClientId=self.cid)
        skills.settle(self, obj)

    def settled_at(self, obj: ObjectState, location: str) -> bool:
        """Read where the released object really lies and record it; True if that is `location`.

        On a fixture: its centre over the fixture and its lowest point on the fixture's surface
        (on the top of the stack, for a stacking fixture), tilted or not. Otherwise on the furniture
        its centre is over, if it rests on that furniture or on something lying there (Bob's
        table, for anything that missed a fixture on it); on nothing (the floor) else."""
        x, y, _ = self.position(obj)
        lay = self.layout
        (_, _, bottom), _ = p.getAABB(obj.body, physicsClientId=self.cid)
        obj.on, obj.inside = None, False
        fx = self.fixture_at(x, y)
        if fx is not None and abs(bottom - skills.surface_top(self, fx.name, without=obj)) < 0.008:
            obj.on = fx.name
        else:
            for f in lay.furniture:
                if f.place_pose is not None and f.contains_xy(x, y) and bottom > f.top - 0.01:
                    obj.on = f.name
                    break
        return obj.on == location

    def within_handover(self, spot: tuple[float, ...]) -> bool:
        """Whether Bob (if present) can pick from `spot` on his table."""
        bob = self.bots.get("bob")
        if bob is None or bob.kind.reach is None:
            return True
        ab = bob.arm_base()
        assert ab is not None
        return 0.3 <= math.hypot(spot[0] - ab[0], spot[1] - ab[1]) <= bob.kind.reach - 0.03

    def objects_on(self, furniture: str) -> list[str]:
        """What lies on (or, for a container, in) a piece of furniture; fixtures count as Bob's table."""
        where = {furniture, *self.fixtures} if furniture == self.layout.bob_table else {furniture}
        return sorted(o.name for o in self.objects.values() if o.on in where and o.held_by is None)

    # ------------------------------------------------------------------ knowledge
    # Each robot's scene graph is its own memory: `known[robot]` names the objects in it and
    # `beliefs[robot]` holds what the robot last saw or was told of each, and of every
    # container's open state. They change only when the robot looks (`look_at`: on arriving at
    # or opening furniture; then on every refresh, the furniture it stands at, for Bob his table
    # and its fixtures), holds or lets go of something, or is told (`tell`).
    def known_objects(self, robot: str) -> set[str]:
        """The objects in `robot`'s scene graph, once it has looked at what it stands at."""
        if robot not in self.beliefs:
            return set()
        self._refresh(robot)
        return set(self.known[robot])

    _known = known_objects

    def belief(self, robot: str, name: str) -> ObjectView | None:
        """`robot`'s view of object `name` (live with the live_state aid); None if it does not know it."""
        if name not in self.known_objects(robot):
            return None
        if "live_state" in self.aids:
            return self._object_view(self.objects[name])
        return self.beliefs[robot].objects[name].view

    def _next_stamp(self) -> int:
        self._stamp += 1
        return self._stamp

    def learn(self, robot: str, names: Iterable[str]) -> None:
        """`robot` learns of `names` as they are now (a stand-in for a report, for tests and scripts)."""
        stamp = self._next_stamp()
        for name in names:
            self.known[robot].add(name)
            self.beliefs[robot].note(self._object_view(self.objects[name]), stamp)

    def look_at(self, robot: str, furniture: str) -> None:
        """`robot` now stands at `furniture` and sees it: whether it is open, and what lies on it
        (or, open, in it). Skills call this when a robot arrives at furniture or opens it; the
        robot keeps seeing it until it looks at other furniture."""
        if robot in self.beliefs and self.layout.get(furniture) is not None:
            self.beliefs[robot].at = furniture
            self._see(robot, furniture)

    def _see(self, robot: str, furniture: str) -> None:
        f = self.layout.get(furniture)
        assert f is not None
        is_open = self.is_open(furniture) if f.container is not None else None
        places = {furniture, *self.fixtures} if furniture == self.layout.bob_table else {furniture}
        visible = [] if is_open is False else [self._object_view(self.objects[n]) for n in self.objects_on(furniture)]
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
        for o in self.objects.values():
            mine = b.objects.get(o.name)
            if o.held_by == robot or (mine is None and o.name in self.known[robot]) or (mine is not None and mine.view.held_by == robot):
                b.note(self._object_view(o), stamp)
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
        named = [n for n in sorted(self.known_objects(sender)) if re.search(rf"\b{re.escape(n.replace('_', ' '))}\b", words)]
        then = Beliefs(objects={n: b for n, b in self.beliefs[sender].objects.items() if n in named})  # beliefs are frozen values

        def deliver() -> None:
            self.known[receiver].update(named)
            self.beliefs[receiver].told(sender, then, named)

        return deliver

    # ------------------------------------------------------------------ public API
    def capabilities(self, robot: str) -> frozenset[str]:
        return frozenset(KINDS[TEAM[robot]].skills) if robot in self.bots else frozenset()

    def finishers(self) -> frozenset[str]:
        """The robots that may place on the task's goal fixtures (the paper: Bob)."""
        return frozenset(name for name, b in self.bots.items() if b.kind.finishes_task)

    def execute(self, robot: str, action: Action) -> SkillOutcome:
        """Run one action of `robot`. Bad arguments give a failure outcome, never an exception."""
        if isinstance(action, Communicate):
            raise ValueError("communicate is handled by the world service, not the simulator")
        if robot not in self.bots:
            return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, fb.no_such_robot(robot, self.robots))
        r = self.bots[robot]
        if action.skill not in r.kind.skills:
            return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, fb.not_capable(robot, action.skill, r.kind.skills))
        out: SkillOutcome
        if isinstance(action, Wait):
            out = SkillOutcome.ok(fb.waited(), sim_time=1.0)
        elif isinstance(action, Navigate):
            out = skills.navigate(self, r, action)
        elif isinstance(action, Move):
            out = skills.move(self, r, action)
        elif isinstance(action, Open):
            out = skills.open_(self, r, action)
        elif isinstance(action, Pick):
            out = skills.pick(self, r, action)
        elif isinstance(action, Place):
            out = skills.place(self, r, action)
        else:  # pragma: no cover - the Action union is exhaustive
            out = SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, f"Unknown skill {action.skill}.")
        log.debug("skill", robot=robot, action=action.call(), code=out.code.value, sim_time=round(out.sim_time, 3))
        return out

    def furniture_names(self) -> list[str]:
        return [f.name for f in self.layout.furniture] + list(self.fixtures)

    def place_names(self) -> list[str]:
        return list(self.fixtures) + [f.name for f in self.layout.furniture if f.place_pose is not None]

    # ------------------------------------------------------------------ views
    def _object_view(self, o: ObjectState) -> ObjectView:
        x, y, z = self.position(o)
        return ObjectView(name=o.name, position=(round(x, 3), round(y, 3), round(z, 3)), on=o.on, inside=o.inside, held_by=o.held_by)

    def _furniture_views(self, robot: str | None = None) -> list[FurnitureView]:
        """Every piece of furniture and fixture; open states live, or as `robot` believes them."""
        out = []
        for f in self.layout.furniture:
            out.append(
                FurnitureView(
                    name=f.name,
                    kind=f.kind,
                    position=(f.center[0], f.center[1], f.top),
                    yaw=round(f.yaw, 4),
                    openable=f.container is not None,
                    is_open=None if f.container is None else self.is_open(f.name) if robot is None else self.beliefs[robot].is_open(f.name),
                    stand_poses=[Pose2D(x=x, y=y, yaw=round(yaw, 4)) for x, y, yaw in f.stand_poses],
                    place_pose=(f.place_pose[0], f.place_pose[1], f.top) if f.place_pose else None,
                )
            )
        for fx in self.fixtures.values():
            top = round(self.fixture_top(fx.name), 3)
            x, y = fx.center
            out.append(FurnitureView(name=fx.name, kind=f"{fx.kind} on {self.layout.bob_table}", position=(x, y, top), place_pose=(x, y, top)))
        return out

    def _status(self, robot: str) -> RobotStatus:
        r = self.bots[robot]
        ab = r.arm_base()
        return RobotStatus(
            name=robot,
            kind=r.kind.label,
            skills=list(r.kind.skills),
            base=Pose2D(x=round(r.base[0], 3), y=round(r.base[1], 3), yaw=round(r.base[2], 4)) if r.base else None,
            arm_base=(round(ab[0], 3), round(ab[1], 3), round(ab[2], 3)) if ab else None,
            reach=r.kind.reach,
            holding=r.holding,
        )

    def observe(self, robot: str, tick: int) -> Observation:
        """The robot's own partial view; new_messages is left for the world service to fill."""
        if robot not in self.bots:
            raise ValueError(f"there is no robot {robot!r} in this episode ({', '.join(self.robots)})")
        known = self.known_objects(robot)
        is_bob = robot == "bob"
        live = "live_state" in self.aids  # the aid: known objects and containers as they are now
        beliefs = self.beliefs[robot].objects
        return Observation(
            robot=robot,
            tick=tick,
            status=self._status(robot),
            furniture=self._furniture_views(None if live else robot),
            objects=[self._object_view(o) if live else beliefs[o.name].view for o in self.objects.values() if o.name in known],
            task_brief=self.task.brief,
            task_detail=self.task.detail(robot, self.targets, self.goals, self.aids),
            targets=list(self.targets) if is_bob else [],
            goals=dict(self.goals) if is_bob and "goal_map" in self.aids else {},
            ordered=self.task.ordered,
            task_status=self.task_status() if is_bob else None,
            teammates={o: list(self.bots[o].kind.skills) for o in self.robots if o != robot},
        )

    def lower_bound(self) -> int:
        """A lower bound on the temporal steps any team needs for this episode (see bound.py)."""
        return lower_bound(symbolic_episode(self))

    def answer_key(self) -> tuple[list[str], dict[str, str], bool]:
        """The task's targets (in task order), each one's goal fixture, and whether they must
        arrive in order: said once the episode is over, for reports (EpisodeDone)."""
        return list(self.targets), dict(self.goals), bool(self.task.ordered)

    def seen(self) -> list[Seen]:
        """Every object's end state as the goal check reads it."""
        return [Seen(o.name, o.kind, o.on if o.held_by is None else None, round(self.position(o)[2], 4)) for o in self.objects.values()]

    def evaluate(self) -> TaskResult:
        return self.task.evaluate(self.targets, self.seen())

    def task_status(self) -> str:
        return self.task.status(self.targets, self.seen(), self.aids)

    def views(self) -> tuple[list[FurnitureView], list[ObjectView]]:
        """Full ground truth, for observers."""
        return self._furniture_views(), [self._object_view(o) for o in self.objects.values()]

    def poses(self) -> tuple[dict[str, RobotPose], dict[str, ObjectPose], dict[str, bool]]:
        """Ground truth for viewers (the `snapshot` event): robots, objects, containers."""
        robots = {}
        for r in self.bots.values():
            x, y, yaw = r.base if r.base is not None else (*(r.fixed_arm or (0.0, 0.0, 0.0))[:2], r.fixed_yaw)
            robots[r.name] = RobotPose(x=round(x, 4), y=round(y, 4), yaw=round(yaw, 4), holding=r.holding)
        objects = {}
        for o in self.objects.values():
            x, y, z = self.position(o)
            objects[o.name] = ObjectPose(x=round(x, 4), y=round(y, 4), z=round(z, 4), on=o.on, inside=o.inside, held_by=o.held_by)
        return robots, objects, {name: self.is_open(name) for name in self.opening}

    def apply_snapshot(self, robots: Mapping[str, RobotPose], objects: Mapping[str, ObjectPose], open: Mapping[str, bool]) -> None:
        """Teleport bodies to a `snapshot` event's poses (for videos; no physics is stepped):
        containers, mobile bases, then objects; a held object hangs under its holder's tool
        tip (the arm as it stands now). Names this episode lacks are skipped."""
        for name, is_open in open.items():
            f = self.layout.get(name)
            if name in self.opening and f is not None and f.container is not None:
                self.set_container(name, f.container.travel if is_open else 0.0)
        for name, rp in robots.items():
            bot = self.bots.get(name)
            if bot is not None:
                if bot.base is not None:
                    bot.set_base((rp.x, rp.y, rp.yaw))
                bot.holding = rp.holding
        for name, op in objects.items():
            obj = self.objects.get(name)
            if obj is None:
                continue
            obj.on, obj.inside, obj.held_by = op.on, op.inside, op.held_by
            holder = self.bots.get(op.held_by or "")
            if holder is not None and holder.kind.has_arm:
                x, y, z = holder.tip()
                self._rest(obj, x, y, z - obj.kind.height, holder.tool_yaw())
                continue
            self._rest(obj, op.x, op.y, op.z - obj.kind.height / 2)
            if op.inside and op.on in self.opening:  # keep its spot in the container's frame, to move along
                (cx, cy, _), cyaw = self._container_frame(op.on)
                c, s = math.cos(cyaw), math.sin(cyaw)
                obj.local = (c * (op.x - cx) + s * (op.y - cy), -s * (op.x - cx) + c * (op.y - cy))

    def snapshot(self) -> dict[str, Any]:
        """Every body's pose and robot state, for comparing runs (determinism tests)."""
        return {
            "objects": {o.name: (self.position(o), o.on, o.inside, o.held_by) for o in self.objects.values()},
            "robots": {r.name: (r.base, tuple(round(float(v), 9) for v in r.q), r.holding) for r in self.bots.values()},
            "containers": dict(self.opening),
        }
