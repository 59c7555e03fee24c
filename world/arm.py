"""Arm kinematics and motion planning for the Franka Panda arms (Alice's and Bob's).

Everything here runs in a separate p.DIRECT "shadow" client holding one Panda and copies of
the scene's fixed bodies, so planning never moves the live robots. IK is plain PyBullet IK,
clipped to the joint limits, reseeded with random restarts and verified by forward kinematics;
motions are planned with OMPL BIT* in joint space, every state checked for contacts.
"""

from __future__ import annotations

import functools
import math
import re
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet_data
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from .scene import StaticBody
from .shadow import POOL, Shadow, ShadowPool, statics_key

ARM_JOINTS = tuple(range(7))
FINGERS = (9, 10)
EE_LINK = 11  # panda_grasptarget: the suction cup's tip
LOWER = np.array([-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671])  # panda.urdf's limits
UPPER = np.array([2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671])
_LOW, _HIGH = LOWER - 1e-6, UPPER + 1e-6  # what `valid` accepts
_LIMITS = tuple(zip(_LOW.tolist(), _HIGH.tolist(), strict=True))  # the same, for a check in plain Python
_STILL = [[0.0]] * len(ARM_JOINTS)  # joint velocities set with the positions
# Collision filter groups of the planning client: its arm and everything else. Only the arm's
# contacts are ever read (`valid`), so the obstacles are not tested against one another: a check's
# collision detection skips the furniture-furniture and furniture-other-arm pairs (about a third
# of its time), and the arm's own contacts are the same.
_ARM_GROUP, _OBSTACLE_GROUP = 2, 1
HOME = np.array([0.0, -1.2, 0.0, -2.9, 0.0, 1.9, 0.785])  # tucked carry posture: hand over the base
DOWN = (math.pi, 0.0)  # roll, pitch of a top-down tool (z axis pointing down)
OMPL_SEED = 20240917
# A plan's budget is counted in collision checks, not seconds, so that a loaded machine plans what
# a quiet one does: a wall-clock budget (1.5 s, before) made the same episode end differently when
# two cores were shared by more work (an eval with workers, a bench beside tests). The heuristic
# team's plans on the default grid take at most ~5,000 checks; 20,000 is about 1.5 s on a quiet
# core. The wall limit is only a guard against a machine so slow that it would plan for minutes.
PLAN_CHECKS = 20_000
PLAN_WALL_LIMIT = 30.0  # s

# OMPL's RNG is process-wide. Re-seeding it before each plan restarts its seed sequence, so a
# plan depends only on its inputs, not on how many plans ran before (same seed, same outcome).
# The lock keeps two simulators in two threads from interleaving their sampling.
_ompl_lock = threading.Lock()
_ompl_ready = False


def _reset_ompl_rng() -> None:
    global _ompl_ready
    if not _ompl_ready:
        ou.setLogLevel(ou.LogLevel.LOG_NONE)  # re-seeding logs an error we mean to ignore
        _ompl_ready = True
    ou.RNG.setSeed(OMPL_SEED)


@functools.cache
def _shadow_panda_urdf() -> str:
    """pybullet_data's panda.urdf without its visual elements, mesh paths made absolute: the same
    links, joints, inertias and collision meshes (the planning client is never drawn), loaded
    about 7 times faster (no visual meshes to read): 10 ms where the whole URDF takes 70-80."""
    d = Path(pybullet_data.getDataPath()) / "franka_panda"
    text = (d / "panda.urdf").read_text(encoding="utf-8")
    return re.sub(r"<visual>.*?</visual>", "", text, flags=re.S).replace("package://", f"{d}/")


@dataclass
class IKResult:
    q: np.ndarray | None
    error: float  # the best attempt's tool-tip distance from the target (m)
    collided: bool  # some attempt reached the target but collided


@dataclass
class PlanResult:
    path: list[np.ndarray] | None
    reason: str = ""  # "start_invalid", "goal_invalid" or "no_plan" when path is None
    checks: int = 0


class ArmPlanner:
    """IK and collision-free joint-space plans for a Panda whose base can be anywhere."""

    def __init__(
        self,
        statics: list[StaticBody],
        *,
        seed: int = 0,
        budget: int = PLAN_CHECKS,
        wall_limit: float = PLAN_WALL_LIMIT,
        pool: ShadowPool | None = POOL,
    ) -> None:
        """`pool`: where the shadow client comes from and goes back to when closed (world/shadow.py;
        None: a client of its own, disconnected when closed)."""
        self.rng = np.random.default_rng(seed)
        self.budget, self.wall_limit = budget, wall_limit
        key = statics_key(statics)
        shadow = pool.take(key) if pool is not None else None
        if shadow is None:
            shadow = Shadow.build(statics, key, _shadow_panda_urdf(), _setup)
        self._pool = pool
        self._shadow: Shadow | None = shadow
        self.cid = shadow.cid
        self.panda = shadow.panda  # every Panda of this client: the arm and the other arms
        self.arm = shadow.arm
        self.bodies = shadow.bodies
        self.boxes: dict[str, int] = {}
        self.other_arms: dict[str, int] = {}
        self.checks = 0

    def close(self) -> None:
        """Let go of the shadow client (idempotent): back to the pool, or disconnected. From then on
        every call of this planner fails (its `cid` is -1), as on a disconnected client."""
        shadow, self._shadow = self._shadow, None
        self.cid = -1
        if shadow is None:
            return
        if self._pool is None:
            shadow.close()
        else:
            self._pool.give(shadow, list(self.boxes.values()), list(self.other_arms.values()))

    # ------------------------------------------------------------------ world model
    def _filter(self, body: int, group: int, mask: int) -> None:
        _filter(self.cid, body, group, mask)

    def set_joint(self, body: str, joint: int, value: float) -> None:
        """Mirror a live joint (an opened drawer) into the planning world."""
        if self._shadow is not None:
            self._shadow.note_joint(self.bodies[body], joint)  # set back when the client goes back to the pool
        p.resetJointState(self.bodies[body], joint, value, physicsClientId=self.cid)

    def set_box(
        self, name: str, center: tuple[float, float, float], half: tuple[float, float, float], yaw: float = 0.0
    ) -> None:
        """Create or move the obstacle box `name` (a chassis, an object)."""
        orn = p.getQuaternionFromEuler((0, 0, yaw))
        if name not in self.boxes:
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.cid)
            self.boxes[name] = p.createMultiBody(0, shape, -1, center, orn, physicsClientId=self.cid)
            self._filter(self.boxes[name], _OBSTACLE_GROUP, _ARM_GROUP)
        else:
            p.resetBasePositionAndOrientation(self.boxes[name], center, orn, physicsClientId=self.cid)

    def hide_box(self, name: str) -> None:
        if name in self.boxes:
            p.resetBasePositionAndOrientation(self.boxes[name], (0, 0, -50), (0, 0, 0, 1), physicsClientId=self.cid)

    def set_other_arm(self, name: str, base: tuple[float, float, float], yaw: float, q: np.ndarray) -> None:
        """Mirror another robot's arm (pose and joints) as an obstacle."""
        if name not in self.other_arms:
            if self._shadow is not None and self._shadow.spares:  # a Panda an earlier episode left hidden
                self.other_arms[name] = self._shadow.spares.pop()
            else:
                self.other_arms[name] = p.loadURDF(self.panda, useFixedBase=True, physicsClientId=self.cid)
                self._filter(self.other_arms[name], _OBSTACLE_GROUP, _ARM_GROUP)
        body = self.other_arms[name]
        p.resetBasePositionAndOrientation(body, base, p.getQuaternionFromEuler((0, 0, yaw)), physicsClientId=self.cid)
        set_joints(self.cid, body, q)
        for f in FINGERS:
            p.resetJointState(body, f, 0.0, physicsClientId=self.cid)

    def hide_other_arm(self, name: str) -> None:
        if name in self.other_arms:
            p.resetBasePositionAndOrientation(
                self.other_arms[name], (0, 0, -50), (0, 0, 0, 1), physicsClientId=self.cid
            )

    def set_base(self, xyz: tuple[float, float, float], yaw: float) -> None:
        p.resetBasePositionAndOrientation(
            self.arm, xyz, p.getQuaternionFromEuler((0, 0, yaw)), physicsClientId=self.cid
        )

    # ------------------------------------------------------------------ kinematics
    def _set(self, q: np.ndarray) -> None:
        set_joints(self.cid, self.arm, q)

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool-tip position and orientation (quaternion) of configuration q."""
        self._set(q)
        st = p.getLinkState(self.arm, EE_LINK, computeForwardKinematics=True, physicsClientId=self.cid)
        return np.array(st[4]), np.array(st[5])

    def valid(self, q: np.ndarray | list[float]) -> bool:
        """Within limits and touching nothing but the mount under the arm's base link. `q`: an
        array, or the plain list OMPL's states give (BIT* calls this for every state it checks,
        so the limits are compared in plain Python, without building an array)."""
        self.checks += 1
        values = q.tolist() if isinstance(q, np.ndarray) else q
        for (low, high), x in zip(_LIMITS, values, strict=True):
            if not low <= x <= high:
                return False
        set_joints(self.cid, self.arm, values)
        p.performCollisionDetection(physicsClientId=self.cid)
        for c in p.getContactPoints(bodyA=self.arm, physicsClientId=self.cid):
            if c[2] != self.arm and c[3] >= 0 and c[8] < 0:  # c[3]: the arm's link; its base (-1) sits on the mount
                return False
        return True

    def solve(self, target: tuple[float, float, float], yaw: float, seed_q: np.ndarray, restarts: int = 8) -> IKResult:
        """A verified, collision-free joint solution putting the tool tip at `target`, pointing down.

        Each attempt starts from `seed_q` (then from random configurations) and refines the plain
        IK answer a few times; an answer counts only if FK confirms it within 2 mm and 0.05 rad.
        """
        orn = np.array(p.getQuaternionFromEuler((*DOWN, yaw)))
        tgt = np.array(target)
        best, collided = math.inf, False
        for k in range(restarts):
            q = np.array(seed_q if k == 0 else self.rng.uniform(LOWER, UPPER), dtype=float)
            self._set(q)  # later rounds start where fk(q) left the arm
            for _ in range(3):
                sol = p.calculateInverseKinematics(
                    self.arm,
                    EE_LINK,
                    target,
                    orn,
                    maxNumIterations=100,
                    residualThreshold=1e-6,
                    physicsClientId=self.cid,
                )
                q = np.clip(np.array(sol[:7]), LOWER, UPPER)
                pos, got = self.fk(q)
                err = float(np.linalg.norm(pos - tgt))
                if err < 5e-4:
                    break
            best = min(best, err)
            if err > 0.002 or 2 * math.acos(min(1.0, abs(float(np.dot(orn, got))))) > 0.05:
                continue
            if self.valid(q):
                return IKResult(q, err, False)
            collided = True
        return IKResult(None, best, collided)

    def ik(
        self, target: tuple[float, float, float], yaw: float, seed_q: np.ndarray, restarts: int = 8
    ) -> np.ndarray | None:
        return self.solve(target, yaw, seed_q, restarts).q

    def reach_error(self, target: tuple[float, float, float], yaw: float, seed_q: np.ndarray, tries: int = 4) -> float:
        """How far the best of a few IK attempts leaves the tool tip from `target` (metres)."""
        orn = p.getQuaternionFromEuler((*DOWN, yaw))
        best = math.inf
        for k in range(tries):
            self._set(seed_q if k == 0 else self.rng.uniform(LOWER, UPPER))
            sol = p.calculateInverseKinematics(
                self.arm, EE_LINK, target, orn, maxNumIterations=200, physicsClientId=self.cid
            )
            pos, _ = self.fk(np.clip(np.array(sol[:7]), LOWER, UPPER))
            best = min(best, float(np.linalg.norm(pos - np.array(target))))
        return best

    # ------------------------------------------------------------------ planning
    def plan(self, start: np.ndarray, goal: np.ndarray, points: int = 30) -> PlanResult:
        """BIT* from start to goal (first solution), interpolated to at least `points` states."""
        checks0 = self.checks
        if not self.valid(start):
            return PlanResult(None, "start_invalid", self.checks - checks0)
        if not self.valid(goal):
            return PlanResult(None, "goal_invalid", self.checks - checks0)
        with _ompl_lock:
            _reset_ompl_rng()
            path = self._bitstar(start, goal, points)
        return PlanResult(path, "" if path is not None else "no_plan", self.checks - checks0)

    def _bitstar(self, start: np.ndarray, goal: np.ndarray, points: int) -> list[np.ndarray] | None:
        space = ob.RealVectorStateSpace(7)
        bounds = ob.RealVectorBounds(7)
        for i in range(7):
            bounds.setLow(i, float(LOWER[i]))
            bounds.setHigh(i, float(UPPER[i]))
        space.setBounds(bounds)
        ss = og.SimpleSetup(space)
        ss.setStateValidityChecker(lambda s: self.valid(s[0:7]))
        si = ss.getSpaceInformation()
        si.setStateValidityCheckingResolution(0.005)
        st, gl = si.allocState(), si.allocState()
        for i in range(7):
            st[i], gl[i] = float(start[i]), float(goal[i])
        ss.setStartAndGoalStates(st, gl)
        planner = og.BITstar(si)
        planner.setStopOnSolnImprovement(True)
        ss.setPlanner(planner)
        start_checks = self.checks
        enough = ob.PlannerTerminationCondition(lambda: self.checks - start_checks >= self.budget)
        status = ss.solve(
            ob.plannerOrTerminationCondition(enough, ob.timedPlannerTerminationCondition(self.wall_limit))
        )
        out: list[np.ndarray] | None = None
        if status.getStatus() == ob.PlannerStatus.EXACT_SOLUTION:
            path = ss.getSolutionPath()
            path.interpolate(points)
            out = [np.array([path.getState(k)[i] for i in range(7)]) for k in range(path.getStateCount())]
        ss.clear()
        return out


def _filter(cid: int, body: int, group: int, mask: int) -> None:
    """Every link of `body` in collision group `group`, colliding only with `mask`."""
    for link in range(-1, p.getNumJoints(body, physicsClientId=cid)):
        p.setCollisionFilterGroupMask(body, link, group, mask, physicsClientId=cid)


def _setup(shadow: Shadow) -> None:
    """A new shadow client's collision filters (the arm against the obstacles only), fingers closed."""
    _filter(shadow.cid, shadow.arm, _ARM_GROUP, _OBSTACLE_GROUP)
    for f in FINGERS:
        p.resetJointState(shadow.arm, f, 0.0, physicsClientId=shadow.cid)
    for body in shadow.bodies.values():
        _filter(shadow.cid, body, _OBSTACLE_GROUP, _ARM_GROUP)


def set_joints(cid: int, body: int, q: np.ndarray | list[float]) -> None:
    """A Panda's seven arm joints at `q`, still: one call, the state that a resetJointState per joint
    leaves (the same links and contacts; the planning client lists contacts in another order now and
    then, which `valid` ignores; the live world's settling came out bit for bit the same)."""
    values = q.tolist() if isinstance(q, np.ndarray) else q
    p.resetJointStatesMultiDof(body, ARM_JOINTS, [[x] for x in values[:7]], _STILL, physicsClientId=cid)


def straight(a: np.ndarray, b: np.ndarray, n: int) -> list[np.ndarray]:
    """n joint configurations from a to b, both included."""
    return [a + (b - a) * t for t in np.linspace(0.0, 1.0, n)]
