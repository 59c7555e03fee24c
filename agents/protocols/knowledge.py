"""What a team knows together: the union of its robots' scene graphs, their statuses and the
task as the finisher's observation gives it. Built only from the observations and results the
robots received (never the world's state), so a planner over it is as partially observing as
the robots themselves.

Each robot's scene graph is its own memory, and memories disagree (one robot saw an object
taken away, another still remembers it where it was). The union keeps, for each object, the
newest change any robot's memory made: when a robot's view of an object differs from its view
at the step before, it learned something, and that is what the team now believes. One change is
not: a robot that finds an object gone from where it saw it, when the team already believes it
elsewhere (a teammate moved it), learned nothing new; nor does one that finds an object gone from
the finisher's table (the finisher took it, and the finisher's own view of its table says so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mhrc.core.protocol import ActionResult, FurnitureView, Navigate, ObjectView, Observation, Open, OutcomeCode, Place

from ..heuristic_base import HANDOVER, goal_of, role_of

__all__ = ["Knowledge", "dist"]


def dist(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


@dataclass
class Knowledge:
    """The union of the team's knowledge (see the module docstring)."""

    furniture: dict[str, FurnitureView] = field(default_factory=dict)
    objects: dict[str, ObjectView] = field(default_factory=dict)
    obs: dict[str, Observation] = field(default_factory=dict)  # robot -> its latest observation
    explored: set[str] = field(default_factory=set)  # furniture some robot has looked at (inside, for a container)
    told: list[str] = field(default_factory=list)  # the task's targets as a teammate told them (no task view here)
    told_ordered: bool = False
    brought: set[str] = field(default_factory=set)  # put on the finisher's table (by this robot, or as reported)
    _views: dict[str, dict[str, ObjectView]] = field(default_factory=dict)  # robot -> object -> its last view
    _open: dict[str, dict[str, bool | None]] = field(default_factory=dict)  # robot -> container -> is_open
    _after: dict[str, Observation] = field(default_factory=dict)  # robot -> the observation its last result carried

    # ---------------------------------------------------------------- taking in
    def take(self, obs: Observation) -> None:
        """Take in one robot's observation: its changes of belief become the team's."""
        self.obs[obs.robot] = obs
        before = self._views.setdefault(obs.robot, {})
        for o in obs.objects:
            known = self.objects.get(o.name)
            stale = (
                known is not None and o.last_seen_on is not None and known.on != o.last_seen_on
            )  # "gone from where I saw it", about a place the team knows it left already
            if o.on is None and o.held_by is None and o.last_seen_on == HANDOVER and obs.robot != self.finisher:
                stale = stale or self.finisher is not None  # the finisher sees its own table: its word on it counts
            if known is None or (before.get(o.name) != o and not stale):
                self.objects[o.name] = o
            before[o.name] = o
        opened = self._open.setdefault(obs.robot, {})
        for f in obs.furniture:
            seen = self.furniture.get(f.name)
            if seen is None or opened.get(f.name, f.is_open) != f.is_open:
                self.furniture[f.name] = f
            opened[f.name] = f.is_open
        holding = obs.status.holding
        if holding is not None and holding in self.objects:
            self.objects[holding] = self.objects[holding].model_copy(update={"held_by": obs.robot, "on": None})

    def record(self, robot: str, result: ActionResult) -> None:
        """What a result says beyond the next observation: a furniture looked at, and where the
        robot stands after it (its next observation may come only at its next turn)."""
        self._after[robot] = result.observation
        a, ok = result.action, result.outcome.succeeded
        if isinstance(a, Navigate) and ok:
            f = self.furniture.get(a.target)
            if f is not None and not (f.openable and not f.is_open):
                self.explored.add(a.target)
        if isinstance(a, Place) and ok and a.location == HANDOVER:
            self.brought.add(a.obj)
        if isinstance(a, Open) and (ok or result.outcome.code == OutcomeCode.ALREADY_OPEN):
            self.explored.add(a.target)

    # ---------------------------------------------------------------- the task (the finisher's view)
    @property
    def finisher(self) -> str | None:
        return next((r for r, o in self.obs.items() if role_of(o.status.skills) == "finisher"), None)

    def task_obs(self) -> Observation | None:
        """The observation that carries the task's target list (the finisher's)."""
        return next((o for o in self.obs.values() if o.targets), None)

    @property
    def targets(self) -> list[str]:
        t = self.task_obs()
        return list(t.targets) if t is not None else list(self.told)

    @property
    def ordered(self) -> bool:
        t = self.task_obs()
        return t.ordered if t is not None else self.told_ordered

    def goal(self, target: str) -> str:
        t = self.task_obs()
        return goal_of(t, target) if t is not None else HANDOVER

    def done(self, target: str) -> bool:
        """On its goal; for a robot without the task's view (only the finisher has it), brought to
        the finisher's table by this robot or, as a teammate reported, by another."""
        if self.task_obs() is None:
            return target in self.brought
        o = self.objects.get(target)
        return o is not None and o.held_by is None and o.on == self.goal(target)

    def todo(self) -> list[str]:
        return [t for t in self.targets if not self.done(t)]

    def located(self, name: str) -> ObjectView | None:
        """Where the team believes `name` is (held, or on a furniture); None when nobody knows."""
        o = self.objects.get(name)
        if o is None or (o.on is None and o.held_by is None):
            return None
        return o

    def goal_fixture(self, name: str | None) -> bool:
        """A task fixture on the finisher's table (tray, panel, board): nobody stands at it."""
        f = self.furniture.get(name or "")
        return f is not None and not f.stand_poses and name != HANDOVER

    def in_reach(self, robot: str, o: ObjectView, margin: float = 0.0) -> bool:
        """Whether `o` lies on the finisher's table within `robot`'s arm reach (plus `margin`)."""
        s = self.obs[robot].status
        return (
            o.on == HANDOVER
            and s.arm_base is not None
            and s.reach is not None
            and dist(o.position, s.arm_base) <= s.reach + margin
        )

    def latest(self, robot: str) -> Observation:
        """`robot`'s newest observation: the one it decided on, or, when newer, the one its last
        result carried (in the sequential schedule a robot that acted this tick shows where it
        went only at its next turn; its teammates plan before then)."""
        o, after = self.obs[robot], self._after.get(robot)
        return after if after is not None and after.tick > o.tick else o

    def base(self, robot: str) -> tuple[float, float] | None:
        b = self.latest(robot).status.base
        return None if b is None else (b.x, b.y)
