"""Arm kinematics and motion planning for the Franka Panda arms (Alice's and Bob's).

Planning runs in a separate p.DIRECT "shadow" client holding one Panda and the furniture as
boxes, so it never moves the live robots: IK is plain PyBullet IK, clipped to the joint
limits, reseeded with random restarts and verified by forward kinematics; motions are planned
with OMPL BIT* in joint space, each state checked for contacts against the furniture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as p
import pybullet_data
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

ARM_JOINTS = list(range(7))
EE_LINK = 11  # panda_grasptarget: the suction cup's tip
LOWER = np.array([-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671])
UPPER = np.array([2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671])
HOME = np.array([0.0, -0.5, 0.0, -2.2, 0.0, 1.9, 0.785])
DOWN = (math.pi, 0.0)  # roll, pitch of a top-down tool (z axis pointing down)

_seeded = False


def seed_ompl(seed: int = 0) -> None:
    """OMPL's RNG seed must be set before any planner exists in the process (SIM-NOTES)."""
    global _seeded
    if not _seeded:
        ou.RNG.setSeed(seed + 1)
        ou.setLogLevel(ou.LogLevel.LOG_ERROR)
        _seeded = True


@dataclass
class PlanResult:
    path: list[np.ndarray] | None
    reason: str = ""  # "start_invalid", "goal_invalid", "no_plan" when path is None


class ArmPlanner:
    """IK and collision-free joint-space plans for a Panda whose base can be anywhere."""

    def __init__(self, seed: int = 0, budget: float = 1.0) -> None:
        seed_ompl(seed)
        self.cid = p.connect(p.DIRECT)
        self.rng = np.random.default_rng(seed)
        self.budget = budget
        self.arm = p.loadURDF(
            pybullet_data.getDataPath() + "/franka_panda/panda.urdf", useFixedBase=True, physicsClientId=self.cid
        )
        for f in (9, 10):
            p.resetJointState(self.arm, f, 0.0, physicsClientId=self.cid)
        self.boxes: dict[str, int] = {}
        self.checks = 0

    def close(self) -> None:
        if self.cid >= 0:
            p.disconnect(self.cid)
            self.cid = -1

    # ------------------------------------------------------------------ world model
    def set_box(self, name: str, center: tuple[float, float, float], half: tuple[float, float, float], yaw: float = 0.0) -> None:
        """Create or move the obstacle box `name`."""
        orn = p.getQuaternionFromEuler((0, 0, yaw))
        if name in self.boxes:
            p.resetBasePositionAndOrientation(self.boxes[name], center, orn, physicsClientId=self.cid)
            return
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.cid)
        self.boxes[name] = p.createMultiBody(0, shape, -1, center, orn, physicsClientId=self.cid)

    def set_base(self, xyz: tuple[float, float, float], yaw: float) -> None:
        p.resetBasePositionAndOrientation(self.arm, xyz, p.getQuaternionFromEuler((0, 0, yaw)), physicsClientId=self.cid)

    # ------------------------------------------------------------------ kinematics
    def _set(self, q: np.ndarray) -> None:
        for j, v in zip(ARM_JOINTS, q):
            p.resetJointState(self.arm, j, float(v), physicsClientId=self.cid)

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._set(q)
        st = p.getLinkState(self.arm, EE_LINK, computeForwardKinematics=True, physicsClientId=self.cid)
        return np.array(st[4]), np.array(st[5])

    def valid(self, q: np.ndarray) -> bool:
        """Within limits and touching no obstacle box."""
        self.checks += 1
        if np.any(q < LOWER - 1e-6) or np.any(q > UPPER + 1e-6):
            return False
        self._set(q)
        p.performCollisionDetection(physicsClientId=self.cid)
        for c in p.getContactPoints(bodyA=self.arm, physicsClientId=self.cid):
            if c[2] != self.arm and c[8] < 0:
                return False
        return True

    def ik(self, target: tuple[float, float, float], yaw: float, seed_q: np.ndarray, restarts: int = 8) -> np.ndarray | None:
        """A verified, collision-free joint solution putting the tool tip at `target`, pointing down."""
        orn = p.getQuaternionFromEuler((*DOWN, yaw))
        tgt = np.array(target)
        for k in range(restarts):
            start = seed_q if k == 0 else self.rng.uniform(LOWER, UPPER)
            self._set(start)
            sol = p.calculateInverseKinematics(
                self.arm, EE_LINK, target, orn, maxNumIterations=200, residualThreshold=1e-5, physicsClientId=self.cid
            )
            q = np.clip(np.array(sol[:7]), LOWER, UPPER)
            pos, got = self.fk(q)
            if np.linalg.norm(pos - tgt) > 0.005:
                continue
            dot = abs(float(np.dot(np.array(orn), got)))
            if 2 * math.acos(min(1.0, dot)) > 0.1:
                continue
            if self.valid(q):
                return q
        return None

    def reach_error(self, target: tuple[float, float, float], yaw: float, seed_q: np.ndarray) -> float:
        """How far the best IK attempt's tool tip stays from `target` (metres)."""
        orn = p.getQuaternionFromEuler((*DOWN, yaw))
        self._set(seed_q)
        sol = p.calculateInverseKinematics(self.arm, EE_LINK, target, orn, maxNumIterations=200, physicsClientId=self.cid)
        pos, _ = self.fk(np.clip(np.array(sol[:7]), LOWER, UPPER))
        return float(np.linalg.norm(pos - np.array(target)))

    # ------------------------------------------------------------------ planning
    def plan(self, start: np.ndarray, goal: np.ndarray, points: int = 30) -> PlanResult:
        """BIT* from start to goal (first solution), interpolated to `points` states."""
        if not self.valid(start):
            return PlanResult(None, "start_invalid")
        if not self.valid(goal):
            return PlanResult(None, "goal_invalid")
        space = ob.RealVectorStateSpace(7)
        bounds = ob.RealVectorBounds(7)
        for i in range(7):
            bounds.setLow(i, float(LOWER[i]))
            bounds.setHigh(i, float(UPPER[i]))
        space.setBounds(bounds)
        ss = og.SimpleSetup(space)
        ss.setStateValidityChecker(lambda s: self.valid(np.array([s[i] for i in range(7)])))
        si = ss.getSpaceInformation()
        si.setStateValidityCheckingResolution(0.005)
        st, gl = si.allocState(), si.allocState()
        for i in range(7):
            st[i], gl[i] = float(start[i]), float(goal[i])
        ss.setStartAndGoalStates(st, gl)
        planner = og.BITstar(si)
        planner.setStopOnSolnImprovement(True)
        ss.setPlanner(planner)
        status = ss.solve(self.budget)
        if status.getStatus() != ob.PlannerStatus.EXACT_SOLUTION:
            ss.clear()
            return PlanResult(None, "no_plan")
        path = ss.getSolutionPath()
        path.interpolate(points)
        out = [np.array([path.getState(k)[i] for i in range(7)]) for k in range(path.getStateCount())]
        ss.clear()
        return PlanResult(out)
