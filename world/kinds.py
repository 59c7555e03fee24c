"""Robot kinds as data: what each kind can do (skills, reach, speed, whether it flies or finishes
the task) and the few dimensions of its body that planners and views share. No simulator here:
checking a team, placing it on a map or drawing it needs none (world/robots.py builds the bodies).

A new robot kind is a new `RobotKind` entry, not a new code path: the skills check
`has_arm` / `mobile` / `flies` / `finishes_task` and the capability set; a base's speed and a
flier's altitude are the kind's numbers.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RobotKind:
    id: str
    label: str  # how observations describe it
    skills: tuple[str, ...]
    model: str  # what the body is made of
    mobile: bool
    has_arm: bool
    reach: float | None = None  # conservative horizontal reach of the arm (m): picks within it usually succeed
    footprint: float = 0.0  # radius the occupancy grid is inflated by
    finishes_task: bool = False  # may place on the task's goal fixtures (the paper: only Bob finishes the task)
    speed: float = 0.5  # m/s along a navigate's path: the simulated time of base motions
    flies: bool = False  # plans in the air: walls block it, furniture does not (PhysicalWorld.grid_for)
    altitude: float = 0.0  # m: a flier's lowest cruise height (flight_altitude raises it over tall furniture)


KINDS: dict[str, RobotKind] = {
    k.id: k
    for k in (
        RobotKind(
            "mobile_manipulator",
            "mobile manipulator",
            ("navigate", "move", "open", "pick", "place", "communicate", "wait"),
            "box chassis with a Franka Panda arm and a suction cup",
            mobile=True,
            has_arm=True,
            reach=0.72,
            footprint=0.3,
        ),
        RobotKind(
            "tabletop_arm",
            "tabletop manipulator",
            ("pick", "place", "communicate", "wait"),
            "Franka Panda arm fixed on table_0, with a suction cup",
            mobile=False,
            has_arm=True,
            reach=0.62,
            finishes_task=True,
        ),
        RobotKind(
            "mobile_base",
            "mobile robot",
            ("navigate", "communicate", "wait"),
            "R2-D2 style wheeled base (pybullet_data r2d2.urdf)",
            mobile=True,
            has_arm=False,
            footprint=0.3,
        ),
        RobotKind(
            "drone",
            "drone",
            ("navigate", "communicate", "wait"),
            "small quadrotor built from boxes, hovering at flight altitude",
            mobile=True,
            has_arm=False,
            footprint=0.25,  # rotor tip to rotor tip 0.46 m
            speed=1.5,
            flies=True,
            altitude=2.0,  # above a mobile manipulator's arm at full stretch (about 1.7 m)
        ),
    )
}

TEAM: dict[str, str] = {"alice": "mobile_manipulator", "bob": "tabletop_arm", "david": "mobile_base"}
ROBOTS = tuple(TEAM)  # the fixed execution order

CHASSIS = (0.6, 0.5, 0.65)  # Alice's chassis: length, width, height (the arm mounts on top)
ARM_FORWARD = 0.2  # arm base ahead of the chassis centre
MAX_ARM_RANGE = 0.9  # no top-down pose of a Panda exists beyond this horizontal distance from its arm base
CHASSIS_COLOR = (0.55, 0.25, 0.6, 1.0)
DRONE_COLOR = (0.95, 0.55, 0.1, 1.0)
AIR_CLEARANCE = 0.4  # m: a flier cruises at least this high above the tallest furniture of its layout


def flight_altitude(kind: RobotKind, tallest: float) -> float:
    """Where a flier cruises and hovers: its kind's altitude, or higher over furniture as tall as
    `tallest` (m), so that it passes over every piece, never through one."""
    return round(max(kind.altitude, tallest + AIR_CLEARANCE), 3)
