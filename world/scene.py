"""Scene layouts as data: walls, furniture (boxes, one may hold a drawer), stand poses, place
poses and the object slots the task generators fill.

A layout is a `Layout` value; `LAYOUTS` maps names to them, so a new layout is new data, not
a new code path. Coordinates are metres in the world frame; furniture is axis-aligned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

STAND_OFFSET = 0.45  # base centre to furniture edge at a stand pose
HALF_PI = math.pi / 2


@dataclass(frozen=True)
class DrawerSpec:
    """A drawer sliding out of its furniture along `axis` (unit x/y vector) by `travel`."""

    axis: tuple[float, float]
    travel: float
    size: tuple[float, float, float]  # inner box: sx, sy, wall height
    bottom: float  # z of the drawer's floor
    slots: tuple[tuple[float, float], ...]  # object spots, relative to the drawer's closed centre


@dataclass(frozen=True)
class FurnitureSpec:
    name: str
    kind: str
    center: tuple[float, float]
    size: tuple[float, float, float]  # sx, sy, height
    color: tuple[float, float, float, float]
    stand_poses: tuple[tuple[float, float, float], ...] = ()
    place_pose: tuple[float, float] | None = None
    slots: tuple[tuple[float, float], ...] = ()  # object spots on top, absolute x, y
    drawer: DrawerSpec | None = None

    @property
    def top(self) -> float:
        return self.size[2]

    def contains_xy(self, x: float, y: float, margin: float = 0.0) -> bool:
        return abs(x - self.center[0]) <= self.size[0] / 2 + margin and abs(y - self.center[1]) <= self.size[1] / 2 + margin


@dataclass(frozen=True)
class Layout:
    name: str
    description: str
    bounds: tuple[float, float, float, float]  # xmin, xmax, ymin, ymax
    walls: tuple[tuple[float, float, float, float], ...]  # centre x, y, size x, y
    furniture: tuple[FurnitureSpec, ...]
    bob_base: tuple[float, float, float]  # Bob's arm base on table_0
    bob_yaw: float
    tray: tuple[float, float, float]  # centre x, y and side length, on table_0
    near_slots: tuple[tuple[float, float], ...]  # on table_0 within Bob's reach
    far_slots: tuple[tuple[float, float], ...]  # on table_0 beyond Bob's reach
    starts: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    def get(self, name: str) -> FurnitureSpec | None:
        return next((f for f in self.furniture if f.name == name), None)


def _south(x: float, f_y: float, sy: float) -> tuple[float, float, float]:
    return (x, f_y - sy / 2 - STAND_OFFSET, HALF_PI)


def _north(x: float, f_y: float, sy: float) -> tuple[float, float, float]:
    return (x, f_y + sy / 2 + STAND_OFFSET, -HALF_PI)


def _west(y: float, f_x: float, sx: float) -> tuple[float, float, float]:
    return (f_x - sx / 2 - STAND_OFFSET, y, 0.0)


WOOD = (0.55, 0.4, 0.25, 1.0)
LIGHT = (0.8, 0.75, 0.65, 1.0)

HOUSE = Layout(
    name="house",
    description="a 10 x 8 m house: kitchen with table_0 and a drawer unit to the west, living room and study to the east",
    bounds=(-5.0, 5.0, -4.0, 4.0),
    walls=(
        (0.0, -4.0, 10.2, 0.1),
        (0.0, 4.0, 10.2, 0.1),
        (-5.0, 0.0, 0.1, 8.2),
        (5.0, 0.0, 0.1, 8.2),
        (0.5, -2.3, 0.1, 3.4),  # interior wall with a 1.2 m doorway around y = 0
        (0.5, 2.3, 0.1, 3.4),
        (2.2, 0.0, 1.0, 0.1),  # partition between living room and study, open to the east
    ),
    furniture=(
        FurnitureSpec(
            "table_0", "table", (-3.0, 0.0), (1.6, 0.7, 0.7), WOOD,
            stand_poses=(_south(-3.2, 0.0, 0.7), _south(-2.5, 0.0, 0.7), _north(-2.5, 0.0, 0.7)),
            place_pose=(-3.12, -0.08),
        ),
        FurnitureSpec(
            "drawer_unit", "drawer unit", (-3.0, 3.5), (1.0, 0.8, 0.6), LIGHT,
            stand_poses=((-3.0, 3.1 - 0.45 - STAND_OFFSET, HALF_PI),),
            drawer=DrawerSpec(axis=(0.0, -1.0), travel=0.45, size=(0.8, 0.7, 0.17), bottom=0.36,
                              slots=((-0.25, -0.22), (0.0, -0.22), (0.25, -0.22))),
        ),
        FurnitureSpec(
            "counter", "counter", (-1.0, -3.5), (1.4, 0.6, 0.8), LIGHT,
            stand_poses=(_north(-1.3, -3.5, 0.6), _north(-0.7, -3.5, 0.6)),
            place_pose=(-1.0, -3.45),
            slots=((-1.35, -3.45), (-1.0, -3.4), (-0.65, -3.45)),
        ),
        FurnitureSpec(
            "table_1", "table", (2.5, 2.5), (1.2, 0.7, 0.7), WOOD,
            stand_poses=(_south(2.2, 2.5, 0.7), _south(2.8, 2.5, 0.7)),
            place_pose=(2.5, 2.45),
            slots=((2.15, 2.42), (2.5, 2.4), (2.85, 2.42)),
        ),
        FurnitureSpec(
            "table_2", "table", (2.5, -2.8), (1.2, 0.7, 0.7), WOOD,
            stand_poses=(_north(2.2, -2.8, 0.7), _north(2.8, -2.8, 0.7)),
            place_pose=(2.5, -2.75),
            slots=((2.15, -2.72), (2.5, -2.7), (2.85, -2.72)),
        ),
        FurnitureSpec(
            "sofa", "sofa", (4.2, -0.5), (0.8, 1.8, 0.45), (0.3, 0.35, 0.6, 1.0),
            stand_poses=(_west(-0.9, 4.2, 0.8), _west(0.0, 4.2, 0.8)),
            place_pose=(4.05, -0.5),
            slots=((4.0, -1.0), (4.0, -0.5), (4.0, 0.0)),
        ),
    ),  # fmt: skip
    bob_base=(-3.7, 0.0, 0.7),
    bob_yaw=0.0,
    tray=(-3.35, 0.2, 0.4),
    near_slots=((-3.48, -0.18), (-3.25, -0.24)),
    far_slots=((-2.55, -0.15), (-2.33, -0.05), (-2.6, 0.08)),
    starts={"alice": (-1.5, 1.2, 0.0), "david": (4.0, 3.0, math.pi)},
)

LAYOUTS: dict[str, Layout] = {HOUSE.name: HOUSE}


def get_layout(name: str) -> Layout:
    try:
        return LAYOUTS[name]
    except KeyError:
        raise ValueError(f"unknown scene {name!r}; known scenes: {', '.join(LAYOUTS)}") from None
