"""The robots' kinematic PyBullet bodies (their kinds are data: world/kinds.py).

Bases and arms are moved by setting poses and joint states; an object held by suction follows the tool tip (a kinematic attachment, so
every run of the same actions ends in the same state).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np
import pybullet_data

from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from . import assets
from .arm import EE_LINK, FINGERS, HOME, set_joints
from .assets import AssetDir
from .kinds import ARM_FORWARD, CHASSIS, CHASSIS_COLOR, DRONE_COLOR, RobotKind

PANDA = "franka_panda/panda.urdf"


@dataclass
class RobotBody:
    """One robot's live state: base pose, arm joints, held object, body ids."""

    name: str
    kind: RobotKind
    cid: int
    base: tuple[float, float, float] | None = None  # x, y, yaw; None for a fixed arm
    fixed_arm: tuple[float, float, float] | None = None  # arm base of a fixed arm
    fixed_yaw: float = 0.0
    body: int = -1  # chassis or mobile base
    arm: int = -1
    q: np.ndarray = field(default_factory=lambda: HOME.copy())
    holding: str | None = None
    held_body: int = -1
    held_drop: float = 0.0  # how far the held object's centre hangs below the tool tip
    held_yaw: float = 0.0  # the held object's yaw relative to the tool's
    altitude: float = 0.0  # a flier's height above the floor (flight_altitude)

    # ---------------------------------------------------------------- geometry
    def arm_base(self) -> tuple[float, float, float] | None:
        if not self.kind.has_arm:
            return None
        if self.base is None:
            return self.fixed_arm
        x, y, yaw = self.base
        return (x + ARM_FORWARD * math.cos(yaw), y + ARM_FORWARD * math.sin(yaw), CHASSIS[2])

    def arm_yaw(self) -> float:
        return self.base[2] if self.base is not None else self.fixed_yaw

    def tip(self) -> tuple[float, float, float]:
        st = p.getLinkState(self.arm, EE_LINK, computeForwardKinematics=True, physicsClientId=self.cid)
        return (float(st[4][0]), float(st[4][1]), float(st[4][2]))

    def tool_yaw(self) -> float:
        """Heading of the tool's x axis in the world's xy plane."""
        st = p.getLinkState(self.arm, EE_LINK, computeForwardKinematics=True, physicsClientId=self.cid)
        m = p.getMatrixFromQuaternion(st[5])
        return math.atan2(m[3], m[0])

    # ---------------------------------------------------------------- moving
    def set_base(self, pose: tuple[float, float, float]) -> None:
        self.base = pose
        x, y, yaw = pose
        if self.kind.has_arm:
            orn = p.getQuaternionFromEuler((0, 0, yaw))
            p.resetBasePositionAndOrientation(self.body, (x, y, 0.0), orn, physicsClientId=self.cid)
            ab = self.arm_base()
            assert ab is not None
            p.resetBasePositionAndOrientation(self.arm, ab, orn, physicsClientId=self.cid)
            self._carry()
        elif self.kind.flies:  # hovering: the body's origin is its centre
            orn = p.getQuaternionFromEuler((0, 0, yaw))
            p.resetBasePositionAndOrientation(self.body, (x, y, self.altitude), orn, physicsClientId=self.cid)
        else:  # r2d2.urdf faces its own +y
            orn = p.getQuaternionFromEuler((0, 0, yaw - math.pi / 2))
            p.resetBasePositionAndOrientation(self.body, (x, y, 0.38), orn, physicsClientId=self.cid)

    def set_arm(self, q: np.ndarray) -> None:
        self.q = np.array(q, dtype=float)
        set_joints(self.cid, self.arm, self.q)
        self._carry()

    def run(self, path: list[np.ndarray], joint_speed: float = 1.0) -> float:
        """Move the arm along `path`; the simulated seconds it takes at `joint_speed` rad/s.

        Motion is kinematic and nothing steps or looks at the world while the arm moves (a skill
        holds the simulator), so only the path's end is set: the world after it is the one that
        setting every waypoint left, bit for bit (tests/test_arm.py plays episodes both ways)."""
        if path:
            self.set_arm(path[-1])
        return sum(float(np.max(np.abs(b - a))) for a, b in pairwise(path)) / joint_speed

    # ---------------------------------------------------------------- suction
    def attach(self, name: str, body: int) -> None:
        """Hold `body` as it is now, relative to the tool tip (suction)."""
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=self.cid)
        self.holding, self.held_body = name, body
        self.held_drop = self.tip()[2] - float(pos[2])
        self.held_yaw = p.getEulerFromQuaternion(orn)[2] - self.tool_yaw()
        self._carry()

    def release(self) -> None:
        self.holding, self.held_body = None, -1

    def _carry(self) -> None:
        if self.held_body < 0:
            return
        x, y, z = self.tip()
        orn = p.getQuaternionFromEuler((0, 0, self.tool_yaw() + self.held_yaw))
        p.resetBasePositionAndOrientation(self.held_body, (x, y, z - self.held_drop), orn, physicsClientId=self.cid)


def spawn(
    cid: int,
    name: str,
    kind: RobotKind,
    assets_dir: AssetDir,
    *,
    pose: tuple[float, float, float] | None = None,
    arm_base: tuple[float, float, float] | None = None,
    arm_yaw: float = 0.0,
    altitude: float = 0.0,
    visuals: bool = True,
) -> RobotBody:
    """Load a robot's bodies: a chassis with an arm, a fixed arm, a bare mobile base or a drone
    (hovering at `altitude`). `visuals` False: pybullet_data's robots without their visual meshes
    (most of a scene's build time: the Panda's alone take 65 ms a load), for a world no camera sees;
    their collision shapes, inertia and joints are the same."""
    r = RobotBody(name, kind, cid, fixed_arm=arm_base, fixed_yaw=arm_yaw, altitude=altitude)
    data = pybullet_data.getDataPath()
    flags = 0 if visuals else p.URDF_IGNORE_VISUAL_SHAPES
    if kind.has_arm:
        if kind.mobile:
            urdf = assets.link_urdf(f"{name}_chassis", assets.chassis_boxes(*CHASSIS, CHASSIS_COLOR))
            r.body = p.loadURDF(assets_dir.write(f"{name}_chassis", urdf), useFixedBase=True, physicsClientId=cid)
            r.arm = p.loadURDF(f"{data}/{PANDA}", useFixedBase=True, flags=flags, physicsClientId=cid)
        else:
            assert arm_base is not None, f"{name}: a fixed arm needs its base position"
            orn = p.getQuaternionFromEuler((0, 0, arm_yaw))
            r.arm = p.loadURDF(f"{data}/{PANDA}", arm_base, orn, useFixedBase=True, flags=flags, physicsClientId=cid)
        for f in FINGERS:  # closed fingers around the suction cup
            p.resetJointState(r.arm, f, 0.0, physicsClientId=cid)
    elif kind.flies:
        urdf = assets.link_urdf(f"{name}_drone", assets.drone_boxes(DRONE_COLOR))
        r.body = p.loadURDF(assets_dir.write(f"{name}_drone", urdf), useFixedBase=True, physicsClientId=cid)
    else:
        r.body = p.loadURDF(f"{data}/r2d2.urdf", globalScaling=0.8, flags=flags, physicsClientId=cid)
    if kind.mobile:
        assert pose is not None, f"{name}: a mobile robot needs a start pose"
        r.set_base(pose)
    if kind.has_arm:
        r.set_arm(HOME)
    return r
