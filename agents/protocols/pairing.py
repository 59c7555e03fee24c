"""Where a fetcher stands at the finisher's table to do two things from one place: put down what it
brings within the finisher's reach, and pick up a target that lies on that table beyond the
finisher's reach (every episode has one). From such a stand pose the object beyond the arm costs
a pick and a place, not a navigation there, a pick, a navigation back and a place.

Worked out from what the robot knows: the stand poses of the table (its furniture view), its own
arm's offset from its base and its reach (its status), the finisher's arm base and reach (the
finisher's status), the object's position (a scene graph). A guess that proves wrong costs a
failed place, after which the fetcher tries another pose (steps.Hand.spoil).
"""

from __future__ import annotations

import math

from ..heuristic_base import HANDOVER
from .knowledge import Knowledge, dist

__all__ = ["arm_at", "pair_pose", "places_from"]

PLACE_MARGIN = 0.15  # m: as steps.PLACE_MARGIN, the band of the finisher's table both arms reach
PICK_MARGIN = 0.1  # m inside the fetcher's reach it counts on picking from the pose (steps.REACH_MARGIN)


def arm_at(k: Knowledge, robot: str, idx: int, furniture: str = HANDOVER) -> tuple[float, float] | None:
    """Where `robot`'s arm base would be standing at stand pose `idx` of `furniture`: the pose,
    plus the arm's offset ahead of the base that the robot's status shows now."""
    s = k.latest(robot).status
    f = k.furniture.get(furniture)
    if s.base is None or s.arm_base is None or f is None or idx >= len(f.stand_poses):
        return None
    ahead = dist(s.arm_base, (s.base.x, s.base.y))
    sp = f.stand_poses[idx]
    return (sp.x + ahead * math.cos(sp.yaw), sp.y + ahead * math.sin(sp.yaw))


def places_from(k: Knowledge, robot: str, arm: tuple[float, float]) -> bool:
    """Whether `robot`'s arm based at `arm` likely reaches a spot of the finisher's table within
    the finisher's arm's reach: the band both arms reach, near the table's place pose (where the
    place skill puts things down)."""
    mine = k.latest(robot).status
    fin = k.obs.get(k.finisher or "")
    table = k.furniture.get(HANDOVER)
    if fin is None or fin.status.arm_base is None or mine.reach is None or table is None:
        return False
    near = table.place_pose or table.position
    return (
        dist(arm, fin.status.arm_base) <= mine.reach + (fin.status.reach or 0.0) - PLACE_MARGIN
        and dist(arm, near) <= mine.reach
    )


def pair_pose(k: Knowledge, robot: str, obj: str, skip: set[int]) -> int | None:
    """A stand pose of the finisher's table (none of `skip`) from which `robot` both picks `obj`,
    lying on that table, and places within the finisher's reach; the one nearest the object."""
    o = k.located(obj)
    f = k.furniture.get(HANDOVER)
    reach = k.latest(robot).status.reach
    if o is None or o.on != HANDOVER or o.held_by is not None or f is None or reach is None:
        return None
    options = []
    for i in range(len(f.stand_poses)):
        arm = arm_at(k, robot, i)
        if i in skip or arm is None:
            continue
        d = dist(arm, o.position)
        if d <= reach - PICK_MARGIN and places_from(k, robot, arm):
            options.append((d, i))
    return min(options)[1] if options else None
