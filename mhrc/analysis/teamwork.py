"""The metrics of a team's work (issue 33), computed from an episode's action results: who did how
much of it, what was done twice, and what talking cost. `mhrc.analysis.metrics.from_trace` adds them to
every episode's metrics; none of the paper's metrics (Succ, PS, TS, AS) reads them.

Per robot:

- actions: `action_steps_per_robot` (wait excluded) and `actions_per_robot` (wait included), as
  mhrc.analysis.metrics has always counted them;
- messages_per_robot: its communicate actions that were delivered (what `messages` sums);
- moves_per_robot: its successful picks and its successful places, one each (a pick and the place
  that puts the object down are two moves): the objects it moved, its share of the work as PARTNR's
  human-AI study reports it. A robot's share of a set of episodes is its moves over all robots'
  moves in them (mhrc.eval.means.summarize); a robot that only looks has share 0.

Communication beside action, DynaHMRC's two cost figures: `communication_steps` are the
communicate actions executed (delivered or not, as AS counts failed actions); the other action
steps are `action_steps - communication_steps` (every other non-wait action).

Redundant actions, what one robot did that a teammate had already done. "Before" is on the world's
clock: action a is before action b when a ended at or before the moment b started (`ended` <=
`started` of their results: in the sequential schedule an earlier robot's turn of the same tick is
before, in lockstep an action of the same tick is not, since the team acts at once); for results
without clock times (traces of hand or of an older world), when a's tick is below b's.

- redundant_navigations, a: a navigate of robot R to furniture F that succeeded, when a teammate had
  reached F before (a successful navigate of the teammate to F, before R's), after which R neither
  picks nor places anything (no pick or place action, whatever its outcome) until it next navigates
  or moves, or the episode ends: R went to look where someone had already looked, and did nothing
  there. A navigate that failed is not counted (it is a failed action, not a second look).
- redundant_picks, b: a pick of object O by robot R (whatever its outcome) when a teammate holds O at
  the moment R's pick starts: the teammate's successful pick of O is before R's pick, and the
  teammate's next successful place of O, if any, is not.
- redundant_per_robot: both counted per robot; `redundant` in summaries is a + b.

In every schedule, a robot's own actions are ordered by their tick, then their start on the clock,
then their place in the trace.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from mhrc.core.protocol import ActionResult, Navigate, Pick, Place

__all__ = ["Teamwork", "before", "teamwork"]

EPS = 1e-6  # clock times are rounded to microseconds (world/schedulers)


@dataclass(frozen=True)
class Teamwork:
    """The team metrics of one episode (the module docstring defines each)."""

    messages_per_robot: dict[str, int]
    moves_per_robot: dict[str, int]
    communication_steps: int
    redundant_navigations: int
    redundant_picks: int
    redundant_per_robot: dict[str, int]


def before(a: ActionResult, b: ActionResult) -> bool:
    """Whether action a ended at or before the moment action b started (the module docstring)."""
    if a.ended is not None and b.started is not None:
        return a.ended <= b.started + EPS
    return a.tick < b.tick


def _own_order(results: Sequence[ActionResult]) -> dict[str, list[ActionResult]]:
    """Each robot's results in the order it did them."""
    out: dict[str, list[tuple[int, float, int, ActionResult]]] = {}
    for i, r in enumerate(results):
        out.setdefault(r.robot, []).append((r.tick, r.started or 0.0, i, r))
    return {robot: [r for *_, r in sorted(mine, key=lambda x: x[:3])] for robot, mine in out.items()}


def _redundant_navigations(results: Sequence[ActionResult], own: dict[str, list[ActionResult]]) -> Counter[str]:
    reached: dict[str, list[ActionResult]] = {}  # furniture -> the successful navigates to it
    for r in results:
        if isinstance(r.action, Navigate) and r.outcome.succeeded:
            reached.setdefault(r.action.target, []).append(r)
    found: Counter[str] = Counter()
    for robot, mine in own.items():
        for i, nav in enumerate(mine):
            if not isinstance(nav.action, Navigate) or not nav.outcome.succeeded:
                continue
            seen = any(o.robot != robot and before(o, nav) for o in reached.get(nav.action.target, []))
            if not seen:
                continue
            worked = False
            for later in mine[i + 1 :]:
                if later.action.skill in ("navigate", "move"):
                    break
                if later.action.skill in ("pick", "place"):
                    worked = True
                    break
            if not worked:
                found[robot] += 1
    return found


def _held(own: dict[str, list[ActionResult]]) -> dict[str, list[tuple[str, ActionResult, ActionResult | None]]]:
    """Object -> (robot, its successful pick, its next successful place of that object or None)."""
    spans: dict[str, list[tuple[str, ActionResult, ActionResult | None]]] = {}
    for robot, mine in own.items():
        for i, pick in enumerate(mine):
            if not isinstance(pick.action, Pick) or not pick.outcome.succeeded:
                continue
            obj = pick.action.obj
            put = next(
                (
                    p
                    for p in mine[i + 1 :]
                    if isinstance(p.action, Place) and p.action.obj == obj and p.outcome.succeeded
                ),
                None,
            )
            spans.setdefault(obj, []).append((robot, pick, put))
    return spans


def _redundant_picks(results: Sequence[ActionResult], own: dict[str, list[ActionResult]]) -> Counter[str]:
    spans = _held(own)
    found: Counter[str] = Counter()
    for r in results:
        if not isinstance(r.action, Pick):
            continue
        for holder, pick, put in spans.get(r.action.obj, []):
            if holder != r.robot and before(pick, r) and (put is None or not before(put, r)):
                found[r.robot] += 1
                break
    return found


def teamwork(results: Sequence[ActionResult], robots: Sequence[str]) -> Teamwork:
    """The team metrics of an episode from its action results (in trace order) and its robots."""
    own = _own_order(results)
    messages = Counter(r.robot for r in results if r.action.skill == "communicate" and r.outcome.succeeded)
    moves = Counter(r.robot for r in results if r.action.skill in ("pick", "place") and r.outcome.succeeded)
    navigations = _redundant_navigations(results, own)
    picks = _redundant_picks(results, own)
    return Teamwork(
        messages_per_robot={r: messages.get(r, 0) for r in robots},
        moves_per_robot={r: moves.get(r, 0) for r in robots},
        communication_steps=sum(1 for r in results if r.action.skill == "communicate"),
        redundant_navigations=sum(navigations.values()),
        redundant_picks=sum(picks.values()),
        redundant_per_robot={r: navigations.get(r, 0) + picks.get(r, 0) for r in robots},
    )
