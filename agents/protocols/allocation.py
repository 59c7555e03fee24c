"""Who does which work: estimated costs of each robot for each job, and the assignment that
minimizes their sum, solved exactly (scipy's `linear_sum_assignment`, the Hungarian method on a
rectangular matrix). The same estimates are the bids of the leader protocol's auction.

A cost is in steps (a navigation is one step, whatever its length, as TS counts them), with the
distance to walk as a tie-break, plus a job's base: fetching is worth more than looking, so a
fetcher fetches what is known before it explores, and looking falls to whoever is free.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..heuristic_base import HANDOVER
from .knowledge import Knowledge, dist
from .steps import Hand, Job

__all__ = ["INFEASIBLE", "assign", "cost"]

INFEASIBLE = 1e6
EXPLORE_BASE = 5.0  # steps: what looking costs beside fetching (see the module docstring)
PER_METRE = 0.05  # steps per metre walked: the tie-break between robots and jobs of equal steps
STAY = 0.5  # steps: a robot keeps the job it has over an equal one


def cost(k: Knowledge, hand: Hand, job: Job) -> float:
    """Estimated steps for `hand`'s robot to do `job` (INFEASIBLE when it cannot)."""
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
        return EXPLORE_BASE + 1 + (1 if closed else 0) + PER_METRE * dist(here, f.position) + keep
    if "pick" not in skills:
        return INFEASIBLE
    o = k.located(job.target)
    if o is None or o.on is None:
        return INFEASIBLE
    src = k.furniture.get(o.on)
    table = k.furniture.get(HANDOVER)
    if src is None or table is None:
        return INFEASIBLE
    steps = 4.0 + (1 if src.openable and not src.is_open else 0) + (1 if hand.tries.get(job.target, 0) else 0)
    walk = dist(here, o.position) + dist(o.position, table.position)
    return steps + PER_METRE * walk + keep


def assign(k: Knowledge, hands: Sequence[Hand], jobs: Sequence[Job]) -> dict[str, Job]:
    """The assignment of `jobs` to `hands` that minimizes the summed cost (each robot at most one
    job, each job at most one robot); pairs that cannot be done are left out."""
    if not hands or not jobs:
        return {}
    from scipy.optimize import linear_sum_assignment  # here: the CLI's start does not load scipy

    matrix = np.array([[cost(k, h, j) for j in jobs] for h in hands], dtype=float)
    rows, cols = linear_sum_assignment(matrix)
    return {hands[r].robot: jobs[c] for r, c in zip(rows, cols, strict=True) if matrix[r, c] < INFEASIBLE}
