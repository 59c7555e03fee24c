"""The physical state of one episode: its bodies in one PyBullet client, and where things are.

Furniture, fixtures, robots and objects as `Sim` built them; containers' joints; what an object
lies on or in, who holds it. Everything here is the live truth: skills act on it (through
their context), observers and each robot's eyes (observe.py) read it; what a robot knows of
it is observe.Knowledge's.

Objects are placed kinematically (set on a surface, carried under a tool tip); a released
object alone falls and settles under PyBullet physics (`settle`), unless the exact_motion aid
sets it down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from .arm import ArmPlanner
from .astar import Grid
from .furniture import Layout
from .robots import RobotBody
from .scene import BuiltScene, Fixture
from .tasks import ObjectKind, Seen

SPOT_GAP = 0.02  # clearance between placed objects' footprints
SETTLE_STEPS = 480  # at most 2 s of PyBullet time (240 Hz) for a released object to come to rest
SETTLE_STILL = 12  # steps in a row nearly still that count as at rest
GRAVITY = 9.81
STACK_TOUCH = 0.003  # m: how near a released piece must lie to a piece of the stack to rest on it
ROLLING_FRICTION = 0.005  # m: what stops a tipped disc or a ball rolling (PyBullet's default is none)


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


def half_extent(kind: ObjectKind, yaw: float, gap: float = SPOT_GAP) -> tuple[float, float]:
    """Half the x and y extent of an upright object turned by `yaw`, plus half of `gap`."""
    fx, fy = kind.shape.footprint
    c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
    return (c * fx + s * fy) / 2 + gap / 2, (s * fx + c * fy) / 2 + gap / 2


class PhysicalWorld:
    """One episode's bodies and their live state; `Sim` builds it (robots and objects included)."""

    def __init__(
        self,
        cid: int,
        layout: Layout,
        scene: BuiltScene,
        planner: ArmPlanner,
        fixtures: dict[str, Fixture],
        aids: frozenset[str],
    ) -> None:
        self.cid = cid
        self.layout = layout
        self.scene = scene
        self.grid = scene.grid
        self.planner = planner  # the arms' shadow planning client, kept in step with containers
        self.fixtures = fixtures
        self.aids = aids
        self.one_per_stand_pose = True  # Sim sets it by the team (off for the paper's)
        self.opening: dict[str, float] = {name: 0.0 for name in scene.joints}  # container -> joint value
        self.bots: dict[str, RobotBody] = {}
        self.objects: dict[str, ObjectState] = {}

    # ------------------------------------------------------------------ robots
    def grid_for(self, r: RobotBody) -> Grid:
        """The grid `r` plans on: the air's (walls only) for a flier, the floor's for a ground base."""
        if r.kind.flies:
            assert self.scene.air is not None, "the scene was built without the air's grid"
            return self.scene.air
        return self.grid

    def occupant(self, r: RobotBody, xy: tuple[float, float], within: float) -> str | None:
        """The robot other than `r` whose base is within `within` of `xy` on r's level: fliers
        share the air with fliers, ground bases the floor with ground bases (a drone hovers above
        a robot standing below it). None when the spot is free, and always without the rule
        (`one_per_stand_pose` off: the paper's team, whose robots may share a stand pose)."""
        if not self.one_per_stand_pose:
            return None
        for other in self.bots.values():
            if other is r or other.base is None or other.kind.flies != r.kind.flies:
                continue
            if math.hypot(other.base[0] - xy[0], other.base[1] - xy[1]) <= within:
                return other.name
        return None

    def finisher(self) -> RobotBody | None:
        """The robot that places on the task's goal fixtures (kinds.RobotKind.finishes_task; the paper's Bob)."""
        return next((b for b in self.bots.values() if b.kind.finishes_task), None)

    # ------------------------------------------------------------------ objects and containers
    def position(self, obj: ObjectState) -> tuple[float, float, float]:
        pos, _ = p.getBasePositionAndOrientation(obj.body, physicsClientId=self.cid)
        return (float(pos[0]), float(pos[1]), float(pos[2]))

    def yaw(self, obj: ObjectState) -> float:
        _, orn = p.getBasePositionAndOrientation(obj.body, physicsClientId=self.cid)
        return float(p.getEulerFromQuaternion(orn)[2])

    def rest(self, obj: ObjectState, x: float, y: float, surface_z: float, yaw: float = 0.0) -> None:
        """Set `obj` upright on a surface at height `surface_z`, its centre over (x, y)."""
        orn = p.getQuaternionFromEuler((0, 0, yaw))
        p.resetBasePositionAndOrientation(
            obj.body, (x, y, surface_z + obj.kind.height / 2), orn, physicsClientId=self.cid
        )

    def container_frame(self, name: str) -> tuple[tuple[float, float, float], float]:
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

    def to_world(self, name: str, local: tuple[float, float, float]) -> tuple[float, float, float]:
        (x, y, z), yaw = self.container_frame(name)
        c, s = math.cos(yaw), math.sin(yaw)
        return (x + c * local[0] - s * local[1], y + s * local[0] + c * local[1], z + local[2])

    def follow_container(self, obj: ObjectState) -> None:
        """Put an object that lies in a container at its spot in the container's frame."""
        assert obj.on is not None and obj.local is not None
        x, y, z = self.to_world(obj.on, (obj.local[0], obj.local[1], 0.0))
        self.rest(obj, x, y, z)

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
                self.follow_container(o)

    def handle_position(self, name: str) -> tuple[float, float, float]:
        """Top centre of a container's handle, wherever its drawer, lid or door now is."""
        f = self.layout.get(name)
        assert f is not None
        if f.lid is not None or f.door is not None:
            st = p.getLinkState(
                self.scene.bodies[name],
                self.scene.joints[name],
                computeForwardKinematics=True,
                physicsClientId=self.cid,
            )
            handle = f.chest_geometry().handle if f.lid is not None else f.cupboard_geometry().handle
            pos, _ = p.multiplyTransforms(st[4], st[5], handle, (0, 0, 0, 1))
            return (float(pos[0]), float(pos[1]), float(pos[2]))
        return self.to_world(name, f.drawer_geometry().handle)

    # ------------------------------------------------------------------ surfaces
    def table_top(self) -> float:
        f = self.layout.get(self.layout.bob_table)
        assert f is not None
        return f.top

    def fixture_top(self, name: str, without: ObjectState | None = None) -> float:
        """The z where the next object set on fixture `name` rests (the top of the stack, for a stacking fixture)."""
        fx = self.fixtures[name]
        top = self.table_top() + fx.thickness
        if fx.stack:
            top += sum(
                o.kind.height for o in self.objects.values() if o.on == name and o.held_by is None and o is not without
            )
        return top

    def surface_top(self, fixture: str, without: ObjectState | None = None) -> float:
        """Where the next object set on `fixture` comes to rest: its surface, or for a stacking
        fixture the highest top of what lies on it (measured, so a slice lying askew counts as it lies)."""
        fx = self.fixtures[fixture]
        top = self.table_top() + fx.thickness
        if not fx.stack:
            return top
        if "exact_motion" in self.aids:  # objects lie exactly as set down: the stack is the sum of their heights
            return self.fixture_top(fixture, without=without)
        tops = [
            p.getAABB(o.body, physicsClientId=self.cid)[1][2]
            for o in self.objects.values()
            if o.on == fixture and o.held_by is None and o is not without
        ]
        return max([top, *tops])

    def fixture_at(self, x: float, y: float) -> Fixture | None:
        return next((fx for fx in self.fixtures.values() if fx.contains_xy(x, y)), None)

    def on_bob_table(self, on: str | None) -> bool:
        """Whether `on` is Bob's table or one of the fixtures lying on it."""
        return on == self.layout.bob_table or on in self.fixtures

    def within_handover(self, spot: tuple[float, ...]) -> bool:
        """Whether the robot that finishes the task (if present) can pick from `spot` on its table."""
        fin = self.finisher()
        if fin is None or fin.kind.reach is None:
            return True
        ab = fin.arm_base()
        assert ab is not None
        return 0.3 <= math.hypot(spot[0] - ab[0], spot[1] - ab[1]) <= fin.kind.reach - 0.03

    def objects_on(self, furniture: str) -> list[str]:
        """What lies on (or, for a container, in) a piece of furniture; fixtures count as Bob's table."""
        where = {furniture, *self.fixtures} if furniture == self.layout.bob_table else {furniture}
        return sorted(o.name for o in self.objects.values() if o.on in where and o.held_by is None)

    def furniture_names(self) -> list[str]:
        return [f.name for f in self.layout.furniture] + list(self.fixtures)

    def place_names(self) -> list[str]:
        return list(self.fixtures) + [f.name for f in self.layout.furniture if f.place_pose is not None]

    def seen(self) -> list[Seen]:
        """Every object's end state as the goal check reads it."""
        return [
            Seen(o.name, o.kind, o.on if o.held_by is None else None, round(self.position(o)[2], 4))
            for o in self.objects.values()
        ]

    # ------------------------------------------------------------------ holding and letting go
    def grasp(self, r: RobotBody, obj: ObjectState) -> None:
        """`r` holds `obj` by suction from now on (what the robot knows of it is the caller's: SkillContext.grasp)."""
        r.attach(obj.name, obj.body)
        obj.held_by, obj.on, obj.inside, obj.local = r.name, None, False, None

    def release(
        self,
        r: RobotBody,
        obj: ObjectState,
        spot: tuple[float, float, float],
        yaw: float,
        location: str | None = None,
        error: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """Let go of `obj` over `spot` (x, y, surface z), turned to `yaw`, placing it on `location`.

        With the exact_motion aid it is set down upright on the spot. Otherwise it falls from
        where the tool holds it, shifted by the release `error` (x, y; kept over the furniture
        that bears `location`, so it never drops off the edge), and settles under gravity
        (`settle`): it may tip off a stack, catch a rim or slide off a panel."""
        r.release()
        obj.held_by = None
        if "exact_motion" in self.aids:
            self.rest(obj, spot[0], spot[1], spot[2], yaw)
            return
        x, y, z = self.position(obj)
        x, y = x + error[0], y + error[1]
        bearer = self.layout.get(self.layout.bob_table if location in self.fixtures else location or "")
        if bearer is not None:
            hx, hy = half_extent(obj.kind, yaw, gap=0.0)
            (cx, cy), (sx, sy) = bearer.center, bearer.size[:2]
            x = min(max(x, cx - sx / 2 + hx), cx + sx / 2 - hx)
            y = min(max(y, cy - sy / 2 + hy), cy + sy / 2 - hy)
        orn = p.getQuaternionFromEuler((0, 0, yaw))
        p.resetBasePositionAndOrientation(
            obj.body, (x, y, max(z, spot[2] + obj.kind.height / 2)), orn, physicsClientId=self.cid
        )
        self.settle(obj)

    def settle(self, obj: ObjectState) -> int:
        """Let a just released object come to rest under gravity (PyBullet physics, at most
        SETTLE_STEPS steps); the simulation steps it alone. Every other object is static while it
        does (mass 0), only it feels gravity (so no arm sags and no lid falls), and whatever it
        nudged (arms, containers, a wheeled base) is set back afterwards. Returns the steps taken."""
        cid = self.cid
        others = [o for o in self.objects.values() if o is not obj]
        masses = [p.getDynamicsInfo(o.body, -1, physicsClientId=cid)[0] for o in others]
        for o in others:
            p.changeDynamics(o.body, -1, mass=0.0, physicsClientId=cid)
        mass = p.getDynamicsInfo(obj.body, -1, physicsClientId=cid)[0]
        # what tips over slides and rolls a little, not across the table (Bullet multiplies the two
        # bodies' friction coefficients: 1.0 against the furniture's default 0.5 makes 0.5)
        p.changeDynamics(
            obj.body,
            -1,
            lateralFriction=1.0,
            rollingFriction=ROLLING_FRICTION,
            spinningFriction=ROLLING_FRICTION,
            physicsClientId=cid,
        )
        p.resetBaseVelocity(obj.body, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
        still, steps = 0, 0
        while steps < SETTLE_STEPS and still < SETTLE_STILL:
            pos, _ = p.getBasePositionAndOrientation(obj.body, physicsClientId=cid)
            p.applyExternalForce(obj.body, -1, (0.0, 0.0, -GRAVITY * mass), pos, p.WORLD_FRAME, physicsClientId=cid)
            p.stepSimulation(physicsClientId=cid)
            steps += 1
            v, w = p.getBaseVelocity(obj.body, physicsClientId=cid)
            still = still + 1 if steps > 10 and math.hypot(*v) < 2e-3 and math.hypot(*w) < 2e-2 else 0
        p.resetBaseVelocity(obj.body, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
        for o, m in zip(others, masses):
            p.changeDynamics(o.body, -1, mass=m, physicsClientId=cid)
            p.resetBaseVelocity(o.body, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
        for bot in self.bots.values():
            if bot.kind.has_arm:
                bot.set_arm(bot.q)
            elif bot.base is not None:
                bot.set_base(bot.base)
                p.resetBaseVelocity(bot.body, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
        for name, value in self.opening.items():
            p.resetJointState(self.scene.bodies[name], self.scene.joints[name], value, physicsClientId=cid)
        return steps

    def _leans_on_stack(self, obj: ObjectState, fixture: str, bottom: float, centre: float) -> bool:
        """Whether `obj` rests on a stacking fixture's stack though its lowest point is below the
        stack's top: tilted across a narrow piece (a bacon strip) onto the layer under it, or lying
        on such a tilted piece. It counts as it lies when it touches a piece of the stack that lies
        lower than itself (it is borne by the stack, not standing beside it on the board) and its
        centre is above every piece's (it reads as the stack's new top, not a piece beside the top)."""
        if not self.fixtures[fixture].stack or "exact_motion" in self.aids:
            return False
        cid = self.cid
        pieces = [o for o in self.objects.values() if o.on == fixture and o.held_by is None and o is not obj]
        if any(self.position(o)[2] >= centre - 0.001 for o in pieces):
            return False
        return any(
            p.getAABB(o.body, physicsClientId=cid)[0][2] < bottom - 0.002
            and p.getClosestPoints(obj.body, o.body, STACK_TOUCH, physicsClientId=cid)
            for o in pieces
        )

    def settled_at(self, obj: ObjectState, location: str) -> bool:
        """Read where the released object really lies and record it; True if that is `location`.

        On a fixture: its centre over the fixture and its lowest point on the fixture's surface
        (on the top of the stack, for a stacking fixture, or leaning on it: `_leans_on_stack`),
        tilted or not. Otherwise on the furniture
        its centre is over, if it rests on that furniture or on something lying there (Bob's
        table, for anything that missed a fixture on it); on nothing (the floor) else."""
        x, y, z = self.position(obj)
        lay = self.layout
        (_, _, bottom), _ = p.getAABB(obj.body, physicsClientId=self.cid)
        obj.on, obj.inside = None, False
        fx = self.fixture_at(x, y)
        if fx is not None and (
            abs(bottom - self.surface_top(fx.name, without=obj)) < 0.008
            or self._leans_on_stack(obj, fx.name, bottom, z)
        ):
            obj.on = fx.name
        else:
            for f in lay.furniture:
                if f.place_pose is not None and f.contains_xy(x, y) and bottom > f.top - 0.01:
                    obj.on = f.name
                    break
        return obj.on == location
