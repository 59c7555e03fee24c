"""Layout geometry: a house's furniture and layout as the simulator uses them (frozen specs,
built from layout files by layout_schema.py), and the floor things cover: an open drawer, a
door's sweep, a chassis or an arm at a pose. Coordinates are metres in the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .assets import ChestGeometry, Color, CupboardGeometry, DrawerGeometry, Panel
from .kinds import CHASSIS

Vec2 = tuple[float, float]
HANDLE_CLEARANCE = 0.015  # an open drawer's footprint reaches this beyond its handle
CHASSIS_FOOTPRINT = CHASSIS[:2]  # Alice's chassis, length x width
# Alice's arm in its carry posture (arm.HOME), seen from above: from this far behind to this far
# ahead of her base centre, this wide (measured from panda.urdf's link boxes; a test keeps it so)
HOME_FOOTPRINT = (-0.18, 0.53, 0.27)


@dataclass(frozen=True)
class DrawerSpec:
    """A drawer sliding out of its unit's front along `axis` (a unit x/y vector) by `travel`."""

    axis: tuple[float, float]
    travel: float
    inner: tuple[float, float, float]  # inside of the drawer: width, depth, wall height
    floor: float  # z of the drawer's floor surface
    slots: tuple[tuple[float, float], ...]  # object spots in the drawer frame (x across, y towards the back)
    max_object_height: float = 0.12
    handle_out: float = 0.045  # how far the handle stands out of the drawer's front


@dataclass(frozen=True)
class LidSpec:
    """A chest's lid, hinged at the back, opening up to `angle` rad; the front faces `axis`."""

    axis: tuple[float, float]
    angle: float
    floor: float  # z of the chest's inside floor
    slots: tuple[tuple[float, float], ...]  # object spots in the chest frame (x across, y towards the back)
    max_object_height: float = 0.12

    @property
    def travel(self) -> float:
        return self.angle


@dataclass(frozen=True)
class DoorSpec:
    """A cupboard's side-hinged door over its one cavity: the door covers `at` to `at + width`
    across the front (to the right of someone facing it, from the unit's centre), hinges at its
    `hinge` edge and swings out to `angle` rad; the front faces `axis`."""

    axis: tuple[float, float]
    hinge: str  # left | right, for someone facing the front
    at: float  # the door's left edge, across the front from the unit's centre
    width: float
    angle: float
    floor: float  # z of the cavity's floor
    ceiling: float  # z of the cavity's top
    slots: tuple[tuple[float, float], ...]  # object spots in the cavity's frame (x across, y towards the back)
    max_object_height: float = 0.12
    handle_out: float = 0.1

    @property
    def travel(self) -> float:
        return self.angle


Container = DrawerSpec | LidSpec | DoorSpec


def drawer_footprint(
    center: tuple[float, float], size: tuple[float, ...], axis: tuple[float, float], travel: float, handle_out: float
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Centre and size of the floor an open drawer (and its handle) covers in front of its unit
    (`size`: the unit's world x, y extent; the drawer slides out along `axis` by `travel`)."""
    along_y = abs(axis[1]) > 0.5
    width, depth = (size[0], size[1]) if along_y else (size[1], size[0])
    out = travel + handle_out + HANDLE_CLEARANCE
    reach = depth / 2 + out / 2
    return (center[0] + axis[0] * reach, center[1] + axis[1] * reach), ((width, out) if along_y else (out, width))


def door_footprint(
    center: tuple[float, float], size: tuple[float, ...], door: DoorSpec
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Centre and size of the floor a side-hinged door (and its handle) sweeps in front of its
    unit while it opens (`size`: the unit's world x, y extent): out of the front by the swing's
    radius, across from the hinge by that radius on the door's side and by the handle's reach
    on the other (a door opens at most 90 degrees: its handle then stands out past the hinge)."""
    along_y = abs(door.axis[1]) > 0.5
    width, depth = (size[0], size[1]) if along_y else (size[1], size[0])
    g = CupboardGeometry(
        width, depth, 1.0, door.at, door.width, door.hinge, door.floor, door.ceiling, door.angle, door.handle_out
    )
    radius = g.swing_radius
    behind = g.door + g.handle_out + HANDLE_CLEARANCE  # the handle, past the hinge line at 90 degrees
    hinge_u = g.hinge_point[0]
    mid_u = hinge_u + g.side * (radius - behind) / 2  # across the front, in the body frame
    across = radius + behind
    # body frame (front along -y) to world: the body is turned by axis_yaw(axis)
    yaw = axis_yaw(door.axis)
    c, s = round(math.cos(yaw)), round(math.sin(yaw))
    lx, ly = mid_u, -(depth / 2 + radius / 2)
    world = (center[0] + c * lx - s * ly, center[1] + s * lx + c * ly)
    return world, ((across, radius) if along_y else (radius, across))


SWEEP_STEPS = 12  # door positions sampled over its swing (the base planners' grid, the stand-pose check)


def door_sweep(
    center: tuple[float, float], size: tuple[float, ...], door: DoorSpec
) -> list[tuple[tuple[float, float], tuple[float, float], float]]:
    """The door (with its handle) at SWEEP_STEPS + 1 angles from shut to open, each as a world
    rectangle: centre, size and yaw. Their union is the floor the door sweeps, closer than
    `door_footprint`'s square."""
    along_y = abs(door.axis[1]) > 0.5
    width, depth = (size[0], size[1]) if along_y else (size[1], size[0])
    g = CupboardGeometry(
        width, depth, 1.0, door.at, door.width, door.hinge, door.floor, door.ceiling, door.angle, door.handle_out
    )
    thick = g.door + g.handle_out + HANDLE_CLEARANCE
    hx, hy, _ = g.hinge_point
    body_yaw = axis_yaw(door.axis)
    c, s = math.cos(body_yaw), math.sin(body_yaw)
    out = []
    for k in range(SWEEP_STEPS + 1):
        a = -g.side * door.angle * k / SWEEP_STEPS  # the door's turn about +z in the body frame
        lx, ly = g.side * g.door_width / 2, -thick / 2  # the door's centre in its link frame, shut
        bx = hx + math.cos(a) * lx - math.sin(a) * ly
        by = hy + math.sin(a) * lx + math.cos(a) * ly
        world = (center[0] + c * bx - s * by, center[1] + s * bx + c * by)
        out.append((world, (g.door_width, thick), body_yaw + a))
    return out


def axis_yaw(axis: tuple[float, float]) -> float:
    """Body yaw (in [-pi, pi]) of furniture whose front faces `axis`: bodies are built with their front along -y."""
    return math.atan2(axis[0], -axis[1])


@dataclass(frozen=True)
class FurnitureSpec:
    name: str
    kind: str
    style: str  # table | block | sofa | drawer_unit | chest | cupboard: how assets.py builds it
    center: tuple[float, float]
    size: tuple[float, float, float]  # sx, sy, height (of the top surface)
    color: Color
    stand_poses: tuple[tuple[float, float, float], ...] = ()
    place_pose: tuple[float, float] | None = None
    place_radius: float = 0.3  # free spots for `place` are searched this far from the place pose
    slots: tuple[tuple[float, float], ...] = ()  # object spots on top, absolute x, y
    drawer: DrawerSpec | None = None
    lid: LidSpec | None = None
    door: DoorSpec | None = None
    front: tuple[float, float] | None = None  # the side a block's facade faces (containers face their axis)
    panels: tuple[Panel, ...] = ()  # the facade: visual-only panels on the front

    @property
    def top(self) -> float:
        return self.size[2]

    @property
    def facing(self) -> tuple[float, float] | None:
        """The side its front faces: a container's axis, or the facade's front."""
        return self.container.axis if self.container is not None else self.front

    @property
    def yaw(self) -> float:
        """Body yaw: containers and blocks with a facade are built with their front along -y of their own frame."""
        facing = self.facing
        return 0.0 if facing is None else axis_yaw(facing)

    def contains_xy(self, x: float, y: float, margin: float = 0.0) -> bool:
        return (
            abs(x - self.center[0]) <= self.size[0] / 2 + margin
            and abs(y - self.center[1]) <= self.size[1] / 2 + margin
        )

    @property
    def container(self) -> Container | None:
        """What makes this furniture a closed container (a drawer, a lid, a door), if anything."""
        return self.drawer or self.lid or self.door

    def own_size(self) -> tuple[float, float]:
        """Width and depth in the body's own frame (front along -y)."""
        turned = abs(math.sin(self.yaw)) > 0.5
        return (self.size[1], self.size[0]) if turned else (self.size[0], self.size[1])

    def open_drawer_footprint(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """Centre and size of the floor its drawer covers when open, if it has one."""
        d = self.drawer
        return None if d is None else drawer_footprint(self.center, self.size, d.axis, d.travel, d.handle_out)

    def swept_footprint(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """Centre and size of the floor its drawer covers when open, or its door sweeps, if any."""
        if self.door is not None:
            return door_footprint(self.center, self.size, self.door)
        return self.open_drawer_footprint()

    def cupboard_geometry(self) -> CupboardGeometry:
        d = self.door
        assert d is not None, f"{self.name} has no door"
        width, depth = self.own_size()
        return CupboardGeometry(
            width, depth, self.size[2], d.at, d.width, d.hinge, d.floor, d.ceiling, d.angle, d.handle_out
        )

    def chest_geometry(self) -> ChestGeometry:
        lid = self.lid
        assert lid is not None, f"{self.name} has no lid"
        width, depth = self.own_size()
        return ChestGeometry(width, depth, self.size[2], lid.floor, lid.angle)

    def drawer_geometry(self) -> DrawerGeometry:
        d = self.drawer
        assert d is not None, f"{self.name} has no drawer"
        width, depth = self.own_size()
        return DrawerGeometry(width, depth, self.size[2], d.travel, d.inner, d.floor, handle_out=d.handle_out)


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
    goal_area: tuple[
        float, float, float, float
    ]  # centre x, y and size x, y on Bob's table: the task's fixtures go here
    near_slots: tuple[tuple[float, float], ...]  # on Bob's table within his reach
    far_slots: tuple[tuple[float, float], ...]  # on Bob's table beyond his reach
    starts: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    source: str = ""  # the file it came from

    @property
    def arm_mounts(self) -> tuple[tuple[tuple[float, float, float], float], ...]:
        """Where a fixed arm can be mounted, (base, yaw) each: one today, on Bob's table."""
        return ((self.bob_base, self.bob_yaw),)

    def get(self, name: str) -> FurnitureSpec | None:
        return next((f for f in self.furniture if f.name == name), None)

    def in_goal_area(self, x: float, y: float, margin: float = 0.0) -> bool:
        tx, ty, sx, sy = self.goal_area
        return abs(x - tx) <= sx / 2 + margin and abs(y - ty) <= sy / 2 + margin


# --------------------------------------------------------------------------- floor geometry


def overlap(c1: Vec2, s1: tuple[float, ...], c2: Vec2, s2: tuple[float, ...]) -> float:
    """How deep two axis-aligned footprints (centre, size) intersect: the smaller of the
    overlaps along x and y; 0 when they are apart."""
    ox = min(c1[0] + s1[0] / 2, c2[0] + s2[0] / 2) - max(c1[0] - s1[0] / 2, c2[0] - s2[0] / 2)
    oy = min(c1[1] + s1[1] / 2, c2[1] + s2[1] / 2) - max(c1[1] - s1[1] / 2, c2[1] - s2[1] / 2)
    return max(0.0, min(ox, oy))


def chassis_outline(pose: tuple[float, float, float], step: float = 0.05) -> list[Vec2]:
    """Points every `step` along the outline of Alice's chassis standing at `pose` (x, y, yaw)."""
    hl, hw = CHASSIS_FOOTPRINT[0] / 2, CHASSIS_FOOTPRINT[1] / 2
    return _outline(pose, (-hl, hl), (-hw, hw), step)


def home_outline(pose: tuple[float, float, float], step: float = 0.05) -> list[Vec2]:
    """Points every `step` along the outline of Alice's arm in its carry posture, seen from above."""
    back, ahead, wide = HOME_FOOTPRINT
    return _outline(pose, (back, ahead), (-wide / 2, wide / 2), step)


def _outline(
    pose: tuple[float, float, float], us: tuple[float, float], vs: tuple[float, float], step: float
) -> list[Vec2]:
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    local: list[Vec2] = []
    for u in _linspace(us[0], us[1], int(round((us[1] - us[0]) / step)) + 1):
        local += [(u, vs[0]), (u, vs[1])]
    for v in _linspace(vs[0], vs[1], int(round((vs[1] - vs[0]) / step)) + 1):
        local += [(us[0], v), (us[1], v)]
    return [(x + c * u - s * v, y + s * u + c * v) for u, v in local]


def _linspace(start: float, stop: float, num: int) -> list[float]:
    """numpy.linspace's points, bit for bit (i * step + start, the last exactly `stop`), without
    numpy: checking a layout imports no numerics."""
    if num <= 1:
        return [float(start)][:num]
    step = (stop - start) / (num - 1)
    return [i * step + start for i in range(num - 1)] + [float(stop)]


def inside_turned(center: Vec2, size: tuple[float, ...], yaw: float, xy: Vec2, margin: float) -> bool:
    """Whether `xy` lies within `margin` (straight-line distance) of a rectangle turned by `yaw`."""
    dx, dy = xy[0] - center[0], xy[1] - center[1]
    c, s = math.cos(yaw), math.sin(yaw)
    ox, oy = max(abs(c * dx + s * dy) - size[0] / 2, 0.0), max(abs(-s * dx + c * dy) - size[1] / 2, 0.0)
    return math.hypot(ox, oy) <= margin


def inside(center: Vec2, size: tuple[float, ...], xy: Vec2, margin: float = 1e-9) -> bool:
    """Whether `xy` lies on an axis-aligned footprint (centre, size), grown by `margin`."""
    return abs(xy[0] - center[0]) <= size[0] / 2 + margin and abs(xy[1] - center[1]) <= size[1] / 2 + margin


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
