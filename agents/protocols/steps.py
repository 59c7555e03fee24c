"""How one robot carries out the work it was given, a step at a time, over the team's knowledge
(knowledge.py): fetch an object to the finisher's table, look at a furniture (opening a closed
container), or, for the finisher, put what is within its reach on its goal. Shared by the
protocols that allocate work (centralized.py, leader.py); who gets which work is theirs to say.

The steps are the paper's skills with the recoveries the scripted experts use (heuristic.py): a
grasp that fails for distance is fixed with a `move` worked out from the feedback's offsets, any
other failed grasp or open tries the next stand pose, a navigation that stopped short drives
there again, a stand pose another robot holds (or is headed to) is not chosen.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from mhrc.core.protocol import (
    Action,
    ActionResult,
    Move,
    Navigate,
    Open,
    OutcomeCode,
    Pick,
    Place,
)

from ..heuristic_base import HANDOVER, _at_stand_pose, corrective_move, failed
from .knowledge import Knowledge, dist

__all__ = ["MAX_TRIES", "Hand", "Job", "finisher_step", "job_step"]

MAX_TRIES = 4  # failed grasps of one object before it is left (the experts' MAX_GRASP_TRIES)
BOB_TRIES = 2  # failed picks by the finisher before a fetcher brings the object closer
STRETCH = 0.1  # m beyond the finisher's reach it still tries for an object brought to its table


@dataclass(frozen=True)
class Job:
    """A unit of work: fetch an object to the finisher's table, or look at a furniture."""

    kind: Literal["fetch", "explore"]
    target: str

    def call(self) -> str:
        return f"{self.kind}({self.target})"


@dataclass
class Hand:
    """One robot as its planner keeps it: its work, its stand pose and what went wrong."""

    robot: str
    job: Job | None = None
    last: ActionResult | None = None
    pose: tuple[str, int] | None = None  # the stand pose it stands at or heads to
    pose_choice: dict[str, int] = field(default_factory=dict)  # furniture -> the stand pose to use there
    tries: dict[str, int] = field(default_factory=dict)  # object -> failed grasps
    slips: int = 0
    place_shift: int = 0
    broken_until: int = 0

    def record(self, result: ActionResult) -> None:
        self.last = result
        a, code = result.action, result.outcome.code
        if code == OutcomeCode.BROKEN_DOWN:
            ticks = result.outcome.details.get("ticks")
            self.broken_until = max(
                self.broken_until, result.tick + (int(ticks) if isinstance(ticks, (int, float)) else 1)
            )
            return
        if isinstance(a, Pick) and not result.outcome.succeeded:
            self.tries[a.obj] = self.tries.get(a.obj, 0) + 1
        if isinstance(a, Place):
            self.place_shift = 0 if result.outcome.succeeded else self.place_shift + 1
        if isinstance(a, Navigate):
            self.slips = self.slips + 1 if code == OutcomeCode.OFF_TARGET else 0
            if failed(result) and code != OutcomeCode.OFF_TARGET:
                self.pose_choice[a.target] = a.stand_pose + 1  # that stand pose is not to be had: the next
                self.pose = None


Taken = set[tuple[str, int]]  # stand poses other robots stand at or head to


def _pose(k: Knowledge, hand: Hand, furniture: str, near: tuple[float, ...], taken: Taken) -> int | None:
    """The stand pose of `furniture` to use: the one chosen before, else the nearest to `near`
    nobody else holds; None when all are held."""
    f = k.furniture[furniture]
    n = len(f.stand_poses)
    if not n:
        return None
    order = sorted(range(n), key=lambda i: dist((f.stand_poses[i].x, f.stand_poses[i].y), near))
    if furniture in hand.pose_choice:
        start = hand.pose_choice[furniture] % n
        order = order[order.index(start) :] + order[: order.index(start)]
    return next((i for i in order if (furniture, i) not in taken), None)


def _go(k: Knowledge, hand: Hand, furniture: str, idx: int) -> Action | None:
    """Navigate to stand pose `idx` of `furniture` unless the robot stands there already."""
    hand.pose = (furniture, idx)
    if _at_stand_pose(k.obs[hand.robot], k.furniture[furniture], idx):
        return None
    return Navigate(target=furniture, stand_pose=idx)


def _retry_slip(hand: Hand) -> Action | None:
    last = hand.last
    if (
        last is not None
        and isinstance(last.action, Navigate)
        and last.outcome.code == OutcomeCode.OFF_TARGET
        and hand.slips < 3
    ):
        return Navigate(target=last.action.target, stand_pose=last.action.stand_pose)
    return None


def _open(k: Knowledge, hand: Hand, furniture: str, taken: Taken) -> Action | None:
    f = k.furniture[furniture]
    last = hand.last
    if last is not None and isinstance(last.action, Open) and last.action.target == furniture and failed(last):
        hand.pose_choice[furniture] = hand.pose_choice.get(furniture, 0) + 1  # approach again, from the next pose
        hand.last = None
    idx = _pose(k, hand, furniture, f.position, taken)
    if idx is None:
        return None
    return _go(k, hand, furniture, idx) or Open(target=furniture)


def explore_step(k: Knowledge, hand: Hand, furniture: str, taken: Taken) -> Action | None:
    """The next step of looking at `furniture`; None when it is seen (or cannot be reached now)."""
    if furniture in k.explored:
        return None
    if (slip := _retry_slip(hand)) is not None:
        return slip
    f = k.furniture[furniture]
    if f.openable and not f.is_open:
        return _open(k, hand, furniture, taken) if "open" in k.obs[hand.robot].status.skills else None
    idx = _pose(k, hand, furniture, k.base(hand.robot) or f.position, taken)
    if idx is None:
        return None
    step = _go(k, hand, furniture, idx)
    if step is None:
        k.explored.add(furniture)  # standing there: seen
    return step


def _deliver(k: Knowledge, hand: Hand, holding: str, taken: Taken) -> Action | None:
    table = k.furniture.get(HANDOVER)
    if table is None or not table.stand_poses:
        return None
    goal = k.furniture.get(k.goal(holding))
    near = goal.position if goal is not None else (table.place_pose or table.position)
    n = len(table.stand_poses)
    order = sorted(range(n), key=lambda i: dist((table.stand_poses[i].x, table.stand_poses[i].y), near))
    order = order[hand.place_shift % n :] + order[: hand.place_shift % n]
    idx = next((i for i in order if (HANDOVER, i) not in taken), None)
    if idx is None:
        return None
    return _go(k, hand, HANDOVER, idx) or Place(obj=holding, location=HANDOVER)


def job_step(k: Knowledge, hand: Hand, taken: Taken) -> Action | None:
    """The next step of `hand`'s job; None when it is done or cannot go on (the planner gives
    other work)."""
    job, status = hand.job, k.obs[hand.robot].status
    if status.holding is not None:
        return _retry_slip(hand) or _deliver(k, hand, status.holding, taken)
    if job is None:
        return None
    if job.kind == "explore":
        return explore_step(k, hand, job.target, taken)
    o = k.located(job.target)
    if o is None or o.held_by not in (None, hand.robot) or o.on is None or k.done(job.target):
        return None
    if hand.tries.get(job.target, 0) >= MAX_TRIES:
        return None
    f = k.furniture.get(o.on)
    if f is None or not f.stand_poses:
        return None
    if f.openable and not f.is_open:
        return _open(k, hand, f.name, taken)
    if (slip := _retry_slip(hand)) is not None:
        return slip
    last = hand.last
    if last is not None and isinstance(last.action, Pick) and last.action.obj == job.target and failed(last):
        d = last.outcome.details
        if last.outcome.code == OutcomeCode.TOO_FAR and "offset_x" in d and "offset_y" in d:
            fix = corrective_move(k.obs[hand.robot], (float(d["offset_x"]), float(d["offset_y"])))
            if fix is not None:
                hand.last = None
                return Move(dx=fix[0], dy=fix[1])
        hand.pose_choice[f.name] = (hand.pose[1] + 1) if hand.pose is not None and hand.pose[0] == f.name else 1
        hand.last = None
    moved = last is not None and isinstance(last.action, Move) and last.outcome.succeeded
    if moved and hand.pose is not None and hand.pose[0] == f.name:
        return Pick(obj=job.target)
    idx = _pose(k, hand, f.name, o.position, taken)
    if idx is None:
        return None
    return _go(k, hand, f.name, idx) or Pick(obj=job.target)


def finisher_step(k: Knowledge, hand: Hand) -> Action | None:
    """The finisher's next step: place what it holds on its goal, else pick the next target
    within its reach (in the list's order for an ordered task); None when there is none."""
    robot = hand.robot
    holding = k.obs[robot].status.holding
    if holding is not None:
        return Place(obj=holding, location=k.goal(holding) if holding in k.targets else HANDOVER)
    todo = k.todo()
    for t in todo[:1] if k.ordered else todo:
        o = k.located(t)
        if o is None or hand.tries.get(t, 0) >= BOB_TRIES:
            continue
        if k.in_reach(robot, o, STRETCH):
            return Pick(obj=t)
    return None


def finisher_can_take(k: Knowledge, hand: Hand, name: str) -> bool:
    """Whether the finisher will take `name` from its table itself (no fetcher needed)."""
    o = k.located(name)
    return o is not None and hand.tries.get(name, 0) < BOB_TRIES and k.in_reach(hand.robot, o, STRETCH)
