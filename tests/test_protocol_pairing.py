"""The centralized planner at the finisher's table (agents/protocols/pairing.py), on a small
hand-made table (no simulator): a target lying beyond the finisher's reach is fetched from a
stand pose that also puts it down within that reach, and a pose counts as one to put down from
only near the table's place pose."""

from __future__ import annotations

import math

from mhrc.agents.protocols.centralized import CentralPlanner
from mhrc.agents.protocols.knowledge import Knowledge
from mhrc.agents.protocols.pairing import pair_pose
from mhrc.agents.protocols.steps import Hand, Job, Taken, job_step
from mhrc.core.protocol import FurnitureView, Navigate, ObjectView, Observation, Pose2D, RobotStatus

FETCHER = ["navigate", "move", "open", "pick", "place", "communicate", "wait"]
ARM = ["pick", "place", "communicate", "wait"]
SCOUT = ["navigate", "communicate", "wait"]

# The finisher's table: its arm at (-0.5, 0); the fetcher's arm 0.2 m ahead of its base.
# Pose 0 (south, facing north) reaches the far object and the band near the place pose (0, -0.3);
# pose 1 (north) reaches the finisher's arm's band by distance but lies far from the place pose;
# pose 2 (east) is the one nearest the far object.
POSES = [
    Pose2D(x=0.3, y=-1.0, yaw=math.pi / 2),
    Pose2D(x=0.0, y=1.0, yaw=-math.pi / 2),
    Pose2D(x=1.2, y=0.0, yaw=math.pi),
]
FAR = ObjectView(name="book", position=(0.7, -0.35, 0.8), on="table_0")


def _furniture() -> list[FurnitureView]:
    table = FurnitureView(
        name="table_0", kind="desk", position=(0.0, 0.0, 0.7), stand_poses=POSES, place_pose=(0.0, -0.3, 0.7)
    )
    sofa = FurnitureView(name="sofa", kind="sofa", position=(5.0, 0.0, 0.5), stand_poses=[Pose2D(x=5.0, y=-1.0)])
    tray = FurnitureView(name="tray", kind="tray", position=(-0.4, 0.1, 0.72))
    return [table, sofa, tray]


def _fetcher(pose: Pose2D, holding: str | None = None, objects: list[ObjectView] = (), tick: int = 1) -> Observation:  # type: ignore[assignment]
    ahead = (pose.x + 0.2 * math.cos(pose.yaw), pose.y + 0.2 * math.sin(pose.yaw), 0.65)
    status = RobotStatus(name="f0", kind="k", skills=FETCHER, base=pose, arm_base=ahead, reach=0.72, holding=holding)
    return Observation(
        robot="f0",
        tick=tick,
        status=status,
        furniture=_furniture(),
        objects=list(objects),
        task_brief="",
        task_detail="",
    )


def _team(objects: list[ObjectView], at: Pose2D, holding: str | None = None) -> Knowledge:
    k = Knowledge()
    bob = RobotStatus(name="bob", kind="k", skills=ARM, arm_base=(-0.5, 0.0, 0.7), reach=0.62)
    targets = ["book", "mug"]
    k.take(
        Observation(
            robot="bob",
            tick=1,
            status=bob,
            furniture=_furniture(),
            objects=list(objects),
            task_brief="",
            task_detail="",
            targets=targets,
            goals={t: "tray" for t in targets},
        )
    )
    k.take(_fetcher(at, holding, objects))
    return k


def test_the_far_object_is_fetched_from_the_pose_that_also_puts_it_down() -> None:
    """Not the pose nearest the object (2), from which the fetcher would drive to pose 0 to put
    it down: from pose 0 it picks and places, one navigation fewer."""
    k = _team([FAR], Pose2D(x=5.0, y=-1.0))
    assert pair_pose(k, "f0", "book", set()) == 0
    hand = Hand("f0", job=Job("fetch", "book"))
    assert job_step(k, hand, Taken(set(), set()), pair=True) == Navigate(target="table_0", stand_pose=0)
    assert job_step(k, Hand("f0", job=Job("fetch", "book")), Taken(set(), set())) == Navigate(
        target="table_0", stand_pose=2
    )  # without pairing: the nearest pose


def test_the_planner_fetches_the_far_object_from_the_pose_that_puts_it_down() -> None:
    k = _team([FAR], Pose2D(x=5.0, y=-1.0))
    planner = CentralPlanner(("f0", "bob"), "sequential", knowledge=k)
    planner.hands["f0"].job = Job("fetch", "book")
    assert planner._step(planner.hands["f0"]) == Navigate(target="table_0", stand_pose=0)


def test_a_pose_far_from_the_place_pose_is_not_one_to_put_down_from() -> None:
    """Pose 1 lies within both arms' reach of each other, but the place skill puts an object down
    near the table's place pose, out of the fetcher's reach from there: it drives to pose 0."""
    held = ObjectView(name="mug", position=(0.0, 0.8, 0.9), held_by="f0")
    k = _team([held], POSES[1], holding="mug")
    hand = Hand("f0", job=Job("fetch", "mug"), pose=("table_0", 1))
    assert job_step(k, hand, Taken(set(), set()), pair=True) == Navigate(target="table_0", stand_pose=0)
