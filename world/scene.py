"""The builder that turns a layout (`layouts.py`, loaded from `scenes/*.json`) and a task's
fixtures into PyBullet bodies and the base planners' occupancy grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import pybullet_data

from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from . import assets
from .assets import AssetDir
from .astar import Grid
from .furniture import DrawerSpec, Fixture, FurnitureSpec, Layout
from .layouts import LAYOUTS, LayoutError, get_layout, load_layout
from .occupancy import occupancy

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
