"""The house and the robots' bodies as Rerun entities: walls, furniture and the goal area as boxes
(the layout the trace's episode_started names, mhrc.world.layouts), each robot as a few boxes of its
kind (mhrc.world.robots: the sizes the simulator builds, simplified; a drone at its flight altitude).

Coordinates are the world's: metres, z up, the floor at z = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import rerun as rr

from mhrc.world.kinds import CHASSIS, CHASSIS_COLOR, DRONE_COLOR, KINDS, flight_altitude
from mhrc.world.layouts import Layout

WALL_HEIGHT = 1.0  # m (world/layouts.py: walls are 1 m high)
WALL_COLOR = (170, 170, 170, 255)
GOAL_COLOR = (60, 180, 75, 120)
OPEN_COLOR = (240, 200, 40, 160)  # an open container's drawer footprint
ARM_COLOR = (230, 230, 230, 255)
BASE_COLOR = (70, 110, 200, 255)  # a mobile base without an arm (the paper's David)


def _rgba(color: tuple[float, ...]) -> tuple[int, int, int, int]:
    return (
        int(color[0] * 255),
        int(color[1] * 255),
        int(color[2] * 255),
        int((color[3] if len(color) > 3 else 1.0) * 255),
    )


def log_house(rec: rr.RecordingStream, layout: Layout) -> None:
    """The layout's walls, furniture (one entity each, so that a container's state can change) and goal area, static."""
    rec.log(
        "world/walls",
        rr.Boxes3D(
            centers=[(w[0], w[1], WALL_HEIGHT / 2) for w in layout.walls],
            sizes=[(w[2], w[3], WALL_HEIGHT) for w in layout.walls],
            colors=[WALL_COLOR] * len(layout.walls),
            fill_mode="solid",
        ),
        static=True,
    )
    for f in layout.furniture:
        rec.log(
            f"world/furniture/{f.name}",
            rr.Boxes3D(
                centers=[(f.center[0], f.center[1], f.size[2] / 2)],
                sizes=[f.size],
                colors=[_rgba(f.color)],
                labels=[f.name],
                fill_mode="solid",
            ),
            static=True,
        )
    gx, gy, sx, sy = layout.goal_area
    rec.log(
        "world/goal_area",
        rr.Boxes3D(centers=[(gx, gy, 0.01)], sizes=[(sx, sy, 0.02)], colors=[GOAL_COLOR], labels=["goal area"]),
        static=True,
    )


def log_open(rec: rr.RecordingStream, layout: Layout, name: str, is_open: bool) -> None:
    """An openable piece's state (at the current time): its open drawer's floor as a box, its label saying open/closed."""
    furniture = next((f for f in layout.furniture if f.name == name), None)
    if furniture is None:
        return
    path = f"world/furniture/{name}/state"
    footprint = furniture.open_drawer_footprint()
    if is_open and footprint is not None:
        (cx, cy), (sx, sy) = footprint
        center, size = (cx, cy, furniture.size[2] / 2), (sx, sy, furniture.size[2] * 0.6)
    else:  # a door, a lid, or a closed drawer: a thin marker on top saying its state
        center = (furniture.center[0], furniture.center[1], furniture.size[2] + 0.02)
        size = (furniture.size[0] * 0.5, furniture.size[1] * 0.5, 0.02)
    rec.log(
        path,
        rr.Boxes3D(
            centers=[center],
            sizes=[size],
            colors=[OPEN_COLOR if is_open else (90, 90, 90, 200)],
            labels=[f"{name} open" if is_open else ""],  # a closed one's marker says it without a label on every piece
        ),
    )


@dataclass(frozen=True)
class Body:
    """A robot's simple body: boxes in its own frame (x forward, z up), and the height its frame rides at."""

    centers: list[tuple[float, float, float]]
    sizes: list[tuple[float, float, float]]
    colors: list[tuple[int, int, int, int]]
    z: float = 0.0


def body_of(kind: str, layout: Layout | None) -> Body:
    """An honest simple body for a robot `kind`: the chassis and an upright arm, a fixed arm's column, a
    wheeled base, a drone's frame and rotors at its flight altitude; an unknown kind, a marker box."""
    spec = KINDS.get(kind)
    if spec is None:
        return Body([(0.0, 0.0, 0.25)], [(0.4, 0.4, 0.5)], [(200, 200, 200, 255)])
    if spec.flies:
        tallest = max((f.size[2] for f in layout.furniture), default=0.0) if layout is not None else 0.0
        arm = 0.16  # rotor arms: tip to tip about 0.46 m
        rotors = [(arm * math.cos(a), arm * math.sin(a), 0.03) for a in (0.785, 2.356, 3.927, 5.498)]
        return Body(
            [(0.0, 0.0, 0.0), *rotors],
            [(0.2, 0.2, 0.06)] + [(0.14, 0.14, 0.01)] * 4,
            [_rgba(DRONE_COLOR)] + [(40, 40, 40, 255)] * 4,
            z=flight_altitude(spec, tallest),
        )
    if spec.mobile and spec.has_arm:
        length, width, height = CHASSIS
        return Body(
            [(0.0, 0.0, height / 2), (0.2, 0.0, height + 0.45)],
            [(length, width, height), (0.12, 0.12, 0.9)],
            [_rgba(CHASSIS_COLOR), ARM_COLOR],
        )
    if spec.has_arm:  # a fixed arm on its table: the column rises from the arm base (its pose's z is the table's)
        table = layout.bob_base[2] if layout is not None else 0.0
        return Body([(0.0, 0.0, 0.45)], [(0.14, 0.14, 0.9)], [ARM_COLOR], z=table)
    return Body([(0.0, 0.0, 0.3)], [(0.45, 0.45, 0.6)], [BASE_COLOR])


def log_body(rec: rr.RecordingStream, robot: str, body: Body) -> None:
    """A robot's body, static, under its entity: its pose moves it (mhrc.viewer.rerun.episode)."""
    rec.log(
        f"world/robots/{robot}/body",
        rr.Boxes3D(
            centers=body.centers,
            sizes=body.sizes,
            colors=body.colors,
            fill_mode="solid",
            labels=[robot] + [""] * (len(body.centers) - 1),
        ),
        static=True,
    )
