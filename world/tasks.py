"""Tasks, registered by id: each owns its seeded episode generator, the goal fixtures it puts
on Bob's table, its goal check and Bob's progress text. A new task is a new class decorated
with `@register_task`.

All three tasks share one shape: Bob (fixed on his table) finishes the task on the goal
fixtures within his reach; the targets start scattered so that the team must explore, open,
fetch and hand over. `scatter()` is that shared generator: every episode has one target on
Bob's table within his reach, one on it beyond his reach, one inside a closed container and the
rest on furniture in other rooms, plus one or two distractors anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, TypeVar

from .assets import Color, Shape
from .briefs import Briefing, ask
from .colors import NO_PANEL_COLORS, PANEL_COLORS
from .furniture import Fixture, Layout

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np


@dataclass(frozen=True)
class ObjectKind:
    """A graspable object built from one primitive (suction-pickable from its top).

    `group` is what the goal cares about: a solid's colour, an ingredient's type."""

    name: str
    shape: Shape
    color: Color
    group: str = ""

    @property
    def height(self) -> float:
        return self.shape.height


@dataclass(frozen=True)
class Placement:
    """Where the generator put one object: on a furniture top at (x, y), or in a container."""

    kind: ObjectKind
    furniture: str
    xy: tuple[float, float]  # absolute on a surface; in the container's frame when inside
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


@dataclass(frozen=True)
class Seen:
    """One object's end state as a goal check reads it: what it lies on and its height."""

    name: str
    kind: ObjectKind
    on: str | None
    z: float = 0.0


class Task(Protocol):
    id: str
    things: str  # what the task moves, as the helpers' briefs name it: objects, solids, ingredients
    ordered: bool  # whether the targets must reach their goals in the listed order

    def generate(self, layout: Layout, seed: int, n_objects: int) -> list[Placement]: ...
    def fixtures(self, layout: Layout) -> list[Fixture]: ...
    def goal(self, kind: ObjectKind) -> str: ...
    def target_kinds(self) -> list[ObjectKind]:
        """Every object an episode of this task can have as a target (what a new target may be)."""
        ...

    def object_names(self) -> set[str]:
        """Every object name an episode of this task can hold: targets (repeats numbered) and distractors."""
        ...

    def evaluate(self, targets: list[str], objects: list[Seen]) -> TaskResult: ...
    def status(self, targets: list[str], objects: list[Seen], aids: frozenset[str] = frozenset()) -> str:
        """Bob's task status as the paper gives it; with the `status_hints` aid, also what is
        missing, next or wrong."""
        ...

    def finisher_brief(self) -> str:
        """The brief of the robot that finishes the task (the appendix's Bob)."""
        ...

    def finisher_detail(
        self, b: Briefing, targets: list[str], goals: dict[str, str], aids: frozenset[str] = frozenset()
    ) -> str:
        """The finisher's detailed task: what goes where, whom to ask, and the list."""
        ...


TASKS: dict[str, Task] = {}
T = TypeVar("T", bound=Task)


def register_task(cls: type[T]) -> type[T]:
    """Class decorator: make the task available by its `id`."""
    task = cls()
    TASKS[task.id] = task
    return cls


def _rng(seed: int) -> np.random.Generator:
    """An episode's random generator. numpy is imported here: the registry of tasks (a command line
    checking a task's name) needs no numerics."""
    import numpy as np

    return np.random.default_rng(seed)


def get_task(task_id: str) -> Task:
    try:
        return TASKS[task_id]
    except KeyError:
        raise ValueError(f"unknown task {task_id!r}; known tasks: {', '.join(TASKS)}") from None


def _kind(name: str, shape: str, size: tuple[float, float, float], color: Color, group: str = "") -> ObjectKind:
    return ObjectKind(name, Shape(shape, size), color, group)


def _names(names: list[str]) -> str:
    return ", ".join(names) if names else "nothing yet"


# --------------------------------------------------------------------------- the shared generator

Spot = tuple[str, tuple[float, float], bool]  # furniture, xy, inside


def scatter(
    layout: Layout, rng: np.random.Generator, targets: list[ObjectKind], distractors: list[ObjectKind]
) -> list[Placement]:
    """Put targets[0] near Bob, targets[1] far on his table, one target that fits inside a closed
    container, the rest on other furniture; distractors on any spot left. `targets` keeps its order
    in the result (the first len(targets) placements)."""
    containers = [f for f in layout.furniture if f.container is not None]
    container = containers[int(rng.integers(0, len(containers)))] if len(containers) > 1 else containers[0]
    assert container.container is not None
    fits = container.container.max_object_height

    def shuffled(xs: list[Spot]) -> list[Spot]:
        return [xs[i] for i in rng.permutation(len(xs))]

    near = shuffled([(layout.bob_table, s, False) for s in layout.near_slots])
    far = shuffled([(layout.bob_table, s, False) for s in layout.far_slots])
    inside = shuffled([(container.name, s, True) for s in container.container.slots])
    elsewhere = shuffled([(f.name, s, False) for f in layout.furniture if f.name != layout.bob_table for s in f.slots])
    n = len(targets)
    roles = ["near", "far", "inside"] + ["elsewhere"] * (n - 3)
    # the container's target is one short enough for it (the first such one, after the first two)
    order = [2, *range(3, n), 0, 1]
    hidden = next(i for i in order if targets[i].height <= fits)
    roles[2], roles[hidden] = roles[hidden], roles[2]
    pools = {"near": near, "far": far, "inside": inside, "elsewhere": elsewhere}
    out = [Placement(k, *pools[role].pop(), target=True) for k, role in zip(targets, roles)]
    spare = shuffled(near + far + inside + elsewhere)
    for k in distractors:
        spot = next(s for s in spare if not s[2] or k.height <= fits)
        spare.remove(spot)
        out.append(Placement(k, *spot, target=False))
    return out


def _goal_area(layout: Layout) -> tuple[float, float, float, float]:
    return layout.goal_area


# --------------------------------------------------------------------------- Pack Objects

PACK_POOL = (
    _kind("apple", "sphere", (0.04, 0.04, 0.08), (0.8, 0.1, 0.1, 1)),
    _kind("fork", "box", (0.17, 0.03, 0.02), (0.7, 0.7, 0.72, 1)),
    _kind("soap", "box", (0.09, 0.06, 0.035), (0.6, 0.85, 0.95, 1)),
    _kind("toy_duck", "sphere", (0.045, 0.045, 0.09), (0.95, 0.85, 0.1, 1)),
    _kind("phone", "box", (0.15, 0.075, 0.015), (0.1, 0.1, 0.1, 1)),
    _kind("bottle", "cylinder", (0.035, 0.035, 0.2), (0.1, 0.6, 0.3, 1)),
    _kind("book", "box", (0.16, 0.11, 0.03), (0.5, 0.2, 0.1, 1)),
    _kind("mug", "cylinder", (0.04, 0.04, 0.1), (0.95, 0.95, 0.95, 1)),
    _kind("banana", "box", (0.16, 0.04, 0.04), (0.95, 0.9, 0.3, 1)),
    _kind("sponge", "box", (0.1, 0.07, 0.04), (0.95, 0.6, 0.2, 1)),
)


@register_task
class PackObjects:
    """Pack Objects: put each listed object into the tray on Bob's table.

    Randomized by the seed: which 3-6 objects are targets and where they lie (see `scatter`),
    and one or two distractors (not on the list). Success: every target lies in the tray and
    nothing else does; partial success is the fraction of targets in the tray.
    """

    id = "pack_objects"
    things = "objects"
    ordered = False

    def generate(self, layout: Layout, seed: int, n_objects: int) -> list[Placement]:
        rng = _rng(seed)
        n_distractors = 1 + int(rng.integers(0, 2))
        kinds = [PACK_POOL[i] for i in rng.permutation(len(PACK_POOL))[: n_objects + n_distractors]]
        return scatter(layout, rng, kinds[:n_objects], kinds[n_objects:])

    def target_kinds(self) -> list[ObjectKind]:
        return list(PACK_POOL)

    def object_names(self) -> set[str]:
        return {k.name for k in PACK_POOL}  # distractors come from the same pool

    def fixtures(self, layout: Layout) -> list[Fixture]:
        cx, cy, sx, sy = _goal_area(layout)
        return [Fixture("tray", "tray", (cx, cy), (sx, sy), (0.2, 0.3, 0.6, 1.0), thickness=0.01, rim=True)]

    def goal(self, kind: ObjectKind) -> str:
        return "tray"

    def evaluate(self, targets: list[str], objects: list[Seen]) -> TaskResult:
        in_tray = {o.name for o in objects if o.on == "tray"}
        placed = sum(1 for t in targets if t in in_tray)
        return TaskResult(success=placed == len(targets) and in_tray <= set(targets), placed=placed, total=len(targets))

    def status(self, targets: list[str], objects: list[Seen], aids: frozenset[str] = frozenset()) -> str:
        in_tray = [o.name for o in objects if o.on == "tray"]
        parts = [f"In the tray: {_names(in_tray)}."]
        if "status_hints" not in aids:
            return parts[0]
        missing = [t for t in targets if t not in in_tray]
        wrong = [n for n in in_tray if n not in targets]
        parts.append(
            f"Not yet in the tray: {', '.join(missing)}." if missing else "Every listed object is in the tray."
        )
        if wrong:
            parts.append(f"In the tray but not on the list (take it out): {', '.join(wrong)}.")
        return " ".join(parts)

    def finisher_brief(self) -> str:
        return "Put the listed objects into the tray."

    def finisher_detail(
        self, b: Briefing, targets: list[str], goals: dict[str, str], aids: frozenset[str] = frozenset()
    ) -> str:
        return (
            f"Put every object on the list into the tray on {b.table}. {ask(b, self.things)} "
            f"The list: {', '.join(targets)}. Nothing that is not on the list goes into the tray."
        )


# --------------------------------------------------------------------------- Sort Solids

PANEL_SIZE, PANEL_PITCH = 0.1, 0.12
SOLIDS: dict[str, tuple[str, tuple[float, float, float]]] = {
    "cube": ("box", (0.05, 0.05, 0.05)),
    "cylinder": ("cylinder", (0.025, 0.025, 0.06)),
    "prism": ("prism", (0.06, 0.05, 0.045)),
    "cuboid": ("box", (0.07, 0.04, 0.035)),
}


def solid_kind(color: str, shape: str, palette: dict[str, Color]) -> ObjectKind:
    prim, size = SOLIDS[shape]
    return _kind(f"{color}_{shape}", prim, size, palette[color], group=color)


@register_task
class SortSolids:
    """Sort Solids: place each coloured solid on the panel of its colour on Bob's table.

    The six panels (red, blue, pink, green, yellow, purple) lie in Bob's reach. Randomized by
    the seed: 3-6 target solids of distinct colours and random shapes (cube, cylinder, prism,
    cuboid) placed as `scatter` says, and one or two distractor solids in colours that have no
    panel (orange, white). Success: every target on its panel and nothing else on any panel;
    partial success is the fraction of targets on their panel.
    """

    id = "sort_solids"
    things = "solids"
    ordered = False

    def generate(self, layout: Layout, seed: int, n_objects: int) -> list[Placement]:
        rng = _rng(seed)
        shapes = list(SOLIDS)
        colors = [list(PANEL_COLORS)[i] for i in rng.permutation(len(PANEL_COLORS))[:n_objects]]
        targets = [solid_kind(c, shapes[int(rng.integers(0, len(shapes)))], PANEL_COLORS) for c in colors]
        n_distractors = 1 + int(rng.integers(0, 2))
        distractors = [
            solid_kind(c, shapes[int(rng.integers(0, len(shapes)))], NO_PANEL_COLORS)
            for c in list(NO_PANEL_COLORS)[:n_distractors]
        ]
        return scatter(layout, rng, targets, distractors)

    def target_kinds(self) -> list[ObjectKind]:
        return [solid_kind(c, s, PANEL_COLORS) for c in PANEL_COLORS for s in SOLIDS]

    def object_names(self) -> set[str]:
        return {k.name for k in self.target_kinds()} | {f"{c}_{s}" for c in NO_PANEL_COLORS for s in SOLIDS}

    def fixtures(self, layout: Layout) -> list[Fixture]:
        """Six 10 cm panels, 3 x 2 at a 12 cm pitch, centred in the goal area."""
        cx, cy, _, _ = _goal_area(layout)
        out = []
        for i, (name, color) in enumerate(PANEL_COLORS.items()):
            c, r = i % 3, i // 3
            center = (round(cx + (c - 1) * PANEL_PITCH, 4), round(cy + (0.5 - r) * PANEL_PITCH, 4))
            out.append(
                Fixture(f"{name}_panel", f"{name} panel", center, (PANEL_SIZE, PANEL_SIZE), color, thickness=0.008)
            )
        return out

    def goal(self, kind: ObjectKind) -> str:
        return f"{kind.group}_panel"

    def evaluate(self, targets: list[str], objects: list[Seen]) -> TaskResult:
        by_name = {o.name: o for o in objects}
        placed = sum(1 for t in targets if t in by_name and by_name[t].on == self.goal(by_name[t].kind))
        stray = [o for o in objects if o.on is not None and o.on.endswith("_panel") and o.name not in targets]
        return TaskResult(success=placed == len(targets) and not stray, placed=placed, total=len(targets))

    def status(self, targets: list[str], objects: list[Seen], aids: frozenset[str] = frozenset()) -> str:
        on_panels = [o for o in objects if o.on is not None and o.on.endswith("_panel")]
        if "status_hints" not in aids:  # the paper's: which solid lies on which panel, nothing judged
            return f"On the panels: {_names([f'{o.name} on {o.on}' for o in on_panels])}."
        right = [f"{o.name} on {o.on}" for o in on_panels if o.name in targets and o.on == self.goal(o.kind)]
        wrong = [f"{o.name} on {o.on}" for o in on_panels if not (o.name in targets and o.on == self.goal(o.kind))]
        done = {o.name for o in on_panels if o.name in targets and o.on == self.goal(o.kind)}
        missing = [t for t in targets if t not in done]
        parts = [f"Sorted: {_names(right)}."]
        parts.append(f"Not yet sorted: {', '.join(missing)}." if missing else "Every listed solid is on its panel.")
        if wrong:
            parts.append(f"On a wrong panel (move it): {', '.join(wrong)}.")
        return " ".join(parts)

    def finisher_brief(self) -> str:
        return "Put each listed solid on the panel of its colour."

    def finisher_detail(
        self, b: Briefing, targets: list[str], goals: dict[str, str], aids: frozenset[str] = frozenset()
    ) -> str:
        if "goal_map" in aids:
            listed = ", ".join(f"{t} onto {goals[t]}" for t in targets)
        else:  # the paper's: the solids and the panels; matching the colours is the finisher's job
            listed = f"{', '.join(targets)}; the colour panels: {', '.join(f'{c}_panel' for c in PANEL_COLORS)}"
        return (
            f"Put every solid on the list on the panel of its colour on {b.table}. {ask(b, self.things)} "
            f"The list: {listed}. Nothing that is not on the list goes onto a panel."
        )


# --------------------------------------------------------------------------- Make Sandwich

INGREDIENTS: dict[str, tuple[str, tuple[float, float, float], Color]] = {
    "bread_slice": ("box", (0.1, 0.1, 0.02), (0.9, 0.75, 0.45, 1)),
    "ham": ("box", (0.09, 0.09, 0.01), (0.95, 0.55, 0.6, 1)),
    "bacon": ("box", (0.11, 0.035, 0.01), (0.7, 0.25, 0.2, 1)),
    "tomato": ("cylinder", (0.035, 0.035, 0.015), (0.9, 0.15, 0.1, 1)),
    "cucumber": ("cylinder", (0.028, 0.028, 0.012), (0.35, 0.7, 0.25, 1)),
    "cheese": ("box", (0.085, 0.085, 0.01), (1.0, 0.85, 0.2, 1)),
    "beef_patty": ("cylinder", (0.045, 0.045, 0.02), (0.4, 0.22, 0.12, 1)),
}
MENUS: dict[str, tuple[str, ...]] = {  # bottom to top
    "cheese toast": ("bread_slice", "cheese", "tomato"),
    "ham open sandwich": ("bread_slice", "ham", "cucumber"),
    "ham and cheese": ("bread_slice", "ham", "cheese", "bread_slice"),
    "veggie": ("bread_slice", "tomato", "cucumber", "bread_slice"),
    "BLT": ("bread_slice", "bacon", "cucumber", "tomato", "bread_slice"),
    "club": ("bread_slice", "ham", "cheese", "tomato", "bread_slice"),
    "burger": ("bread_slice", "beef_patty", "cheese", "tomato", "cucumber", "bread_slice"),
    "deluxe": ("bread_slice", "ham", "bacon", "cheese", "tomato", "bread_slice"),
}


def ingredient_kind(kind: str, name: str) -> ObjectKind:
    shape, size, color = INGREDIENTS[kind]
    return _kind(name, shape, size, color, group=kind)


@register_task
class MakeSandwich:
    """Make Sandwich: stack the menu's ingredients on the cutting board, bottom to top.

    Randomized by the seed: a menu with as many ingredients as objects asked for (each length
    3-6 has two menus), where they lie (see `scatter`), and one or two distractor ingredients
    the menu does not use. Success: the stack on the board is exactly the menu, in order;
    partial success is the length of the stack's correct prefix over the menu's length.
    """

    id = "make_sandwich"
    things = "ingredients"
    ordered = True

    def menu(self, n_objects: int, rng: np.random.Generator) -> tuple[str, tuple[str, ...]]:
        names = [m for m, items in MENUS.items() if len(items) == n_objects]
        name = names[int(rng.integers(0, len(names)))]
        return name, MENUS[name]

    def generate(self, layout: Layout, seed: int, n_objects: int) -> list[Placement]:
        rng = _rng(seed)
        _, items = self.menu(n_objects, rng)
        seen: dict[str, int] = {}
        targets = []
        for kind in items:
            seen[kind] = seen.get(kind, 0) + 1
            name = f"{kind}_{seen[kind]}" if items.count(kind) > 1 else kind
            targets.append(ingredient_kind(kind, name))
        unused = [k for k in INGREDIENTS if k not in items]
        n_distractors = min(len(unused), 1 + int(rng.integers(0, 2)))
        distractors = [
            ingredient_kind(unused[i], unused[i]) for i in sorted(rng.permutation(len(unused))[:n_distractors])
        ]
        return scatter(layout, rng, targets, distractors)

    def target_kinds(self) -> list[ObjectKind]:
        return [ingredient_kind(k, k) for k in INGREDIENTS]

    def object_names(self) -> set[str]:  # a menu's repeated ingredient is numbered: bread_slice_1, bread_slice_2
        return set(INGREDIENTS) | {f"{k}_{i}" for k in INGREDIENTS for i in (1, 2)}

    def fixtures(self, layout: Layout) -> list[Fixture]:
        cx, cy, _, _ = _goal_area(layout)
        return [
            Fixture(
                "cutting_board",
                "cutting board",
                (cx, cy),
                (0.24, 0.2),
                (0.75, 0.55, 0.3, 1.0),
                thickness=0.02,
                stack=True,
            )
        ]

    def goal(self, kind: ObjectKind) -> str:
        return "cutting_board"

    @staticmethod
    def _stack(objects: list[Seen]) -> list[Seen]:
        return sorted((o for o in objects if o.on == "cutting_board"), key=lambda o: o.z)

    def _correct_prefix(self, targets: list[str], objects: list[Seen]) -> int:
        kinds = {o.name: o.kind.group for o in objects}
        menu = [kinds.get(t, t) for t in targets]
        n = 0
        for o, want in zip(self._stack(objects), menu):
            if o.kind.group != want:
                break
            n += 1
        return n

    def evaluate(self, targets: list[str], objects: list[Seen]) -> TaskResult:
        placed = self._correct_prefix(targets, objects)
        stack = self._stack(objects)
        return TaskResult(
            success=placed == len(targets) and len(stack) == len(targets), placed=placed, total=len(targets)
        )

    def status(self, targets: list[str], objects: list[Seen], aids: frozenset[str] = frozenset()) -> str:
        stack = self._stack(objects)
        parts = [f"On the cutting board, bottom to top: {_names([o.name for o in stack])}."]
        if "status_hints" not in aids:
            return parts[0]
        good = self._correct_prefix(targets, objects)
        if good < len(stack):
            parts.append(f"Wrong from {stack[good].name} up (take those off).")
        elif good < len(targets):
            parts.append(
                f"Next: {targets[good]}; still to stack after it: {_names(targets[good + 1 :]) if good + 1 < len(targets) else 'nothing'}."
            )
        else:
            parts.append("The sandwich is complete.")
        return " ".join(parts)

    def finisher_brief(self) -> str:
        return "Make the sandwich on the menu on the cutting board."

    def finisher_detail(
        self, b: Briefing, targets: list[str], goals: dict[str, str], aids: frozenset[str] = frozenset()
    ) -> str:
        return (
            f"Stack the menu's ingredients on the cutting board on {b.table}, bottom to top in the menu's order. {ask(b, self.things)} "
            f"The menu, bottom to top: {', '.join(targets)}. Nothing that is not on the menu goes onto the board."
        )
