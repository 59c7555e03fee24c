"""A lower bound on the temporal steps any team could need for a generated episode.

The bound comes from a relaxation of the episode, solved exactly: full knowledge (nobody has to
explore, ask or tell), no failed skills, `navigate` reaches any stand pose in one step, every
robot acts once per lockstep tick. What the relaxation keeps are the hard constraints of the
team and the world:

- Alice is the only robot that can both move and carry, and her gripper holds one object at a
  time. Each target that starts away from Bob's table therefore costs her at least a navigate
  to it, a pick, a navigate back to Bob's table carrying it, and a place: 4 of her steps, none
  shared between two objects.
- A target inside a closed container needs that container opened once (1 step of hers).
- A target on Bob's table beyond any pose of his arm (farther than the arm's range from his
  base) needs her pick and place (2 steps), and, if she brings nothing else, a navigate there.
- A target Bob can reach needs a pick and a place by some arm (2 steps).

Alice's steps happen one per tick, so their sum bounds the makespan; so does half the steps of
both arms together. The bound is the larger of the two, and ignoring order (a sandwich's stack)
only loosens it. It is never above what a real team achieves (tests check the heuristic team).

A team with several fetchers (robots that navigate and pick) shares the fetching work: their
steps together, divided among them, bound the makespan, and so does the longest chain one
fetcher must walk alone for one object (its navigate, pick, navigate back and place, after an
open); the arms' steps are divided among every arm of the team. With the paper's team (one
fetcher, two arms) this is the bound above.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .physics import PhysicalWorld
from .robots import MAX_ARM_RANGE


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
    arms: int = 2  # robots with an arm, fetchers included (Alice and Bob)


def lower_bound(ep: SymbolicEpisode) -> int:
    """The relaxation's optimum (see the module docstring): a lower bound on temporal steps."""
    away = [o for o in ep.objects if not o.on_bob_table]
    far = [o for o in ep.objects if o.on_bob_table and not o.bob_can_reach]
    near = [o for o in ep.objects if o.on_bob_table and o.bob_can_reach]
    opens = len({o.source for o in away if o.inside})
    alice = 4 * len(away) + 2 * len(far) + opens + (1 if far and not away else 0)  # every fetcher's steps
    arms = alice + 2 * len(near)
    chain = max([4 + (1 if o.inside else 0) for o in away] + [2 + (0 if away else 1) for o in far] + [0])
    return max(math.ceil(alice / ep.fetchers), chain, math.ceil(arms / ep.arms))


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
    arms = sum(1 for b in world.bots.values() if b.kind.has_arm)
    return SymbolicEpisode(tuple(objs), max(fetchers, 1), max(arms, 1))
