"""The builder that turns a layout (`layouts.py`, loaded from `scenes/*.json`) and a task's
fixtures into PyBullet bodies and the base planners' occupancy grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet_data

from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from . import assets
from .assets import AssetDir, Color
from .astar import Grid
from .furniture import DrawerSpec, FurnitureSpec, Layout, door_sweep
from .layouts import LAYOUTS, LayoutError, get_layout, load_layout

__all__ = ["LAYOUTS", "DrawerSpec", "FurnitureSpec", "Layout", "LayoutError", "get_layout", "load_layout"]

WALL_HEIGHT = 1.0


# --------------------------------------------------------------------------- building


@dataclass(frozen=True)
class StaticBody:
    """A fixed body by file and pose, so a planning client can load the same thing."""

    name: str
    path: str
    position: tuple[float, float, float]
    yaw: float = 0.0


@dataclass
class BuiltScene:
    """The bodies of a built layout in one client."""

    statics: list[StaticBody]
    bodies: dict[str, int]  # static name -> body id
    joints: dict[
        str, int
    ]  # container name -> the joint that opens it (a drawer's prismatic, a lid's or door's revolute)
    grid: Grid
    air: Grid | None = None  # fliers' grid: walls only (built when the team has a flier)


@dataclass(frozen=True)
class Fixture:
    """A goal surface a task lays on Bob's table: the tray, a coloured panel, the cutting board."""

    name: str
    kind: str  # how observations describe it
    center: tuple[float, float]
    size: tuple[float, float]
    color: Color
    thickness: float  # its surface above the table top
    rim: bool = False  # a tray's low walls
    stack: bool = False  # objects go on top of each other at its centre

    def contains_xy(self, x: float, y: float, margin: float = 0.0) -> bool:
        return (
            abs(x - self.center[0]) <= self.size[0] / 2 + margin
            and abs(y - self.center[1]) <= self.size[1] / 2 + margin
        )


def scene_statics(
    layout: Layout, assets_dir: AssetDir, fixtures: list[Fixture] | tuple[Fixture, ...] = ()
) -> list[StaticBody]:
    """Write the layout's URDFs and list every fixed body (walls, furniture, the task's fixtures)."""
    out: list[StaticBody] = []
    wall_color = (0.9, 0.9, 0.88, 1.0)
    for i, (cx, cy, sx, sy) in enumerate(layout.walls):
        path = assets_dir.write(
            f"wall_{i}", assets.link_urdf(f"wall_{i}", assets.wall_boxes((sx, sy, WALL_HEIGHT), wall_color))
        )
        out.append(StaticBody(f"wall_{i}", path, (cx, cy, 0.0)))
    for f in layout.furniture:
        width, depth = f.own_size()
        facade = assets.facade_boxes(depth, f.panels)  # in the body's own frame, front along -y
        if f.style == "drawer_unit":
            urdf = assets.drawer_unit_urdf(f.name, f.drawer_geometry(), f.color, facade)
        elif f.style == "chest":
            urdf = assets.chest_urdf(f.name, f.chest_geometry(), f.color, facade)
        elif f.style == "cupboard":
            urdf = assets.cupboard_urdf(f.name, f.cupboard_geometry(), f.color, facade)
        elif f.style == "table":
            urdf = assets.link_urdf(f.name, assets.table_boxes(f.size, f.color))
        elif f.style == "sofa":
            urdf = assets.link_urdf(f.name, assets.sofa_boxes(f.size, f.color))
        elif f.style == "block":
            urdf = assets.link_urdf(f.name, assets.block_boxes((width, depth, f.top), f.color) + facade)
        else:
            raise ValueError(f"{f.name}: unknown furniture style {f.style!r}")
        out.append(StaticBody(f.name, assets_dir.write(f.name, urdf), (f.center[0], f.center[1], 0.0), f.yaw))
    top = _require(layout, layout.bob_table).top
    for fx in fixtures:
        boxes = (
            assets.tray_boxes(*fx.size, fx.color, t=fx.thickness)
            if fx.rim
            else assets.slab_boxes(*fx.size, fx.thickness, fx.color)
        )
        path = assets_dir.write(fx.name, assets.link_urdf(fx.name, boxes))
        out.append(StaticBody(fx.name, path, (fx.center[0], fx.center[1], top)))
    return out


def load_statics(cid: int, statics: list[StaticBody]) -> dict[str, int]:
    bodies = {}
    for s in statics:
        orn = p.getQuaternionFromEuler((0.0, 0.0, s.yaw))
        bodies[s.name] = p.loadURDF(s.path, s.position, orn, useFixedBase=True, physicsClientId=cid)
    return bodies


def occupancy(layout: Layout, margin: float, res: float = 0.05, *, furniture: bool = True) -> Grid:
    """Walls and furniture footprints (open drawers and the floor doors sweep included) grown by
    `margin`. Without `furniture`, the walls alone: the air a flier plans in (it passes over
    furniture; walls reach the ceiling)."""
    xmin, xmax, ymin, ymax = layout.bounds
    grid = Grid.empty(xmin, xmax, ymin, ymax, res)
    for cx, cy, sx, sy in layout.walls:
        grid.add_box(cx, cy, sx, sy, margin=margin)
    for f in layout.furniture if furniture else ():
        extra = 0.15 if f.style == "sofa" else 0.0  # the backrest
        grid.add_box(f.center[0] + extra / 2, f.center[1], f.size[0] + extra, f.size[1], margin=margin)
        footprint = f.open_drawer_footprint()
        if footprint is not None:  # the drawer may stand open: its footprint is never free floor
            (cx, cy), (sx, sy) = footprint
            grid.add_box(cx, cy, sx, sy, margin=margin)
        if f.door is not None:  # nor is the floor a door sweeps
            for (cx, cy), (sx, sy), yaw in door_sweep(f.center, f.size, f.door):
                _block_near(grid, (cx, cy), (sx, sy), yaw, margin)
    return grid


def _block_near(grid: Grid, center: tuple[float, float], size: tuple[float, float], yaw: float, margin: float) -> None:
    """Block the cells within `margin` (straight-line distance) of a turned rectangle: rounded
    corners, unlike `Grid.add_box`'s grown rectangle, which would block floor a base can use
    beside a door swung half open."""
    reach = math.hypot(*size) / 2 + margin
    i0, j0 = grid.cell(center[0] - reach, center[1] - reach)
    i1, j1 = grid.cell(center[0] + reach, center[1] + reach)
    i0, j0 = max(i0, 0), max(j0, 0)
    i1, j1 = min(i1 + 1, grid.blocked.shape[0]), min(j1 + 1, grid.blocked.shape[1])
    if i0 >= i1 or j0 >= j1:
        return
    xs = grid.x0 + (np.arange(i0, i1) + 0.5) * grid.res - center[0]
    ys = grid.y0 + (np.arange(j0, j1) + 0.5) * grid.res - center[1]
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    c, s = math.cos(yaw), math.sin(yaw)
    ox = np.maximum(np.abs(c * gx + s * gy) - size[0] / 2, 0.0)
    oy = np.maximum(np.abs(-s * gx + c * gy) - size[1] / 2, 0.0)
    grid.blocked[i0:i1, j0:j1] |= np.hypot(ox, oy) <= margin


def build_scene(
    cid: int,
    layout: Layout,
    assets_dir: AssetDir,
    margin: float,
    fixtures: list[Fixture] | tuple[Fixture, ...] = (),
    air_margin: float | None = None,
) -> BuiltScene:
    """Floor, walls, furniture and the task's fixtures in client `cid`, the ground bases' occupancy
    grid (grown by `margin`) and, given `air_margin`, the fliers' (walls only, grown by it)."""
    p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
    p.loadURDF("plane.urdf", physicsClientId=cid)
    statics = scene_statics(layout, assets_dir, fixtures)
    bodies = load_statics(cid, statics)
    joints: dict[str, int] = {}
    for f in layout.furniture:
        if f.container is not None:
            body = bodies[f.name]
            joints[f.name] = next(
                j
                for j in range(p.getNumJoints(body, physicsClientId=cid))
                if p.getJointInfo(body, j, physicsClientId=cid)[2] in (p.JOINT_PRISMATIC, p.JOINT_REVOLUTE)
            )
            p.setJointMotorControl2(body, joints[f.name], p.VELOCITY_CONTROL, force=0.0, physicsClientId=cid)
    air = None if air_margin is None else occupancy(layout, air_margin, furniture=False)
    return BuiltScene(statics, bodies, joints, occupancy(layout, margin), air)


def _require(layout: Layout, name: str) -> FurnitureSpec:
    f = layout.get(name)
    if f is None:
        raise ValueError(f"layout {layout.name!r} has no furniture {name!r}")
    return f
