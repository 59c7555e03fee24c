"""Tasks, registered by id: each owns its episode generator, its goal check and Bob's status text."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .scene import Layout


@dataclass(frozen=True)
class ObjectKind:
    """A graspable object built from one primitive."""

    name: str
    shape: str  # box | cylinder | sphere
    size: tuple[float, float, float]  # box: sx, sy, sz; cylinder: r, r, h; sphere: r, r, 2r
    color: tuple[float, float, float, float]

    @property
    def height(self) -> float:
        return self.size[2]


@dataclass(frozen=True)
class Placement:
    """Where the generator put one object: on a furniture top at (x, y), or in its drawer."""

    kind: ObjectKind
    furniture: str
    xy: tuple[float, float]  # absolute for surfaces; relative to the closed drawer's centre when inside
    inside: bool
    target: bool


@dataclass(frozen=True)
class TaskResult:
    success: bool
    placed: int
    total: int

    @property
    def partial_success(self) -> float:
        return self.placed / self.total if self.total else 0.0


class ObjectState(Protocol):
    name: str
    on: str | None


class Task(Protocol):
    id: str
    brief: str

    def generate(self, layout: Layout, seed: int, n_objects: int) -> list[Placement]: ...
    def evaluate(self, targets: list[str], objects: list[ObjectState]) -> TaskResult: ...
    def status(self, targets: list[str], objects: list[ObjectState]) -> str: ...
    def detail(self, targets: list[str]) -> str: ...


PACK_POOL = (
    ObjectKind("apple", "sphere", (0.04, 0.04, 0.08), (0.8, 0.1, 0.1, 1)),
    ObjectKind("fork", "box", (0.17, 0.03, 0.02), (0.7, 0.7, 0.72, 1)),
    ObjectKind("soap", "box", (0.09, 0.06, 0.035), (0.6, 0.85, 0.95, 1)),
    ObjectKind("toy_duck", "sphere", (0.045, 0.045, 0.09), (0.95, 0.85, 0.1, 1)),
    ObjectKind("phone", "box", (0.15, 0.075, 0.015), (0.1, 0.1, 0.1, 1)),
    ObjectKind("bottle", "cylinder", (0.035, 0.035, 0.2), (0.1, 0.6, 0.3, 1)),
    ObjectKind("book", "box", (0.2, 0.14, 0.03), (0.5, 0.2, 0.1, 1)),
    ObjectKind("mug", "cylinder", (0.04, 0.04, 0.1), (0.95, 0.95, 0.95, 1)),
    ObjectKind("banana", "box", (0.18, 0.04, 0.04), (0.95, 0.9, 0.3, 1)),
    ObjectKind("sponge", "box", (0.1, 0.07, 0.04), (0.95, 0.6, 0.2, 1)),
)


class PackObjects:
    """Pack Objects: put each listed object into the tray on table_0, and nothing else.

    Randomized (by seed): which 3-6 objects are targets, and where they lie: at least one on
    table_0 within Bob's reach, one on table_0 beyond it, one hidden in the closed drawer, the
    rest on furniture in other rooms; plus one or two distractors that must stay out.

    Success: every target lies in the tray and no other object does; partial success is the
    fraction of targets in the tray.
    """

    id = "pack_objects"
    brief = "Pack the listed objects into the tray on table_0; nothing else goes in the tray."

    def generate(self, layout: Layout, seed: int, n_objects: int) -> list[Placement]:
        rng = np.random.default_rng(seed)
        pool = list(PACK_POOL)
        order = rng.permutation(len(pool))
        n_distractors = 1 + int(rng.integers(0, 2))
        kinds = [pool[i] for i in order[: n_objects + n_distractors]]
        drawer = next(f for f in layout.furniture if f.drawer is not None)
        surfaces = [f for f in layout.furniture if f.slots and f.drawer is None]
        spots: list[tuple[str, tuple[float, float], bool]] = []
        near, far = list(layout.near_slots), list(layout.far_slots)
        inside = list(drawer.drawer.slots) if drawer.drawer else []
        rng.shuffle(near)
        rng.shuffle(far)
        rng.shuffle(inside)
        other = [(f.name, s) for f in surfaces for s in f.slots]
        other = [other[i] for i in rng.permutation(len(other))]
        # the three kinds of work every episode needs
        spots.append(("table_0", near.pop(), False))
        spots.append(("table_0", far.pop(), False))
        spots.append((drawer.name, inside.pop(), True))
        # the rest anywhere: table_0, the drawer, or furniture in other rooms
        rest = [("table_0", s, False) for s in near + far] + [(drawer.name, s, True) for s in inside]
        rest += [(name, s, False) for name, s in other]
        for i in rng.permutation(len(rest)):
            if len(spots) >= len(kinds):
                break
            spots.append(rest[i])
        target_idx = set(range(n_objects))
        return [Placement(kind, name, xy, ins, i in target_idx) for i, (kind, (name, xy, ins)) in enumerate(zip(kinds, spots, strict=True))]

    def evaluate(self, targets: list[str], objects: list[ObjectState]) -> TaskResult:
        in_tray = {o.name for o in objects if o.on == "tray"}
        placed = sum(1 for t in targets if t in in_tray)
        return TaskResult(success=placed == len(targets) and in_tray <= set(targets), placed=placed, total=len(targets))

    def status(self, targets: list[str], objects: list[ObjectState]) -> str:
        in_tray = [o.name for o in objects if o.on == "tray"]
        missing = [t for t in targets if t not in in_tray]
        wrong = [n for n in in_tray if n not in targets]
        parts = [f"In the tray: {', '.join(in_tray) if in_tray else 'nothing yet'}."]
        parts.append(f"Still to pack: {', '.join(missing)}." if missing else "Every listed object is packed.")
        if wrong:
            parts.append(f"Not on the list but in the tray: {', '.join(wrong)}.")
        return " ".join(parts)

    def detail(self, targets: list[str]) -> str:
        return f"Objects to pack: {', '.join(targets)}."


TASKS: dict[str, Task] = {PackObjects.id: PackObjects()}


def get_task(task_id: str) -> Task:
    try:
        return TASKS[task_id]
    except KeyError:
        raise ValueError(f"unknown task {task_id!r}; known tasks: {', '.join(TASKS)}") from None
