"""A scenario's events applied to a running episode (issue 25; the file format is scenario.py).

`Dynamics` holds one episode's scenario and fires its events when their tick opens (the
schedulers say when: world.schedulers). Each event changes the physical world only, never what a
robot believes (observe.Knowledge): robots learn of a relocated or new object by looking, of a
teammate's breakdown from its messages. An event that cannot apply when it fires (its object
already in place, nothing open to close) is skipped, and the `ScenarioEvent` says why.

Defaults (an event without `object`, `to`, `on` or `target`) are drawn from a generator seeded
by the episode's seed and the event's index, so the same episode and scenario always change
the same things.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from mhrc.core.logs import get_logger
from mhrc.core.protocol import ScenarioEvent
from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from . import assets
from .assets import AssetDir
from .furniture import Layout
from .layouts import get_layout
from .physics import ObjectState, PhysicalWorld
from .scenario import Breakdown, Close, EpisodeFacts, NewTarget, Relocate, Scenario, ScenarioEventSpec
from .tasks import Task, get_task

log = get_logger("mhrc.world.dynamics")

SPOT_CLEARANCE = 0.12  # m: a slot counts as free when no object's centre lies closer than this


def surfaces(layout: Layout) -> list[str]:
    """Furniture an object can be put on top of (slots, not a container)."""
    return [f.name for f in layout.furniture if f.slots and f.container is None]


def episode_facts(*, task: str, scene: str, horizon: int, robots: Iterable[str]) -> EpisodeFacts:
    """What scenario.check_scenario needs of an episode, read from the task and layout alone
    (nothing built). Object names: every name the task can generate (a sandwich's repeated
    ingredients are numbered: bread_slice_1, bread_slice_2)."""
    names = get_task(task).object_names()
    layout = get_layout(scene)
    return EpisodeFacts(
        horizon=horizon,
        robots=tuple(robots),
        surfaces=frozenset(surfaces(layout)),
        containers=frozenset(f.name for f in layout.furniture if f.container is not None),
        objects=frozenset(names),
    )


class Skip(Exception):
    """An event that cannot apply now; the message says why."""


class Dynamics:
    """One episode's scenario, fired tick by tick on its physical world."""

    def __init__(
        self,
        world: PhysicalWorld,
        task: Task,
        targets: list[str],
        goals: dict[str, str],
        asset_dir: AssetDir,
        seed: int,
        scenario: Scenario | None,
    ) -> None:
        self.world = world
        self.task = task
        self.targets = targets  # the Sim's own list and dict: a new target joins the task
        self.goals = goals
        self.assets = asset_dir
        self.seed = seed
        self.scenario = scenario
        self.tick = 0  # the latest tick opened
        self.pending = (
            sorted(range(len(scenario.events)), key=lambda i: (scenario.events[i].tick, i)) if scenario else []
        )
        self.broken: dict[str, int] = {}  # robot -> the tick its breakdown ends (exclusive)
        self.opened: list[str] = []  # containers open now, in the order they were opened

    # ------------------------------------------------------------------ what the simulator asks
    def broken_for(self, robot: str) -> int:
        """Ticks `robot` stays broken down from the current tick on (0: it works)."""
        return max(0, self.broken.get(robot, 0) - self.tick)

    def note_containers(self) -> None:
        """Keep the order containers were opened in (after every skill: for `close` without a target)."""
        now_open = [name for name in self.world.opening if self.world.is_open(name)]
        self.opened = [n for n in self.opened if n in now_open] + [n for n in now_open if n not in self.opened]

    # ------------------------------------------------------------------ firing
    def fire_due(self, tick: int) -> list[ScenarioEvent]:
        """Tick `tick` opens: apply every event due by then, in tick then file order."""
        self.tick = max(self.tick, tick)
        out = []
        while self.scenario is not None and self.pending and self.scenario.events[self.pending[0]].tick <= tick:
            index = self.pending.pop(0)
            out.append(self._fire(index, self.scenario.events[index]))
        return out

    def _fire(self, index: int, ev: ScenarioEventSpec) -> ScenarioEvent:
        assert self.scenario is not None
        rng = np.random.default_rng([self.seed, index, 0x5CE7])
        try:
            if isinstance(ev, Relocate):
                changed = self._relocate(ev, rng)
            elif isinstance(ev, Breakdown):
                changed = self._breakdown(ev)
            elif isinstance(ev, NewTarget):
                changed = self._new_target(ev, rng)
            else:
                assert isinstance(ev, Close)
                changed = self._close(ev)
            applied, skipped, text = True, None, _sentence(ev.kind, changed)
        except Skip as why:
            applied, skipped, changed, text = (
                False,
                str(why),
                {},
                f"The {ev.kind} event of tick {ev.tick} was skipped: {why}.",
            )
        log.info(
            "scenario event", index=index, kind=ev.kind, tick=ev.tick, applied=applied, skipped=skipped, changed=changed
        )
        return ScenarioEvent(
            scenario=self.scenario.name,
            sha256=self.scenario.sha256,
            index=index,
            event=ev.kind,
            tick=ev.tick,
            applied=applied,
            skipped=skipped,
            changed=changed,
            text=text,
        )

    def _relocate(self, ev: Relocate, rng: np.random.Generator) -> dict[str, str]:
        w = self.world
        movable = [n for n in self.targets if w.objects[n].held_by is None and w.objects[n].on != self.goals.get(n)]
        if ev.object is not None:
            if ev.object not in w.objects or ev.object not in self.targets:
                raise Skip(f"{ev.object} is not a target of this episode")
            if ev.object not in movable:
                raise Skip(
                    f"{ev.object} is already in place"
                    if w.objects[ev.object].held_by is None
                    else f"{ev.object} is held by {w.objects[ev.object].held_by}"
                )
            name = ev.object
        elif movable:
            name = movable[int(rng.integers(0, len(movable)))]
        else:
            raise Skip("every target is in place or held")
        obj = w.objects[name]
        old = obj.on or "nowhere"
        to = self._surface(ev.to, rng, avoid=obj.on)
        self._put(obj, to, rng)
        return {"object": name, "from": old, "to": to}

    def _breakdown(self, ev: Breakdown) -> dict[str, str]:
        if ev.robot not in self.world.bots:
            raise Skip(f"{ev.robot} is not in this episode")
        until = max(self.broken.get(ev.robot, 0), ev.tick + ev.ticks)
        self.broken[ev.robot] = until
        return {"robot": ev.robot, "until": str(until)}

    def _new_target(self, ev: NewTarget, rng: np.random.Generator) -> dict[str, str]:
        w = self.world
        kinds = {k.name: k for k in self.task.target_kinds()}
        if ev.object is not None:
            if ev.object in w.objects:
                raise Skip(f"{ev.object} is already in the scene")
            if ev.object not in kinds:
                raise Skip(f"{ev.object} cannot be a target of {self.task.id}")
            kind = kinds[ev.object]
        else:
            used_goals = {self.goals[t] for t in self.targets} if self.task.id == "sort_solids" else set()
            fresh = [k for k in kinds.values() if k.name not in w.objects and self.task.goal(k) not in used_goals]
            if not fresh:
                raise Skip(f"every object {self.task.id} can add is in the scene already")
            kind = fresh[int(rng.integers(0, len(fresh)))]
        on = self._surface(ev.on, rng, avoid=None)
        path = assets.write_object(self.assets, kind.name, kind.shape, kind.color)
        body = p.loadURDF(path, (0, 0, -5), physicsClientId=w.cid)
        obj = ObjectState(kind.name, kind, body, on, False, True)
        try:
            self._put(obj, on, rng)
        except Skip:
            p.removeBody(body, physicsClientId=w.cid)
            raise
        w.objects[kind.name] = obj
        self.targets.append(kind.name)
        self.goals[kind.name] = self.task.goal(kind)
        return {"object": kind.name, "on": on, "total": str(len(self.targets))}

    def _close(self, ev: Close) -> dict[str, str]:
        self.note_containers()
        if ev.target is not None:
            if not self.world.is_open(ev.target):
                raise Skip(f"{ev.target} is already closed")
            name = ev.target
        elif self.opened:
            name = self.opened[-1]
        else:
            raise Skip("no container is open")
        self.world.set_container(name, 0.0)
        self.note_containers()
        return {"container": name}

    # ------------------------------------------------------------------ places
    def _surface(self, given: str | None, rng: np.random.Generator, avoid: str | None) -> str:
        lay = self.world.layout
        if given is not None:
            if given == avoid:
                raise Skip(f"the object already lies on {given}")
            return given
        choices = [s for s in surfaces(lay) if s not in (avoid, lay.bob_table) and self._free_slots(s)]
        if not choices:
            raise Skip("no surface has a free spot")
        return choices[int(rng.integers(0, len(choices)))]

    def _free_slots(self, furniture: str) -> list[tuple[float, float]]:
        f = self.world.layout.get(furniture)
        assert f is not None
        taken = [self.world.position(o)[:2] for o in self.world.objects.values() if o.held_by is None]
        return [s for s in f.slots if all(math.hypot(s[0] - x, s[1] - y) >= SPOT_CLEARANCE for x, y in taken)]

    def _put(self, obj: ObjectState, furniture: str, rng: np.random.Generator) -> None:
        """Set `obj` on a free slot of `furniture` (upright, at rest)."""
        free = self._free_slots(furniture)
        if not free:
            raise Skip(f"{furniture} has no free spot")
        x, y = free[int(rng.integers(0, len(free)))]
        f = self.world.layout.get(furniture)
        assert f is not None
        obj.on, obj.inside, obj.local = furniture, False, None
        self.world.rest(obj, x, y, f.top)


def _sentence(kind: str, c: dict[str, str]) -> str:
    if kind == "relocate":
        return f"Someone moved {c['object']} from {c['from']} to {c['to']}."
    if kind == "breakdown":
        return f"{c['robot']} broke down until tick {c['until']}: it can only communicate and wait."
    if kind == "new_target":
        return f"{c['object']} joined the task, on {c['on']} ({c['total']} targets now)."
    return f"{c['container']} closed."
