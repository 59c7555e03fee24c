"""Tasks, registered by id: each owns its seeded episode generator, its goal check and Bob's
progress text. A new task is a new class decorated with `@register_task`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, TypeVar

import numpy as np

from .assets import Color, Shape
from .scene import Layout


@dataclass(frozen=True)
class ObjectKind:
    """A graspable object built from one primitive (suction-pickable from its top)."""

    name: str
    shape: Shape
    color: Color

    @property
    def height(self) -> float:
        return self.shape.height


@dataclass(frozen=True)
class Placement:
    """Where the generator put one object: on a furniture top at (x, y), or in its drawer."""

    kind: ObjectKind
    furniture: str
    xy: tuple[float, float]  # absolute on a surface; in the drawer's frame when inside
    inside: bool
    target: bool


@dataclass(frozen=True)
class TaskResult:
    """The goal check: success kept apart from the score."""

    success: bool
    placed: int
    total: int
    partial_success: float = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "partial_success", self.placed / self.total if self.total else 0.0)


class ObjectState(Protocol):
    @property
    def name(self) -> str: ...
    @property
    def on(self) -> str | None: ...


class Task(Protocol):
    id: str
    brief: str

    def generate(self, layout: Layout, seed: int, n_objects: int) -> list[Placement]: ...
    def evaluate(self, targets: list[str], objects: list[ObjectState]) -> TaskResult: ...
    def status(self, targets: list[str], objects: list[ObjectState]) -> str: ...
    def detail(self, robot: str, targets: list[str]) -> str: ...


TASKS: dict[str, Task] = {}
T = TypeVar("T", bound=Task)


def register_task(cls: type[T]) -> type[T]:
    """Class decorator: make the task available by its `id`."""
    task = cls()
    TASKS[task.id] = task
    return cls


def get_task(task_id: str) -> Task:
    try:
        return TASKS[task_id]
    except KeyError:
        raise ValueError(f"unknown task {task_id!r}; known tasks: {', '.join(TASKS)}") from None


def _kind(name: str, shape: str, size: tuple[float, float, float], color: Color) -> ObjectKind:
    return ObjectKind(name, Shape(shape, size), color)


PACK_POOL = (
    _kind("apple", "sphere", (0.04, 0.04, 0.08), (0.8, 0.1, 0.1, 1)),
    _kind("fork", "box", (0.17, 0.03, 0.02), (0.7, 0.7, 0.72, 1)),
    _kind("soap", "box", (0.09, 0.06, 0.035), (0.6, 0.85, 0.95, 1)),
    _kind("toy_duck", "sphere", (0.045, 0.045, 0.09), (0.95, 0.85, 0.1, 1)),
    _kind("phone", "box", (0.15, 0.075, 0.015), (0.1, 0.1, 0.1, 1)),
    _kind("bottle", "cylinder", (0.035, 0.035, 0.2), (0.1, 0.6, 0.3, 1)),
    _kind("book", "box", (0.2, 0.14, 0.03), (0.5, 0.2, 0.1, 1)),
    _kind("mug", "cylinder", (0.04, 0.04, 0.1), (0.95, 0.95, 0.95, 1)),
    _kind("banana", "box", (0.18, 0.04, 0.04), (0.95, 0.9, 0.3, 1)),
    _kind("sponge", "box", (0.1, 0.07, 0.04), (0.95, 0.6, 0.2, 1)),
)


@register_task
class PackObjects:
    """Pack Objects: put each listed object into the tray on Bob's table (table_0).

    What the task is: Bob holds the list of target objects; the team must find them (some are
    hidden or in other rooms), bring them within Bob's reach and pack them into the tray.

    What is randomized (by the seed): which 3-6 objects are targets and where they lie. Every
    episode has one target on table_0 within Bob's reach, one on table_0 beyond it, one in the
    closed drawer unit, and the rest on furniture in other rooms; plus one or two distractors
    (not on the list) anywhere.

    What success means: every target lies in the tray and nothing else does; the partial
    success is the fraction of targets in the tray.
    """

    id = "pack_objects"
    brief = "Pack the listed objects into the tray on table_0; nothing else goes in the tray."

    def generate(self, layout: Layout, seed: int, n_objects: int) -> list[Placement]:
        rng = np.random.default_rng(seed)
        n_distractors = 1 + int(rng.integers(0, 2))
        kinds = [PACK_POOL[i] for i in rng.permutation(len(PACK_POOL))[: n_objects + n_distractors]]
        container = next(f for f in layout.furniture if f.drawer is not None)
        assert container.drawer is not None
        fits = container.drawer.max_object_height

        def shuffled(xs: list[tuple[str, tuple[float, float], bool]]) -> list[tuple[str, tuple[float, float], bool]]:
            return [xs[i] for i in rng.permutation(len(xs))]

        near = shuffled([(layout.bob_table, s, False) for s in layout.near_slots])
        far = shuffled([(layout.bob_table, s, False) for s in layout.far_slots])
        inside = shuffled([(container.name, s, True) for s in container.drawer.slots])
        elsewhere = shuffled([(f.name, s, False) for f in layout.furniture if f.name != layout.bob_table for s in f.slots])
        # the drawer's target is the first one short enough for it
        targets, distractors = kinds[:n_objects], kinds[n_objects:]
        hidden = next(i for i in [*range(2, n_objects), 0, 1] if targets[i].height <= fits)
        targets[2], targets[hidden] = targets[hidden], targets[2]
        out = [
            Placement(targets[0], *near.pop(), target=True),
            Placement(targets[1], *far.pop(), target=True),
            Placement(targets[2], *inside.pop(), target=True),
        ]
        out += [Placement(k, *elsewhere.pop(), target=True) for k in targets[3:]]
        spare = shuffled(near + far + inside + elsewhere)
        for k in distractors:
            spot = next(s for s in spare if not s[2] or k.height <= fits)
            spare.remove(spot)
            out.append(Placement(k, *spot, target=False))
        return out

    def evaluate(self, targets: list[str], objects: list[ObjectState]) -> TaskResult:
        in_tray = {o.name for o in objects if o.on == "tray"}
        placed = sum(1 for t in targets if t in in_tray)
        return TaskResult(success=placed == len(targets) and in_tray <= set(targets), placed=placed, total=len(targets))

    def status(self, targets: list[str], objects: list[ObjectState]) -> str:
        in_tray = [o.name for o in objects if o.on == "tray"]
        missing = [t for t in targets if t not in in_tray]
        wrong = [n for n in in_tray if n not in targets]
        parts = [f"In the tray: {', '.join(in_tray) if in_tray else 'nothing yet'}."]
        parts.append(f"Not yet in the tray: {', '.join(missing)}." if missing else "Every listed object is in the tray.")
        if wrong:
            parts.append(f"In the tray but not on the list (take it out): {', '.join(wrong)}.")
        return " ".join(parts)

    def detail(self, robot: str, targets: list[str]) -> str:
        if robot == "bob":
            return f"Objects to pack: {', '.join(targets)}."
        return "Help Bob pack the listed objects into the tray on table_0: find them, fetch them and hand them over."
