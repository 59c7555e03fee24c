"""Who does which work: estimated costs of each robot for each job, and the assignment that
minimizes their sum, solved exactly (scipy's `linear_sum_assignment`, the Hungarian method on a
rectangular matrix). The same estimates are the bids of the leader protocol's auction.

A cost is in steps (a navigation is one step, whatever its length, as TS counts them), with the
distance to walk as a tie-break, and two terms that make the sum prefer parallel work:

- **Exploration is parallel work.** The fetches known are ranked (in the task's order); the
  first costs its steps, each next one `RANK` more. Looking at a container costs its steps plus
  `LOOK`, between the two: a lone fetcher fetches what is known first (a scout may yet find the
  rest on a surface, and opening a container for nothing costs two steps), while of several
  fetchers one brings the first object and the others open containers at once: the objects still
  unseen are the ones whose fetching cannot start until someone looks.
- **A surface is a scout's.** A robot that can pick pays `SCOUT_SURFACE` more to look at an open
  surface while a scout is there to do it: its steps are worth more elsewhere (it alone can open
  and carry).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mhrc.core.protocol import FurnitureView

from ..heuristic_base import HANDOVER
from .knowledge import Knowledge, dist
from .steps import Hand, Job

__all__ = ["INFEASIBLE", "assign", "cost"]

INFEASIBLE = 1e6
RANK = 2.0  # steps: each known fetch after the first (see the module docstring)
LOOK = 3.0  # steps: looking beside fetching, between the first fetch and the next
SCOUT_SURFACE = 3.0  # steps: a surface looked at by a robot that can pick, while a scout can
PER_METRE = 0.05  # steps per metre walked: the tie-break between robots and jobs of equal steps
AT_POSE = 0.3  # m: a robot this near a stand pose of a furniture stands at it
STAY = 0.5  # steps: a robot keeps the job it has over an equal one


def cost(k: Knowledge, hand: Hand, job: Job, rank: int = 0, scouts: bool = False) -> float:
    """Estimated steps for `hand`'s robot to do `job` (INFEASIBLE when it cannot); `rank`: the
    job's place among the known fetches; `scouts`: a scout is there to look at surfaces."""
    obs = k.obs.get(hand.robot)
    if obs is None:
        return INFEASIBLE
    skills = set(obs.status.skills)
    here = k.base(hand.robot)
    if "navigate" not in skills or here is None:
        return INFEASIBLE
    keep = -STAY if hand.job == job else 0.0
    if job.kind == "explore":
        f = k.furniture[job.target]
        closed = f.openable and not f.is_open
        if closed and "open" not in skills:
            return INFEASIBLE
        surface = not f.openable
        extra = SCOUT_SURFACE if surface and scouts and "pick" in skills else 0.0
        there = _there(hand, job, here, f)  # half done: finish it
        steps = (0 if there else 1) + (1 if closed else 0)
        return LOOK + steps + extra + PER_METRE * dist(here, f.position) + keep
    if "pick" not in skills:
        return INFEASIBLE
    o = k.located(job.target)
    if o is None or o.on is None:
        return INFEASIBLE
    src = k.furniture.get(o.on)
    table = k.furniture.get(HANDOVER)
    if src is None or table is None:
        return INFEASIBLE
    there = _there(hand, job, here, src)
    fetch_steps = (
        (3.0 if there else 4.0)
        + (1 if src.openable and not src.is_open else 0)
        + (1 if hand.tries.get(job.target, 0) else 0)
    )
    walk = dist(here, o.position) + dist(o.position, table.position)
    ahead = 0.0 if there else RANK * rank  # one it stands at does not wait its turn: its navigation is saved
    return fetch_steps + ahead + PER_METRE * walk + keep


def _there(hand: Hand, job: Job, here: tuple[float, float], f: FurnitureView) -> bool:
    """`hand`'s robot stands at a stand pose of `f`, or was sent there for `job` (its navigation
    may still be under way, or its result not heard yet): the navigation is spent."""
    if any(dist(here, (sp.x, sp.y)) <= AT_POSE for sp in f.stand_poses):
        return True
    return hand.job == job and hand.pose is not None and hand.pose[0] == f.name


def assign(
    k: Knowledge, hands: Sequence[Hand], jobs: Sequence[Job], *, start: int = 0, scouts: bool = False
) -> dict[str, Job]:
    """The assignment of `jobs` to `hands` that minimizes the summed cost (each robot at most one
    job, each job at most one robot); pairs that cannot be done are left out. The fetches rank
    after the `start` fetches under way already: in the task's order for an ordered task, else
    cheapest first (by the lowest cost any of `hands` has for it)."""
    if not hands or not jobs:
        return {}
    from scipy.optimize import linear_sum_assignment  # here: the CLI's start does not load scipy

    fetches = [i for i, j in enumerate(jobs) if j.kind == "fetch"]
    if (
        not k.ordered
    ):  # any order will do: the cheapest first (an object in the gripper's reach before one across the house)
        fetches.sort(key=lambda i: min(cost(k, h, jobs[i]) for h in hands))
    ranks = [0] * len(jobs)
    for n, i in enumerate(fetches):
        ranks[i] = start + n
    matrix = np.array([[cost(k, h, j, r, scouts) for j, r in zip(jobs, ranks, strict=True)] for h in hands])
    rows, cols = linear_sum_assignment(matrix)
    return {hands[r].robot: jobs[c] for r, c in zip(rows, cols, strict=True) if matrix[r, c] < INFEASIBLE}
