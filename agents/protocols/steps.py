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

import math
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
    Wait,
)

from ..heuristic_base import HANDOVER, _at_stand_pose, corrective_move, failed
from .knowledge import Knowledge, dist
from .pairing import arm_at, pair_pose, places_from

__all__ = ["MAX_TRIES", "Hand", "Job", "finisher_step", "job_step", "next_wanted", "standing"]

HOLD_TICKS = 8  # ticks a fetcher holds an object the ordered task does not want yet, before putting it down
MAX_TRIES = 8  # failed grasps of one object by one robot before it leaves it to others
BOB_TRIES = 2  # failed picks by the finisher before a fetcher brings the object closer
HANDOVER_MARGIN = 0.35  # m: how far inside both arms' reach the band of the finisher's table must lie
REACH_MARGIN = 0.1  # m inside a fetcher's reach it picks from where it stands rather than walk to a nearer pose
PLACE_MARGIN = 0.15  # m: _places_here, the looser estimate of the band (see _hands_over's HANDOVER_MARGIN)
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
    bad: dict[str, set[int]] = field(default_factory=dict)  # furniture -> stand poses that failed it there
    tries: dict[str, int] = field(default_factory=dict)  # object -> failed grasps
    slips: int = 0
    place_shift: int = 0
    broken_until: int = 0
    held_for: int = 0  # ticks it has waited at the table holding an object not wanted yet

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
        if isinstance(a, Place) and not result.outcome.succeeded:
            self.place_shift += 1  # a table too crowded there, or beyond the arm: the next stand pose (kept)
            self.spoil(a.location)  # and not from here again
        if isinstance(a, Place) and result.outcome.succeeded:
            self.bad.pop(a.location, None)
        if isinstance(a, Navigate):
            self.slips = self.slips + 1 if code == OutcomeCode.OFF_TARGET else 0
            if failed(result) and code != OutcomeCode.OFF_TARGET:
                if code != OutcomeCode.OCCUPIED:  # (an occupied one frees)
                    self.spoil(a.target, a.stand_pose)  # that stand pose is not to be had: another
                self.pose = None  # it is where it was (its planner looks: steps.standing)

    def spoil(self, furniture: str, idx: int | None = None) -> None:
        """Stand pose `idx` of `furniture` (the one it stands at, by default) failed it: use another."""
        if idx is None:
            if self.pose is None or self.pose[0] != furniture:
                return
            idx = self.pose[1]
        self.bad.setdefault(furniture, set()).add(idx)


class Taken(set[tuple[str, int]]):
    """Stand poses other robots stand at or head to; `yielding`: those held by idle robots, which
    leave when another robot needs the pose."""

    def __init__(self, held: set[tuple[str, int]], yielding: set[tuple[str, int]]) -> None:
        super().__init__(held | yielding)
        self.yielding = yielding


WAIT_FOR_ROOM = -1  # _pose: the pose is claimed from an idle robot; wait a step for it to leave


def _pose(k: Knowledge, hand: Hand, furniture: str, near: tuple[float, ...], taken: Taken) -> int | None:
    """The stand pose of `furniture` to use: the one chosen before, else the nearest to `near`
    nobody else holds; None when all are held."""
    f = k.furniture[furniture]
    n = len(f.stand_poses)
    if not n:
        return None
    order = sorted(range(n), key=lambda i: dist((f.stand_poses[i].x, f.stand_poses[i].y), near))
    bad = hand.bad.get(furniture, set())
    if len(bad) >= n:
        bad.clear()  # every pose failed once: try them again
    order = [i for i in order if i not in bad]
    if all((furniture, i) in taken for i in order) and order and taken.yielding:
        # every pose is held; one held by an idle robot is claimed: it leaves (the planner's round) and this one waits
        idle = next((i for i in order if (furniture, i) in taken.yielding), None)
        if idle is not None:
            hand.pose = (furniture, idle)
            return WAIT_FOR_ROOM
    return next((i for i in order if (furniture, i) not in taken), None)


def _go(k: Knowledge, hand: Hand, furniture: str, idx: int) -> Action | None:
    """Navigate to stand pose `idx` of `furniture` unless the robot stands there already."""
    if idx == WAIT_FOR_ROOM:
        return Wait()
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
        hand.spoil(furniture)  # approach again, from another pose
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


def _standing_at(k: Knowledge, hand: Hand, furniture: str) -> int | None:
    """The stand pose of `furniture` the robot stands at now, if any."""
    f = k.furniture.get(furniture)
    if f is None:
        return None
    obs = k.obs[hand.robot]
    return next((i for i in range(len(f.stand_poses)) if _at_stand_pose(obs, f, i)), None)


def standing(k: Knowledge, robot: str, near: float | None = None) -> tuple[str, int] | None:
    """The stand pose `robot` stands at now (furniture, index), if any; with `near`, the nearest
    one within that many metres (a robot stopped off target near a pose is in the way of it)."""
    obs = k.latest(robot) if robot in k.obs else None
    if obs is None or obs.status.base is None:
        return None
    if near is not None:
        b = obs.status.base
        poses = [
            (dist((b.x, b.y), (sp.x, sp.y)), f.name, i)
            for f in k.furniture.values()
            for i, sp in enumerate(f.stand_poses)
        ]
        d, name, idx = min(poses, default=(math.inf, "", 0))
        return (name, idx) if d <= near else None
    for f in k.furniture.values():
        for i in range(len(f.stand_poses)):
            if _at_stand_pose(obs, f, i):
                return (f.name, i)
    return None


def next_wanted(k: Knowledge) -> str | None:
    """For an ordered task (a sandwich), the first target still to go that is not lying on the
    finisher's table already: the only one a fetcher puts down there (the table's band the arm
    reaches holds few objects; one brought early can leave no room for the next)."""
    if not k.ordered:
        return None
    for t in k.todo():
        o = k.objects.get(t)
        if o is None or o.on != HANDOVER:
            return t
    return None


def _hands_over(k: Knowledge, robot: str) -> bool:
    """Whether `robot`'s arm, where it stands, reaches into the band of the finisher's table the
    finisher's arm reaches (the place skill puts an object there or fails)."""
    mine = k.obs[robot].status
    fin = k.obs.get(k.finisher or "")
    theirs = fin.status if fin is not None else None
    if mine.arm_base is None or mine.reach is None or theirs is None or theirs.arm_base is None:
        return False
    return dist(mine.arm_base, theirs.arm_base) <= mine.reach + (theirs.reach or 0.0) - HANDOVER_MARGIN


def _far_one(k: Knowledge, holding: str) -> str | None:
    """A target other than `holding` lying on the finisher's table beyond the finisher's reach,
    that nobody holds: the one a fetcher at the table may take next."""
    fin = k.finisher
    for t in k.todo():
        o = k.located(t)
        if t != holding and o is not None and o.on == HANDOVER and o.held_by is None and fin is not None:
            if not k.in_reach(fin, o, STRETCH):
                return t
    return None


def _deliver(k: Knowledge, hand: Hand, holding: str, taken: Taken, early: int = 0, pair: bool = False) -> Action | None:
    """To the finisher's table and put it down: from the stand pose it stands at already, else
    the free one nearest the table's place pose (after a place failed, the next one). In an
    ordered task only the object wanted next is put down; another waits in the gripper there
    (a few ticks at most: `HOLD_TICKS`). `pair`: a pose it stands at counts when its arm likely
    reaches the band near the table's place pose (pairing.places_from), and it comes to the pose
    from which it also picks a target lying on the table beyond the finisher's reach, when there
    is one (pairing.pair_pose)."""
    table = k.furniture.get(HANDOVER)
    if table is None or not table.stand_poses:
        return None
    bad = hand.bad.get(HANDOVER, set())
    n = len(table.stand_poses)
    if len(bad) >= n:
        bad.clear()  # it failed from every pose (the table was crowded): try them again
    here = _standing_at(k, hand, HANDOVER)
    idx: int | None
    arm = arm_at(k, hand.robot, here) if pair and here is not None else None
    paired = None
    if pair and (far := _far_one(k, holding)) is not None:
        paired = pair_pose(k, hand.robot, far, bad | {i for i in range(n) if (HANDOVER, i) in taken})
    if (
        here is not None
        and here not in bad
        and (HANDOVER, here) not in taken
        and (places_from(k, hand.robot, arm) if arm is not None else _hands_over(k, hand.robot))
        and (paired is None or paired == here)
    ):
        idx = here
    elif paired is not None:
        idx = paired
    else:
        near = table.place_pose or table.position
        order = [
            i
            for i in sorted(range(n), key=lambda i: dist((table.stand_poses[i].x, table.stand_poses[i].y), near))
            if i not in bad
        ]
        idx = next((i for i in order if (HANDOVER, i) not in taken), None)
        if idx is None:  # every pose it may use is held: claim one an idle robot holds (it leaves), else wait
            idle = next((i for i in order if (HANDOVER, i) in taken.yielding), None)
            if idle is not None:
                hand.pose = (HANDOVER, idle)
            return Wait()
    step = _go(k, hand, HANDOVER, idx)
    if step is not None:
        return step
    wanted = next_wanted(k)
    if (
        wanted is not None
        and holding != wanted
        and holding in k.targets
        and hand.held_for < HOLD_TICKS
        and _waiting_on_table(k, wanted) >= early
    ):
        hand.held_for += 1
        return Wait()
    hand.held_for = 0
    return Place(obj=holding, location=HANDOVER)


def _slipped_to(hand: Hand, furniture: str) -> bool:
    """Its last navigation, to `furniture`, ended off target (near the stand pose)."""
    last = hand.last
    return (
        last is not None
        and isinstance(last.action, Navigate)
        and last.action.target == furniture
        and last.outcome.code == OutcomeCode.OFF_TARGET
    )


def _places_here(k: Knowledge, robot: str) -> bool:
    """Whether, from where it stands, `robot`'s arm likely reaches a spot on the finisher's table
    that the finisher's arm reaches (looser than `_hands_over`: a wrong guess costs one failed place)."""
    mine = k.obs[robot].status
    fin = k.obs.get(k.finisher or "")
    theirs = fin.status if fin is not None else None
    if mine.arm_base is None or mine.reach is None or theirs is None or theirs.arm_base is None:
        return False
    return dist(mine.arm_base, theirs.arm_base) <= mine.reach + (theirs.reach or 0.0) - PLACE_MARGIN


def _waiting_on_table(k: Knowledge, wanted: str) -> int:
    """Targets of an ordered task lying on the finisher's table before their turn (`wanted` is next)."""
    return sum(1 for t in k.todo() if t != wanted and (o := k.located(t)) is not None and o.on == HANDOVER)


def job_step(
    k: Knowledge, hand: Hand, taken: Taken, *, near: bool = False, early: int = 0, pair: bool = False
) -> Action | None:
    """The next step of `hand`'s job; None when it is done or cannot go on (the planner gives
    other work). `near`: after a navigation that ended off target, act from where it stopped when
    that looks near enough (the object within its arm's reach; the finisher's table's band within
    reach), rather than always driving to the stand pose again. `early`: in an ordered task, how
    many objects may lie on the finisher's table before their turn (one put down early frees the
    fetcher's gripper; too many fill the band the finisher's arm reaches). `pair`: at the finisher's
    table, stand where one pose serves both picking and placing (pairing.py; `_deliver`)."""
    job, status = hand.job, k.obs[hand.robot].status
    if status.holding is not None:
        wanted = next_wanted(k)
        if (
            near
            and _slipped_to(hand, HANDOVER)
            and _places_here(k, hand.robot)
            and (
                wanted is None
                or wanted == status.holding
                or status.holding not in k.targets
                or _waiting_on_table(k, wanted) < early
            )
        ):
            hand.last = None
            return Place(obj=status.holding, location=HANDOVER)
        return _retry_slip(hand) or _deliver(k, hand, status.holding, taken, early, pair)
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
    if near and _slipped_to(hand, f.name) and _within_arm(k, hand.robot, o.position):
        return Pick(obj=job.target)  # (a grasp too far is fixed with a move, as after any grasp)
    if (slip := _retry_slip(hand)) is not None:
        return slip
    last = hand.last
    if last is not None and isinstance(last.action, Move) and failed(last):  # the fix could not be driven: another pose
        hand.spoil(f.name)
        hand.last = None
    elif last is not None and isinstance(last.action, Pick) and last.action.obj == job.target and failed(last):
        d = last.outcome.details
        if last.outcome.code == OutcomeCode.TOO_FAR and "offset_x" in d and "offset_y" in d:
            fix = corrective_move(k.obs[hand.robot], (float(d["offset_x"]), float(d["offset_y"])))
            if fix is not None:
                hand.last = None
                return Move(dx=fix[0], dy=fix[1])
        hand.spoil(f.name)
        hand.last = None
    moved = last is not None and isinstance(last.action, Move) and last.outcome.succeeded
    if moved and hand.pose is not None and hand.pose[0] == f.name:
        return Pick(obj=job.target)
    here = _standing_at(k, hand, f.name)
    if here is not None and here not in hand.bad.get(f.name, set()) and _within_arm(k, hand.robot, o.position):
        hand.pose = (f.name, here)  # it looked from here (or brought another from here): no need to stand elsewhere
        return Pick(obj=job.target)
    if pair and f.name == HANDOVER:  # beyond the finisher's reach on its table: a pose that also places it
        skip = hand.bad.get(f.name, set()) | {i for i in range(len(f.stand_poses)) if (f.name, i) in taken}
        if (both := pair_pose(k, hand.robot, job.target, skip)) is not None:
            return _go(k, hand, f.name, both) or Pick(obj=job.target)
    idx = _pose(k, hand, f.name, o.position, taken)
    if idx is None:
        return None
    return _go(k, hand, f.name, idx) or Pick(obj=job.target)


def _within_arm(k: Knowledge, robot: str, position: tuple[float, ...]) -> bool:
    s = k.obs[robot].status
    return s.arm_base is not None and s.reach is not None and dist(position, s.arm_base) <= s.reach - REACH_MARGIN


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


def make_room(
    k: Knowledge, hand: Hand, claimed: set[tuple[str, int]], taken: Taken, needed: frozenset[str] = frozenset()
) -> Action | None:
    """An idle robot standing where another robot needs to stand: to the nearest stand pose of a
    furniture nobody needs (not the finisher's table, nothing claimed there, none of `needed`:
    furniture a robot will come to for an object, whose stand poses it may all need)."""
    if hand.pose is None or (hand.pose not in claimed and hand.pose[0] != HANDOVER and hand.pose[0] not in needed):
        return None  # (at the finisher's table it leaves anyway: that is where the fetchers come)
    here = k.base(hand.robot)
    if here is None:
        return None
    options = [
        (dist(here, (sp.x, sp.y)), f.name, i)
        for f in k.furniture.values()
        if f.name != HANDOVER and f.name != hand.pose[0] and f.name not in needed
        for i, sp in enumerate(f.stand_poses)
        if (f.name, i) not in taken and (f.name, i) not in claimed
    ]
    if not options:
        return None
    _, name, idx = min(options)
    hand.pose = (name, idx)
    return Navigate(target=name, stand_pose=idx)
