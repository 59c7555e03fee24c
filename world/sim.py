"""The PyBullet world of one episode: scene, robots, objects, skills and partial views.

Robots move kinematically (bases set along A* paths, arms set along OMPL plans); a held
object follows the suction cup. Every skill returns a `SkillOutcome` whose feedback sentence
comes from what the planners and checks measured, never from a guess.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
import pybullet as p
import pybullet_data
import structlog

from mhrc.protocol import (
    SKILLS,
    Action,
    FurnitureView,
    Move,
    Navigate,
    ObjectView,
    Observation,
    Open,
    OutcomeCode,
    Pick,
    Place,
    Pose2D,
    RobotStatus,
    SkillOutcome,
    Wait,
)

from .arm import HOME, ArmPlanner
from .astar import Grid, astar, path_length
from .scene import FurnitureSpec, Layout, get_layout
from .tasks import ObjectKind, TaskResult, get_task

log = structlog.get_logger("mhrc.world.sim")

ROBOTS = ("alice", "bob", "david")
CAPABILITIES: dict[str, tuple[str, ...]] = {
    "alice": SKILLS,
    "bob": ("pick", "place", "communicate", "wait"),
    "david": ("navigate", "communicate", "wait"),
}
KINDS = {"alice": "mobile manipulator", "bob": "tabletop manipulator", "david": "mobile robot"}
BASE_INFLATION = 0.28  # half the chassis footprint, for the occupancy grid
ARM_FORWARD, ARM_HEIGHT = 0.2, 0.65  # Alice's arm base on her chassis
IDEAL_REACH = 0.6  # arm-base-to-object distance a corrective move aims for
REACH = {"alice": 0.75, "bob": 0.62}
NAV_SPEED, JOINT_SPEED = 0.5, 1.0  # m/s, rad/s for simulated time
MAX_MOVE = 1.0


def check_episode(*, task: str, scene: str, n_objects: int) -> None:
    """Raise ValueError naming the problem, without building anything."""
    get_task(task)
    get_layout(scene)
    if not 3 <= n_objects <= 6:
        raise ValueError(f"n_objects must be between 3 and 6, not {n_objects}")


@dataclass
class _Object:
    name: str
    kind: ObjectKind
    body: int
    on: str | None
    inside: bool
    target: bool
    drawer_offset: tuple[float, float] | None = None  # relative to the drawer's current centre
    held_by: str | None = None


@dataclass
class _Robot:
    name: str
    base: tuple[float, float, float] | None  # x, y, yaw (None for Bob)
    body: int = -1
    arm: int = -1
    q: np.ndarray = field(default_factory=lambda: HOME.copy())
    holding: str | None = None

    def arm_base(self, layout: Layout) -> tuple[float, float, float] | None:
        if self.name == "bob":
            return layout.bob_base
        if self.name == "alice" and self.base is not None:
            x, y, yaw = self.base
            return (x + ARM_FORWARD * math.cos(yaw), y + ARM_FORWARD * math.sin(yaw), ARM_HEIGHT)
        return None

    def arm_yaw(self, layout: Layout) -> float:
        return layout.bob_yaw if self.name == "bob" else (self.base[2] if self.base else 0.0)


class Sim:
    """The PyBullet world of one episode (p.DIRECT unless gui=True)."""

    def __init__(
        self,
        *,
        task: str = "pack_objects",
        scene: str = "house",
        seed: int = 0,
        n_objects: int = 4,
        gui: bool = False,
        robots: tuple[str, ...] = ROBOTS,
    ) -> None:
        check_episode(task=task, scene=scene, n_objects=n_objects)
        if not {"alice", "bob"} <= set(robots) or not set(robots) <= set(ROBOTS):
            raise ValueError(f"robots must include alice and bob and come from {', '.join(ROBOTS)}, not {robots}")
        self.robots = tuple(r for r in ROBOTS if r in robots)
        self.task_id, self.scene_id, self.seed, self.n_objects = task, scene, seed, n_objects
        self.task = get_task(task)
        self.layout = get_layout(scene)
        self.cid = p.connect(p.GUI if gui else p.DIRECT)
        self.planner = ArmPlanner(seed)
        self.drawer_open: dict[str, float] = {}
        self.drawer_bodies: dict[str, int] = {}
        self.objects: dict[str, _Object] = {}
        self.known: dict[str, set[str]] = {r: set() for r in self.robots}
        self.robots_state: dict[str, _Robot] = {}
        self._build()

    # ------------------------------------------------------------------ building
    def _box(self, center: tuple[float, float, float], half: tuple[float, float, float], color: tuple[float, ...], mass: float = 0.0) -> int:
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=color, physicsClientId=self.cid)
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.cid)
        return p.createMultiBody(mass, col, vis, center, physicsClientId=self.cid)

    def _build(self) -> None:
        lay = self.layout
        p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=self.cid)
        p.loadURDF("plane.urdf", physicsClientId=self.cid)
        xmin, xmax, ymin, ymax = lay.bounds
        self.grid = Grid.empty(xmin, xmax, ymin, ymax, 0.05)
        for cx, cy, sx, sy in lay.walls:
            self._box((cx, cy, 0.5), (sx / 2, sy / 2, 0.5), (0.9, 0.9, 0.88, 1))
            self.grid.add_box(cx, cy, sx, sy, margin=BASE_INFLATION)
        for f in lay.furniture:
            sx, sy, h = f.size
            self._box((f.center[0], f.center[1], h / 2), (sx / 2, sy / 2, h / 2), f.color)
            self.grid.add_box(f.center[0], f.center[1], sx, sy, margin=BASE_INFLATION)
            self.planner.set_box(f.name, (f.center[0], f.center[1], h / 2), (sx / 2, sy / 2, h / 2))
            if f.drawer is not None:
                d = f.drawer
                self.drawer_open[f.name] = 0.0
                self.drawer_bodies[f.name] = self._box(self._drawer_center(f), (d.size[0] / 2, d.size[1] / 2, 0.01), (0.7, 0.6, 0.5, 1))
                # the open drawer's footprint is never free floor
                dx, dy = d.axis
                ox = f.center[0] + dx * (f.size[1] / 2 + d.travel / 2)
                oy = f.center[1] + dy * (f.size[1] / 2 + d.travel / 2)
                self.grid.add_box(ox, oy, d.size[0] if dy else d.travel, d.travel if dy else d.size[1], margin=BASE_INFLATION)
        tx, ty, ts = lay.tray
        top = lay.get("table_0").top  # type: ignore[union-attr]
        self._box((tx, ty, top + 0.005), (ts / 2, ts / 2, 0.005), (0.2, 0.3, 0.6, 1))
        for sx, sy, w, l in ((0, 1, ts, 0.01), (0, -1, ts, 0.01), (1, 0, 0.01, ts), (-1, 0, 0.01, ts)):
            self._box((tx + sx * ts / 2, ty + sy * ts / 2, top + 0.02), (w / 2, l / 2, 0.02), (0.2, 0.3, 0.6, 1))
        # robots
        panda = "franka_panda/panda.urdf"
        bob = _Robot("bob", None)
        bob.arm = p.loadURDF(panda, lay.bob_base, p.getQuaternionFromEuler((0, 0, lay.bob_yaw)), useFixedBase=True, physicsClientId=self.cid)
        alice = _Robot("alice", lay.starts["alice"])
        alice.body = self._box((0, 0, ARM_HEIGHT / 2), (0.3, 0.25, ARM_HEIGHT / 2), (0.6, 0.2, 0.6, 1))
        alice.arm = p.loadURDF(panda, (0, 0, ARM_HEIGHT), useFixedBase=True, physicsClientId=self.cid)
        self.robots_state = {"alice": alice, "bob": bob}
        if "david" in self.robots:
            david = _Robot("david", lay.starts["david"])
            david.body = p.loadURDF("r2d2.urdf", (0, 0, 0.47), globalScaling=0.8, physicsClientId=self.cid)
            self.robots_state["david"] = david
            self._set_base(david, david.base)  # type: ignore[arg-type]
        for r in (alice, bob):
            self._set_arm(r, r.q)
        self._set_base(alice, alice.base)  # type: ignore[arg-type]
        # objects
        self.targets: list[str] = []
        for pl in self.task.generate(lay, self.seed, self.n_objects):
            home = lay.get(pl.furniture)
            assert home is not None
            body = self._object_body(pl.kind)
            obj = _Object(pl.kind.name, pl.kind, body, home.name, pl.inside, pl.target)
            if pl.inside:
                obj.drawer_offset = pl.xy
            self.objects[obj.name] = obj
            if pl.target:
                self.targets.append(obj.name)
            if pl.inside:
                self._sync_drawer(home)
            else:
                self._rest(obj, pl.xy[0], pl.xy[1], home.top)
        self.known["bob"] = set()

    def _object_body(self, k: ObjectKind) -> int:
        if k.shape == "box":
            half = (k.size[0] / 2, k.size[1] / 2, k.size[2] / 2)
            vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=k.color, physicsClientId=self.cid)
            col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.cid)
        elif k.shape == "cylinder":
            vis = p.createVisualShape(p.GEOM_CYLINDER, radius=k.size[0], length=k.size[2], rgbaColor=k.color, physicsClientId=self.cid)
            col = p.createCollisionShape(p.GEOM_CYLINDER, radius=k.size[0], height=k.size[2], physicsClientId=self.cid)
        else:
            vis = p.createVisualShape(p.GEOM_SPHERE, radius=k.size[0], rgbaColor=k.color, physicsClientId=self.cid)
            col = p.createCollisionShape(p.GEOM_SPHERE, radius=k.size[0], physicsClientId=self.cid)
        return p.createMultiBody(0.1, col, vis, (0, 0, -5), physicsClientId=self.cid)

    def close(self) -> None:
        if self.cid >= 0:
            p.disconnect(self.cid)
            self.cid = -1
        self.planner.close()

    def __enter__(self) -> Sim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ kinematic state
    def _pos(self, obj: _Object) -> tuple[float, float, float]:
        pos, _ = p.getBasePositionAndOrientation(obj.body, physicsClientId=self.cid)
        return (float(pos[0]), float(pos[1]), float(pos[2]))

    def _rest(self, obj: _Object, x: float, y: float, surface_z: float) -> None:
        p.resetBasePositionAndOrientation(obj.body, (x, y, surface_z + obj.kind.height / 2), (0, 0, 0, 1), physicsClientId=self.cid)

    def _drawer_center(self, f: FurnitureSpec) -> tuple[float, float, float]:
        d = f.drawer
        assert d is not None
        t = self.drawer_open.get(f.name, 0.0)
        return (f.center[0] + d.axis[0] * t, f.center[1] + d.axis[1] * t, d.bottom)

    def _sync_drawer(self, f: FurnitureSpec) -> None:
        cx, cy, z = self._drawer_center(f)
        p.resetBasePositionAndOrientation(self.drawer_bodies[f.name], (cx, cy, z - 0.01), (0, 0, 0, 1), physicsClientId=self.cid)
        for o in self.objects.values():
            if o.on == f.name and o.inside and o.drawer_offset is not None and o.held_by is None:
                self._rest(o, cx + o.drawer_offset[0], cy + o.drawer_offset[1], z)

    def _set_base(self, r: _Robot, base: tuple[float, float, float]) -> None:
        r.base = base
        x, y, yaw = base
        orn = p.getQuaternionFromEuler((0, 0, yaw))
        if r.name == "alice":
            p.resetBasePositionAndOrientation(r.body, (x, y, ARM_HEIGHT / 2), orn, physicsClientId=self.cid)
            ab = r.arm_base(self.layout)
            assert ab is not None
            p.resetBasePositionAndOrientation(r.arm, ab, orn, physicsClientId=self.cid)
            self._carry(r)
        else:
            p.resetBasePositionAndOrientation(r.body, (x, y, 0.38), p.getQuaternionFromEuler((0, 0, yaw + math.pi / 2)), physicsClientId=self.cid)

    def _set_arm(self, r: _Robot, q: np.ndarray) -> None:
        r.q = np.array(q)
        for j in range(7):
            p.resetJointState(r.arm, j, float(q[j]), physicsClientId=self.cid)
        for j in (9, 10):
            p.resetJointState(r.arm, j, 0.0, physicsClientId=self.cid)
        self._carry(r)

    def _carry(self, r: _Robot) -> None:
        """A held object hangs under the suction cup."""
        if r.holding is None:
            return
        obj = self.objects[r.holding]
        tip = p.getLinkState(r.arm, 11, computeForwardKinematics=True, physicsClientId=self.cid)[4]
        p.resetBasePositionAndOrientation(obj.body, (tip[0], tip[1], tip[2] - obj.kind.height / 2), (0, 0, 0, 1), physicsClientId=self.cid)

    def _planner_for(self, r: _Robot) -> ArmPlanner:
        ab = r.arm_base(self.layout)
        assert ab is not None
        self.planner.set_base(ab, r.arm_yaw(self.layout))
        return self.planner

    def _retract(self, r: _Robot) -> float:
        """Back to the carry posture, planned; straight in joint space if no plan is found."""
        res = self._planner_for(r).plan(r.q, HOME)
        path = res.path if res.path is not None else [r.q + (HOME - r.q) * t for t in np.linspace(0, 1, 10)]
        return self._run_path(r, path)

    def _run_path(self, r: _Robot, path: list[np.ndarray]) -> float:
        for q in path:
            self._set_arm(r, q)
        return sum(float(np.max(np.abs(b - a))) for a, b in zip(path, path[1:])) / JOINT_SPEED

    # ------------------------------------------------------------------ public API
    def capabilities(self, robot: str) -> frozenset[str]:
        return frozenset(CAPABILITIES[robot]) if robot in self.robots else frozenset()

    def execute(self, robot: str, action: Action) -> SkillOutcome:
        if robot not in self.robots_state:
            return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, f"There is no robot {robot!r} in this world.")
        if action.skill == "communicate":
            raise ValueError("communicate is handled by the world service, not the simulator")
        if action.skill not in self.capabilities(robot):
            skills = ", ".join(CAPABILITIES[robot])
            return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, f"{robot.capitalize()} cannot {action.skill}: its skills are {skills}.")
        r = self.robots_state[robot]
        if isinstance(action, Wait):
            return SkillOutcome.ok("You waited.", sim_time=1.0)
        if isinstance(action, Navigate):
            return self._navigate(r, action)
        if isinstance(action, Move):
            return self._move(r, action)
        if isinstance(action, Open):
            return self._open(r, action)
        if isinstance(action, Pick):
            return self._pick(r, action)
        if isinstance(action, Place):
            return self._place(r, action)
        return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, f"Unknown skill {action.skill}.")

    # ------------------------------------------------------------------ skills: bases
    def _furniture_names(self) -> str:
        return ", ".join(f.name for f in self.layout.furniture)

    def _navigate(self, r: _Robot, a: Navigate) -> SkillOutcome:
        f = self.layout.get(a.target)
        if f is None:
            if a.target == "tray" or a.target in self.objects:
                return SkillOutcome.fail(OutcomeCode.NOT_NAVIGABLE, f"{a.target} is not furniture you can navigate to; navigate to the furniture it is on.")
            return SkillOutcome.fail(OutcomeCode.TARGET_UNKNOWN, f"There is no {a.target!r} in your scene graph; furniture: {self._furniture_names()}.")
        if not f.stand_poses:
            return SkillOutcome.fail(OutcomeCode.NOT_NAVIGABLE, f"{f.name} has no stand pose to navigate to.")
        if a.stand_pose >= len(f.stand_poses):
            return SkillOutcome.fail(
                OutcomeCode.STAND_POSE_INVALID,
                f"{f.name} has {len(f.stand_poses)} stand pose(s), numbered 0 to {len(f.stand_poses) - 1}; there is no stand pose {a.stand_pose}.",
            )
        assert r.base is not None
        goal = f.stand_poses[a.stand_pose]
        if not self.grid.free(r.base[0], r.base[1]):
            return SkillOutcome.fail(OutcomeCode.START_INVALID, "Navigation failed: your start pose is on an obstacle or off the map.")
        if not self.grid.free(goal[0], goal[1]):
            return SkillOutcome.fail(OutcomeCode.GOAL_INVALID, f"Navigation failed: stand pose {a.stand_pose} of {f.name} is on an obstacle.")
        path = astar(self.grid, (r.base[0], r.base[1]), (goal[0], goal[1]))
        if path is None:
            return SkillOutcome.fail(OutcomeCode.NO_PATH, f"Navigation failed: no collision-free path to {f.name}.")
        length = path_length(path)
        self._set_base(r, goal)
        text = f"You reached stand pose {a.stand_pose} of {f.name}."
        if f.drawer is not None and self.drawer_open[f.name] == 0.0:
            text += f" {f.name} is closed: open it to see what is inside."
        else:
            seen = sorted(o.name for o in self.objects.values() if o.on in (f.name, "tray" if f.name == "table_0" else "") and o.held_by is None)
            self.known[r.name].update(seen)
            text += f" On {f.name}: {', '.join(seen)}." if seen else f" There is nothing on {f.name}."
        return SkillOutcome.ok(text, sim_time=length / NAV_SPEED, path_length=round(length, 3))

    def _move(self, r: _Robot, a: Move) -> SkillOutcome:
        assert r.base is not None
        d = math.hypot(a.dx, a.dy)
        if d > MAX_MOVE:
            return SkillOutcome.fail(OutcomeCode.GOAL_INVALID, f"Move failed: {d:.2f} m is more than the {MAX_MOVE:.1f} m a move may cover.")
        x, y, yaw = r.base
        nx, ny = x + a.dx, y + a.dy
        steps = max(2, int(d / 0.02) + 1)
        if not all(self.grid.free(x + a.dx * t, y + a.dy * t) for t in np.linspace(0, 1, steps)[1:]):
            return SkillOutcome.fail(OutcomeCode.GOAL_INVALID, f"Move failed: moving by ({a.dx:.2f}, {a.dy:.2f}) would hit an obstacle.")
        self._set_base(r, (nx, ny, yaw))
        return SkillOutcome.ok(f"You moved by dx={a.dx:.2f} m, dy={a.dy:.2f} m.", sim_time=d / NAV_SPEED)

    # ------------------------------------------------------------------ skills: arms
    def _too_far(self, r: _Robot, target: tuple[float, float, float], what: str, planner: ArmPlanner) -> SkillOutcome:
        ab = r.arm_base(self.layout)
        assert ab is not None
        err = planner.reach_error(target, r.arm_yaw(self.layout), r.q)
        dist = math.hypot(target[0] - ab[0], target[1] - ab[1])
        if err < 0.01:  # reachable in principle, but every solution collides
            return SkillOutcome.fail(
                OutcomeCode.CONFIG_INVALID,
                f"The arm planner found the goal configuration for {what} invalid: every arm pose that reaches it collides.",
                distance=round(err, 3), horizontal_distance=round(dist, 3),
            )
        details: dict[str, float | str] = {"distance": round(err, 3), "horizontal_distance": round(dist, 3)}
        text = f"The end effector could not reach {what}: it stayed {err:.2f} m away (the arm base is {dist:.2f} m from it)."
        fix = self._corrective_move(r, target) if r.name == "alice" else None
        if fix is not None:
            dx, dy = fix
            details.update(dx=round(dx, 3), dy=round(dy, 3))
            text += f" Moving your base by dx={dx:.2f}, dy={dy:.2f} would bring it within good grasping distance."
        return SkillOutcome(succeeded=False, code=OutcomeCode.TOO_FAR, feedback=text, details=details)

    def _corrective_move(self, r: _Robot, target: tuple[float, float, float]) -> tuple[float, float] | None:
        """The shortest collision-free base shift (<= MAX_MOVE) putting `target` at a good grasp distance."""
        assert r.base is not None
        x, y, yaw = r.base
        fx, fy = ARM_FORWARD * math.cos(yaw), ARM_FORWARD * math.sin(yaw)
        steps = np.round(np.arange(-MAX_MOVE, MAX_MOVE + 1e-9, 0.05), 3)
        cands = sorted(
            ((float(dx), float(dy)) for dx in steps for dy in steps if math.hypot(dx, dy) <= MAX_MOVE),
            key=lambda d: math.hypot(*d),
        )
        for dx, dy in cands:
            if math.hypot(target[0] - (x + dx + fx), target[1] - (y + dy + fy)) > IDEAL_REACH:
                continue
            n = max(2, int(math.hypot(dx, dy) / 0.02) + 1)
            if all(self.grid.free(x + dx * t, y + dy * t) for t in np.linspace(0, 1, n)[1:]):
                return dx, dy
        return None

    def _reach_and_plan(self, r: _Robot, target: tuple[float, float, float], what: str) -> tuple[list[np.ndarray] | None, SkillOutcome | None]:
        """A plan to a pose above `target`, then straight down onto it."""
        planner = self._planner_for(r)
        yaw = r.arm_yaw(self.layout)
        above = (target[0], target[1], target[2] + 0.12)
        q_above = planner.ik(above, yaw, r.q)
        q_at = planner.ik(target, yaw, q_above if q_above is not None else r.q)
        if q_above is None or q_at is None:
            return None, self._too_far(r, target, what, planner)
        res = planner.plan(r.q, q_above)
        if res.path is None:
            if res.reason in ("start_invalid", "goal_invalid"):
                which = "start" if res.reason == "start_invalid" else "goal"
                return None, SkillOutcome.fail(OutcomeCode.CONFIG_INVALID, f"The arm planner found the {which} configuration invalid (in collision) for {what}.")
            return None, SkillOutcome.fail(OutcomeCode.PLAN_FAILED, f"The arm planner found no collision-free motion to {what}.")
        descent = [q_above + (q_at - q_above) * t for t in np.linspace(0, 1, 8)]
        return res.path + descent, None

    def _lookup(self, r: _Robot, name: str) -> _Object | None:
        obj = self.objects.get(name)
        if obj is None or name not in self._known(r.name):
            return None
        return obj

    def _pick(self, r: _Robot, a: Pick) -> SkillOutcome:
        if r.holding is not None:
            return SkillOutcome.fail(OutcomeCode.GRIPPER_FULL, f"Your gripper already holds {r.holding}; place it first.")
        obj = self._lookup(r, a.obj)
        if obj is None:
            known = ", ".join(sorted(self._known(r.name))) or "none"
            return SkillOutcome.fail(OutcomeCode.OBJECT_UNKNOWN, f"There is no {a.obj!r} in your scene graph; objects you know: {known}.")
        if obj.held_by is not None:
            return SkillOutcome.fail(OutcomeCode.OBJECT_UNKNOWN, f"{obj.name} is held by {obj.held_by}.")
        if obj.inside and obj.on is not None and self.drawer_open.get(obj.on, 1.0) == 0.0:
            return SkillOutcome.fail(OutcomeCode.NOT_REACHABLE_CONTAINER, f"{obj.name} is inside {obj.on}, which is closed: open it first.")
        x, y, z = self._pos(obj)
        top = (x, y, z + obj.kind.height / 2 + 0.003)
        path, failure = self._reach_and_plan(r, top, obj.name)
        if failure is not None:
            return failure
        assert path is not None
        t = self._run_path(r, path)
        r.holding, obj.held_by = obj.name, r.name
        obj.on, obj.inside, obj.drawer_offset = None, False, None
        self._carry(r)
        t += self._run_path(r, list(reversed(path[-8:])))
        t += self._retract(r)
        return SkillOutcome.ok(f"You picked up {obj.name}.", sim_time=t + 1.0)

    def _free_spots(self, location: str, held: _Object) -> tuple[list[tuple[float, float]], float] | None:
        """Candidate spots for `held` at `location`, nearest its place pose first, and the surface height."""
        lay = self.layout
        if location == "tray":
            tx, ty, ts = lay.tray
            top = lay.get("table_0").top + 0.01  # type: ignore[union-attr]
            k = ts / 2 - 0.07
            cands = [(tx + dx, ty + dy) for dx in (0.0, -k, k) for dy in (0.0, -k, k)]
        else:
            f = lay.get(location)
            if f is None or f.place_pose is None:
                return None
            top = f.top
            px, py = f.place_pose
            cands = [(px + dx, py + dy) for dx in (0.0, -0.13, 0.13) for dy in (0.0, -0.12, 0.12)]
            cands.sort(key=lambda c: math.hypot(c[0] - px, c[1] - py))
            cands = [c for c in cands if f.contains_xy(c[0], c[1], -0.05) and not self._in_tray(c[0], c[1], 0.08)]
        others = [self._pos(o) for o in self.objects.values() if o is not held and o.held_by is None]
        free = [c for c in cands if all(math.hypot(c[0] - o[0], c[1] - o[1]) > 0.1 or abs(o[2] - top) > 0.3 for o in others)]
        return free, top

    def _in_tray(self, x: float, y: float, margin: float = 0.0) -> bool:
        tx, ty, ts = self.layout.tray
        return abs(x - tx) <= ts / 2 + margin and abs(y - ty) <= ts / 2 + margin

    def _place(self, r: _Robot, a: Place) -> SkillOutcome:
        if r.holding is None:
            return SkillOutcome.fail(OutcomeCode.GRIPPER_EMPTY, f"Your gripper is empty: there is no {a.obj} to place.")
        if a.obj != r.holding:
            return SkillOutcome.fail(OutcomeCode.WRONG_OBJECT, f"You hold {r.holding}, not {a.obj}.")
        held = self.objects[r.holding]
        f = self.layout.get(a.location)
        if f is not None and f.drawer is not None:
            return SkillOutcome.fail(OutcomeCode.LOCATION_UNKNOWN, f"Objects cannot be placed into {f.name}; place them on a table, a counter, the sofa or in the tray.")
        spots = self._free_spots(a.location, held)
        if spots is None:
            names = ", ".join(["tray"] + [f.name for f in self.layout.furniture if f.place_pose is not None])
            return SkillOutcome.fail(OutcomeCode.LOCATION_UNKNOWN, f"There is no place called {a.location!r}; places: {names}.")
        cands, top = spots
        if not cands:
            return SkillOutcome.fail(OutcomeCode.PLACE_FAILED, f"There is no free spot left on {a.location}.")
        failure: SkillOutcome | None = None
        for x, y in cands:
            target = (x, y, top + held.kind.height + 0.01)
            path, failure = self._reach_and_plan(r, target, f"the spot on {a.location}")
            if path is None:
                continue
            t = self._run_path(r, path)
            r.holding, held.held_by = None, None
            self._rest(held, x, y, top)
            t += self._run_path(r, list(reversed(path[-8:])))
            t += self._retract(r)
            px, py, _ = self._pos(held)
            if a.location == "tray":
                ok = self._in_tray(px, py)
            else:
                ok = f is not None and f.contains_xy(px, py) and not self._in_tray(px, py)
            if not ok:
                held.on = None
                return SkillOutcome.fail(OutcomeCode.PLACE_FAILED, f"{held.name} did not end up on {a.location}.")
            held.on = a.location
            return SkillOutcome.ok(f"You placed {held.name} on {a.location}." if a.location != "tray" else f"You placed {held.name} in the tray.", sim_time=t + 1.0)
        assert failure is not None
        return failure

    def _open(self, r: _Robot, a: Open) -> SkillOutcome:
        f = self.layout.get(a.target)
        if f is None:
            return SkillOutcome.fail(OutcomeCode.TARGET_UNKNOWN, f"There is no {a.target!r} in your scene graph; furniture: {self._furniture_names()}.")
        if f.drawer is None:
            return SkillOutcome.fail(OutcomeCode.NOT_OPENABLE, f"{f.name} cannot be opened.")
        if self.drawer_open[f.name] > 0.0:
            return SkillOutcome.fail(OutcomeCode.ALREADY_OPEN, f"{f.name} is already open.")
        if r.holding is not None:
            return SkillOutcome.fail(OutcomeCode.GRIPPER_FULL, f"Your gripper holds {r.holding}; place it before opening {f.name}.")
        d = f.drawer
        front = f.size[1] / 2
        handle = (f.center[0] + d.axis[0] * (front + 0.03), f.center[1] + d.axis[1] * (front + 0.03), d.bottom + d.size[2])
        path, failure = self._reach_and_plan(r, handle, f"the handle of {f.name}")
        if failure is not None:
            if failure.code == OutcomeCode.TOO_FAR:
                text = f"The handle of {f.name} is out of your reach: " + failure.feedback
                return failure.model_copy(update={"code": OutcomeCode.OUT_OF_REACH, "feedback": text})
            return failure
        assert path is not None
        t = self._run_path(r, path)
        planner = self._planner_for(r)
        yaw = r.arm_yaw(self.layout)
        for s in np.linspace(0, d.travel, 10)[1:]:  # pull the handle along the drawer's axis
            self.drawer_open[f.name] = float(s)
            self._sync_drawer(f)
            q = planner.ik((handle[0] + d.axis[0] * s, handle[1] + d.axis[1] * s, handle[2]), yaw, r.q, restarts=2)
            if q is not None:
                t += float(np.max(np.abs(q - r.q))) / JOINT_SPEED
                self._set_arm(r, q)
        cx, cy, cz = self._drawer_center(f)
        self.planner.set_box(f.name + ":drawer", (cx, cy, cz - 0.011), (d.size[0] / 2, d.size[1] / 2, 0.01))
        t += self._retract(r)
        inside = sorted(o.name for o in self.objects.values() if o.on == f.name and o.inside)
        self.known[r.name].update(inside)
        text = f"You opened {f.name}. Inside: {', '.join(inside)}." if inside else f"You opened {f.name}; it is empty."
        return SkillOutcome.ok(text, sim_time=t + 1.0)

    # ------------------------------------------------------------------ views
    def _known(self, robot: str) -> set[str]:
        known = set(self.known[robot])
        if robot == "bob":  # Bob sees his own table
            known |= {o.name for o in self.objects.values() if o.on in ("table_0", "tray")}
        held = self.robots_state[robot].holding
        if held:
            known.add(held)
        return known

    def tell(self, receiver: str, sender: str, text: str) -> None:
        words = set(re.findall(r"[A-Za-z0-9_]+", text))
        self.known[receiver].update(n for n in self._known(sender) if n in words)

    def _object_view(self, o: _Object) -> ObjectView:
        x, y, z = self._pos(o)
        return ObjectView(name=o.name, position=(round(x, 3), round(y, 3), round(z, 3)), on=o.on, inside=o.inside, held_by=o.held_by)

    def _furniture_views(self) -> list[FurnitureView]:
        out = []
        for f in self.layout.furniture:
            out.append(
                FurnitureView(
                    name=f.name,
                    kind=f.kind,
                    position=(f.center[0], f.center[1], f.top),
                    openable=f.drawer is not None,
                    is_open=(self.drawer_open[f.name] > 0.0) if f.drawer is not None else None,
                    stand_poses=[Pose2D(x=x, y=y, yaw=round(yaw, 4)) for x, y, yaw in f.stand_poses],
                    place_pose=(f.place_pose[0], f.place_pose[1], f.top) if f.place_pose else None,
                )
            )
        tx, ty, _ = self.layout.tray
        top = self.layout.get("table_0").top  # type: ignore[union-attr]
        out.append(FurnitureView(name="tray", kind="tray on table_0", position=(tx, ty, top), place_pose=(tx, ty, top)))
        return out

    def observe(self, robot: str, tick: int) -> Observation:
        r = self.robots_state[robot]
        known = self._known(robot)
        status = RobotStatus(
            name=robot,
            kind=KINDS[robot],
            skills=list(CAPABILITIES[robot]),
            base=Pose2D(x=round(r.base[0], 3), y=round(r.base[1], 3), yaw=round(r.base[2], 4)) if r.base else None,
            arm_base=r.arm_base(self.layout),
            reach=REACH.get(robot),
            holding=r.holding,
        )
        is_bob = robot == "bob"
        helper = "Help Bob pack the listed objects into the tray on table_0: find them, fetch them and hand them over."
        return Observation(
            robot=robot,
            tick=tick,
            status=status,
            furniture=self._furniture_views(),
            objects=[self._object_view(o) for o in self.objects.values() if o.name in known],
            task_brief=self.task.brief,
            task_detail=self.task.detail(self.targets) if is_bob else helper,
            targets=list(self.targets) if is_bob else [],
            task_status=self.task.status(self.targets, list(self.objects.values())) if is_bob else None,  # type: ignore[arg-type]
            teammates={o: list(CAPABILITIES[o]) for o in self.robots if o != robot},
        )

    def evaluate(self) -> TaskResult:
        return self.task.evaluate(self.targets, list(self.objects.values()))  # type: ignore[arg-type]

    def task_status(self) -> str:
        return self.task.status(self.targets, list(self.objects.values()))  # type: ignore[arg-type]

    def views(self) -> tuple[list[FurnitureView], list[ObjectView]]:
        return self._furniture_views(), [self._object_view(o) for o in self.objects.values()]
