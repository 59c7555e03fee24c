"""Scene layouts as data (walls, furniture, stand poses, place poses, drawers, object slots)
and the builder that turns one into PyBullet bodies and an occupancy grid.

A layout is a `Layout` value and `LAYOUTS` maps names to them, so a new layout is new data,
not a new code path. Coordinates are metres in the world frame; furniture is axis-aligned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pybullet as p
import pybullet_data

from . import assets
from .assets import AssetDir, Color, DrawerGeometry
from .astar import Grid

STAND_OFFSET = 0.45  # base centre to furniture edge at a stand pose
HALF_PI = math.pi / 2
WALL_HEIGHT = 1.0


@dataclass(frozen=True)
class DrawerSpec:
    """A drawer sliding out of its unit's front along `axis` (a unit x/y vector) by `travel`."""

    axis: tuple[float, float]
    travel: float
    inner: tuple[float, float, float]  # inside of the drawer: width, depth, wall height
    floor: float  # z of the drawer's floor surface
    slots: tuple[tuple[float, float], ...]  # object spots in the drawer frame (x across, y towards the back)
    max_object_height: float = 0.12


@dataclass(frozen=True)
class FurnitureSpec:
    name: str
    kind: str
    style: str  # table | block | sofa | drawer_unit: how assets.py builds it
    center: tuple[float, float]
    size: tuple[float, float, float]  # sx, sy, height (of the top surface)
    color: Color
    stand_poses: tuple[tuple[float, float, float], ...] = ()
    place_pose: tuple[float, float] | None = None
    place_radius: float = 0.3  # free spots for `place` are searched this far from the place pose
    slots: tuple[tuple[float, float], ...] = ()  # object spots on top, absolute x, y
    drawer: DrawerSpec | None = None

    @property
    def top(self) -> float:
        return self.size[2]

    @property
    def yaw(self) -> float:
        """Body yaw: drawer units are built with their front along -y of their own frame."""
        if self.drawer is None:
            return 0.0
        ax, ay = self.drawer.axis
        return math.atan2(ay, ax) + HALF_PI

    def contains_xy(self, x: float, y: float, margin: float = 0.0) -> bool:
        return abs(x - self.center[0]) <= self.size[0] / 2 + margin and abs(y - self.center[1]) <= self.size[1] / 2 + margin

    @property
    def container(self) -> DrawerSpec | None:
        """What makes this furniture a closed container (its drawer), if anything."""
        return self.drawer

    def drawer_geometry(self) -> DrawerGeometry:
        d = self.drawer
        assert d is not None, f"{self.name} has no drawer"
        turned = abs(math.sin(self.yaw)) > 0.5
        width, depth = (self.size[1], self.size[0]) if turned else (self.size[0], self.size[1])
        return DrawerGeometry(width, depth, self.size[2], d.travel, d.inner, d.floor)


@dataclass(frozen=True)
class Layout:
    name: str
    description: str
    bounds: tuple[float, float, float, float]  # xmin, xmax, ymin, ymax
    walls: tuple[tuple[float, float, float, float], ...]  # centre x, y, size x, y
    furniture: tuple[FurnitureSpec, ...]
    bob_table: str  # the table Bob is mounted on; the task's fixtures lie on it
    bob_base: tuple[float, float, float]  # Bob's arm base on his table
    bob_yaw: float
    goal_area: tuple[float, float, float, float]  # centre x, y and size x, y on Bob's table: the task's fixtures go here
    near_slots: tuple[tuple[float, float], ...]  # on Bob's table within his reach
    far_slots: tuple[tuple[float, float], ...]  # on Bob's table beyond his reach
    starts: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    def get(self, name: str) -> FurnitureSpec | None:
        return next((f for f in self.furniture if f.name == name), None)

    def in_goal_area(self, x: float, y: float, margin: float = 0.0) -> bool:
        tx, ty, sx, sy = self.goal_area
        return abs(x - tx) <= sx / 2 + margin and abs(y - ty) <= sy / 2 + margin


def _south(x: float, f_y: float, sy: float) -> tuple[float, float, float]:
    return (x, round(f_y - sy / 2 - STAND_OFFSET, 3), HALF_PI)


def _north(x: float, f_y: float, sy: float) -> tuple[float, float, float]:
    return (x, round(f_y + sy / 2 + STAND_OFFSET, 3), -HALF_PI)


def _west(y: float, f_x: float, sx: float) -> tuple[float, float, float]:
    return (round(f_x - sx / 2 - STAND_OFFSET, 3), y, 0.0)


WOOD = (0.55, 0.4, 0.25, 1.0)
LIGHT = (0.8, 0.75, 0.65, 1.0)

HOUSE = Layout(
    name="house",
    description="a 10 x 8 m house: kitchen with table_0, a drawer unit and a counter to the west; study and living room to the east",
    bounds=(-5.0, 5.0, -4.0, 4.0),
    walls=(
        (0.0, -4.0, 10.2, 0.1),
        (0.0, 4.0, 10.2, 0.1),
        (-5.0, 0.0, 0.1, 8.2),
        (5.0, 0.0, 0.1, 8.2),
        (0.5, -3.1, 0.1, 1.8),  # kitchen | east rooms, with 1.2 m doorways at y = -1.6 and y = 1.6
        (0.5, 0.0, 0.1, 2.0),
        (0.5, 3.1, 0.1, 1.8),
        (1.85, 0.0, 2.7, 0.1),  # study | living room, open between x = 3.2 and the east wall
    ),
    furniture=(
        FurnitureSpec(
            "table_0", "table", "table", (-3.0, 0.0), (1.8, 0.8, 0.7), WOOD,
            stand_poses=(_south(-3.3, 0.0, 0.8), _south(-2.5, 0.0, 0.8), _north(-2.5, 0.0, 0.8)),
            place_pose=(-3.3, -0.22),
        ),
        FurnitureSpec(
            "drawer_unit", "drawer unit", "drawer_unit", (-3.0, 3.45), (1.0, 0.8, 0.6), LIGHT,
            stand_poses=((-3.0, 2.12, HALF_PI),),
            drawer=DrawerSpec(axis=(0.0, -1.0), travel=0.45, inner=(0.8, 0.55, 0.12), floor=0.4,
                              slots=((-0.25, -0.12), (0.0, -0.12), (0.25, -0.12))),
        ),
        FurnitureSpec(
            "counter", "counter", "block", (-1.0, -3.5), (1.4, 0.6, 0.75), LIGHT,
            stand_poses=(_north(-1.3, -3.5, 0.6), _north(-0.7, -3.5, 0.6)),
            place_pose=(-1.0, -3.45),
            slots=((-1.35, -3.45), (-1.0, -3.4), (-0.65, -3.45)),
        ),
        FurnitureSpec(
            "table_1", "table", "table", (2.5, 2.5), (1.2, 0.7, 0.7), WOOD,
            stand_poses=(_south(2.2, 2.5, 0.7), _south(2.8, 2.5, 0.7)),
            place_pose=(2.5, 2.45),
            slots=((2.15, 2.42), (2.5, 2.4), (2.85, 2.42)),
        ),
        FurnitureSpec(
            "table_2", "table", "table", (2.5, -2.8), (1.2, 0.7, 0.7), WOOD,
            stand_poses=(_north(2.2, -2.8, 0.7), _north(2.8, -2.8, 0.7)),
            place_pose=(2.5, -2.75),
            slots=((2.15, -2.72), (2.5, -2.7), (2.85, -2.72)),
        ),
        FurnitureSpec(
            "sofa", "sofa", "sofa", (4.3, -1.6), (0.8, 1.6, 0.45), (0.3, 0.35, 0.6, 1.0),
            stand_poses=(_west(-2.0, 4.3, 0.8), _west(-1.2, 4.3, 0.8)),
            place_pose=(4.1, -1.6),
            slots=((4.1, -2.0), (4.1, -1.6), (4.1, -1.2)),
        ),
    ),  # fmt: skip
    bob_table="table_0",
    bob_base=(-3.75, 0.0, 0.7),
    bob_yaw=0.0,
    goal_area=(-3.3, 0.2, 0.48, 0.36),
    near_slots=((-3.47, -0.22), (-3.25, -0.24)),
    far_slots=((-2.65, -0.15), (-2.4, 0.05), (-2.6, 0.2), (-2.85, 0.05)),
    starts={"alice": (-1.5, 1.2, 0.0), "david": (4.0, 3.0, math.pi)},
)

LAYOUTS: dict[str, Layout] = {HOUSE.name: HOUSE}


def get_layout(name: str) -> Layout:
    try:
        return LAYOUTS[name]
    except KeyError:
        raise ValueError(f"unknown scene {name!r}; known scenes: {', '.join(LAYOUTS)}") from None


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
    drawer_joint: dict[str, int]  # drawer unit name -> its prismatic joint index
    grid: Grid


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
        return abs(x - self.center[0]) <= self.size[0] / 2 + margin and abs(y - self.center[1]) <= self.size[1] / 2 + margin


def scene_statics(layout: Layout, assets_dir: AssetDir, fixtures: list[Fixture] | tuple[Fixture, ...] = ()) -> list[StaticBody]:
    """Write the layout's URDFs and list every fixed body (walls, furniture, the task's fixtures)."""
    out: list[StaticBody] = []
    wall_color = (0.9, 0.9, 0.88, 1.0)
    for i, (cx, cy, sx, sy) in enumerate(layout.walls):
        path = assets_dir.write(f"wall_{i}", assets.link_urdf(f"wall_{i}", assets.wall_boxes((sx, sy, WALL_HEIGHT), wall_color)))
        out.append(StaticBody(f"wall_{i}", path, (cx, cy, 0.0)))
    for f in layout.furniture:
        if f.style == "drawer_unit":
            urdf = assets.drawer_unit_urdf(f.name, f.drawer_geometry(), f.color)
        elif f.style == "table":
            urdf = assets.link_urdf(f.name, assets.table_boxes(f.size, f.color))
        elif f.style == "sofa":
            urdf = assets.link_urdf(f.name, assets.sofa_boxes(f.size, f.color))
        elif f.style == "block":
            urdf = assets.link_urdf(f.name, assets.block_boxes(f.size, f.color))
        else:
            raise ValueError(f"{f.name}: unknown furniture style {f.style!r}")
        out.append(StaticBody(f.name, assets_dir.write(f.name, urdf), (f.center[0], f.center[1], 0.0), f.yaw))
    top = _require(layout, layout.bob_table).top
    for fx in fixtures:
        boxes = assets.tray_boxes(*fx.size, fx.color, t=fx.thickness) if fx.rim else assets.slab_boxes(*fx.size, fx.thickness, fx.color)
        path = assets_dir.write(fx.name, assets.link_urdf(fx.name, boxes))
        out.append(StaticBody(fx.name, path, (fx.center[0], fx.center[1], top)))
    return out


def load_statics(cid: int, statics: list[StaticBody]) -> dict[str, int]:
    bodies = {}
    for s in statics:
        orn = p.getQuaternionFromEuler((0.0, 0.0, s.yaw))
        bodies[s.name] = p.loadURDF(s.path, s.position, orn, useFixedBase=True, physicsClientId=cid)
    return bodies


def occupancy(layout: Layout, margin: float, res: float = 0.05) -> Grid:
    """Walls and furniture footprints (open drawers included) grown by `margin`."""
    xmin, xmax, ymin, ymax = layout.bounds
    grid = Grid.empty(xmin, xmax, ymin, ymax, res)
    for cx, cy, sx, sy in layout.walls:
        grid.add_box(cx, cy, sx, sy, margin=margin)
    for f in layout.furniture:
        extra = 0.15 if f.style == "sofa" else 0.0  # the backrest
        grid.add_box(f.center[0] + extra / 2, f.center[1], f.size[0] + extra, f.size[1], margin=margin)
        if f.drawer is not None:  # the drawer may stand open: its footprint is never free floor
            g = f.drawer_geometry()
            ax, ay = f.drawer.axis
            reach = g.depth / 2 + f.drawer.travel / 2 + 0.03
            along = f.drawer.travel + 0.06
            sx, sy = (g.width, along) if abs(ay) > 0.5 else (along, g.width)
            grid.add_box(f.center[0] + ax * reach, f.center[1] + ay * reach, sx, sy, margin=margin)
    return grid


def build_scene(cid: int, layout: Layout, assets_dir: AssetDir, margin: float, fixtures: list[Fixture] | tuple[Fixture, ...] = ()) -> BuiltScene:
    """Floor, walls, furniture and the task's fixtures in client `cid`, and the base planners' occupancy grid."""
    p.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=cid)
    p.loadURDF("plane.urdf", physicsClientId=cid)
    statics = scene_statics(layout, assets_dir, fixtures)
    bodies = load_statics(cid, statics)
    joints: dict[str, int] = {}
    for f in layout.furniture:
        if f.drawer is not None:
            body = bodies[f.name]
            joints[f.name] = next(
                j for j in range(p.getNumJoints(body, physicsClientId=cid))
                if p.getJointInfo(body, j, physicsClientId=cid)[2] == p.JOINT_PRISMATIC
            )  # fmt: skip
            p.setJointMotorControl2(body, joints[f.name], p.VELOCITY_CONTROL, force=0.0, physicsClientId=cid)
    return BuiltScene(statics, bodies, joints, occupancy(layout, margin))


def _require(layout: Layout, name: str) -> FurnitureSpec:
    f = layout.get(name)
    if f is None:
        raise ValueError(f"layout {layout.name!r} has no furniture {name!r}")
    return f
