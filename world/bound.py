"""A lower bound on the temporal steps any team could need for a generated episode (TS*).

The bound is the optimum of a relaxation of the episode, solved exactly. The relaxation drops
what makes the episode hard to plan: every robot knows where everything is (nobody explores,
asks or tells), no skill fails, `navigate` reaches any stand pose in one step, every robot acts
once per tick, and within a tick a robot acts on what the robots before it did (the sequential
schedule, the paper's: the loosest of the tick schedules, so the bound holds for lockstep too).
It keeps the rules of the task and the team that no plan can get round:

- Only a robot that finishes the task (`RobotKind.finishes_task`: the paper's Bob, fixed on his
  table) may place on the task's goal fixtures (world/skills/manipulation.py refuses anyone
  else). So every target costs a finisher a pick and a place: 2 of its steps.
- Only a fetcher (a robot that navigates and picks: the paper's Alice) moves an object to Bob's
  table, one object at a time. A target that starts away from it costs a fetcher a navigate to
  it, a pick, a navigate back carrying it and a place within Bob's reach: 4 steps, none shared
  between two objects. A closed container is opened once (1 fetcher step) before its targets
  are picked. A target on Bob's table beyond his reach costs a fetcher a pick and a place (2
  steps), and a navigate there if she brings nothing else.
- A target Bob can reach needs only his pick and place.

The bound is the largest of:

- the fetchers' steps shared among the fetchers, plus the finisher's place of the last object
  they bring (he can pick it in the tick it arrives, not before);
- the longest chain one object needs: a fetcher's navigate, (open,) pick, navigate, place, then
  the finisher's place (an open by another fetcher earlier in the same tick does not lengthen it);
- the finishers' work: for every release tick r (the first tick in which a target can be on
  Bob's table within his reach: 1 for one he can reach, 2 for one beyond it, 4 or 5 for one
  fetched), the targets released at r or later need 2 finisher steps each, no earlier than r,
  shared among the finishers.

Ignoring order (a sandwich's stack) and the time to walk between places only loosens it. It is
never above what a real team achieves in a tick schedule (tests check the heuristic team of
every shipped team). The async schedule's TS counts simulated seconds, not actions, so the bound
is not a bound on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .kinds import MAX_ARM_RANGE
from .physics import PhysicalWorld


@dataclass(frozen=True)
class SymbolicObject:
    name: str
    source: str  # the furniture it starts on or in
    inside: bool  # in a closed container
    on_bob_table: bool
    bob_can_reach: bool


@dataclass(frozen=True)
class SymbolicEpisode:
    objects: tuple[SymbolicObject, ...]  # the targets
    fetchers: int = 1  # robots that navigate and pick (the paper's Alice)
    finishers: int = 1  # robots that may place on the goal fixtures (the paper's Bob)


def _release(o: SymbolicObject, fetchers: int) -> int:
    """The first tick in which `o` can lie on Bob's table within his reach (module docstring)."""
    if o.on_bob_table:
        return 1 if o.bob_can_reach else 2  # a fetcher at the table picks (tick 1) and places (tick 2)
    return 4 + (1 if o.inside and fetchers == 1 else 0)  # navigate, (open,) pick, navigate, place


def lower_bound(ep: SymbolicEpisode) -> int:
    """The relaxation's optimum (see the module docstring): a lower bound on temporal steps."""
    away = [o for o in ep.objects if not o.on_bob_table]
    far = [o for o in ep.objects if o.on_bob_table and not o.bob_can_reach]
    opens = len({o.source for o in away if o.inside})
    fetching = 4 * len(away) + 2 * len(far) + opens + (1 if far and not away else 0)  # every fetcher's steps
    bounds = [math.ceil(fetching / ep.fetchers) + 1 if fetching else 0]
    releases = [_release(o, ep.fetchers) for o in ep.objects]
    bounds += [r + 1 for r in releases]  # the finisher picks in the release tick at the earliest, places after
    if ep.finishers:
        for r in set(releases):
            later = sum(1 for q in releases if q >= r)
            bounds.append(r - 1 + math.ceil(2 * later / ep.finishers))
    return max(bounds + [0])


def symbolic_episode(world: PhysicalWorld, targets: list[str]) -> SymbolicEpisode:
    """The relaxation of a freshly built episode, read from its ground truth."""
    fin = world.finisher()  # the arm on Bob's table
    base = fin.arm_base() if fin is not None else None
    objs = []
    for name in targets:
        o = world.objects[name]
        x, y, _ = world.position(o)
        on_table = world.on_bob_table(o.on)
        reach = base is not None and on_table and math.hypot(x - base[0], y - base[1]) <= MAX_ARM_RANGE
        objs.append(SymbolicObject(name, o.on or "", o.inside, on_table, reach))
    fetchers = sum(1 for b in world.bots.values() if b.kind.mobile and {"navigate", "pick"} <= set(b.kind.skills))
    finishers = sum(1 for b in world.bots.values() if b.kind.finishes_task)
    return SymbolicEpisode(tuple(objs), max(fetchers, 1), finishers)
