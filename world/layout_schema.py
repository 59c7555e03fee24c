"""The layout file's schema: pydantic models of `scenes/<name>.json`, every field and every
cross-field rule checked (the format and the rules are documented in layouts.py), built into
the frozen specs of furniture.py.

Errors are ValueErrors naming the field; layouts.parse_layout adds the file.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from .assets import Color, CupboardGeometry, DrawerGeometry, Panel
from .colors import FURNITURE_COLORS
from .furniture import (
    DoorSpec,
    DrawerSpec,
    FurnitureSpec,
    Layout,
    LidSpec,
    Vec2,
    chassis_outline,
    door_footprint,
    door_sweep,
    drawer_footprint,
    home_outline,
    inside,
    inside_turned,
    overlap,
)

STAND_OFFSET = 0.45  # base centre to furniture edge at a stand pose
HALF_PI = math.pi / 2
ROBOT_CLEARANCE = 0.3  # a stand pose or start must be this far from walls and furniture
ARM_REACH = 0.62  # Bob's conservative horizontal reach (robots.KINDS["tabletop_arm"].reach; a test keeps them equal)
FAR_SLOT = 1.0  # far slots lie beyond this from Bob's arm base, his position in his prompt: it tells him he picks best within 1 m
# (the paper's appendix: ideal pick distance about 1 m), so what the task puts "out of his reach" must lie beyond it
GOAL_CORNER_REACH = 0.8  # every corner of the goal area lies within this of Bob's arm base
PANELS = (0.34, 0.22)  # the sort task's six panels, 3 x 2 at a 0.12 m pitch: their extent
PANEL_CENTRES = (0.12, 0.06)  # the panels' centres lie within +- these of the goal area's centre
MIN_GOAL_AREA = 0.17  # m^2: a tray this big holds six of the pack task's objects
MIN_CONTAINERS = 2  # closed containers a target can hide in, in every layout
DOOR_CLEARANCE = 0.03  # m between a swinging door and a chassis at a stand pose or start
OVERLAP_TOLERANCE = 0.01  # m: footprints that share less than this (touching, rounding) do not count as overlapping

Name = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=40)]
Positive = Annotated[float, Field(gt=0)]
Pose = tuple[float, float, float]
Rect = tuple[float, float, Positive, Positive]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class StandSide(_Strict):
    side: Literal["north", "south", "east", "west"]
    at: float = Field(description="x (north/south side) or y (east/west side) of the pose")


class DrawerFile(_Strict):
    axis: Vec2
    travel: Positive
    inner: tuple[Positive, Positive, Positive]
    floor: Positive
    slots: list[Vec2] = Field(min_length=1)
    max_object_height: Positive = 0.12
    handle_out: float = Field(0.045, ge=0.03, le=0.15)

    @model_validator(mode="after")
    def _axis(self) -> DrawerFile:
        if (err := _axis_error(self.axis)) is not None:
            raise ValueError(err)
        for i, (x, y) in enumerate(self.slots):
            if abs(x) > self.inner[0] / 2 or abs(y) > self.inner[1] / 2:
                raise ValueError(f"slots.{i}: {[x, y]} lies outside the drawer's inside {list(self.inner[:2])}")
        return self


class LidFile(_Strict):
    axis: Vec2 = Field(description="the side the chest's front faces, e.g. [0, -1]")
    open_deg: float = Field(75.0, gt=10, le=110)
    floor: Positive
    slots: list[Vec2] = Field(min_length=1)
    max_object_height: Positive = 0.12

    @model_validator(mode="after")
    def _axis(self) -> LidFile:
        if (err := _axis_error(self.axis)) is not None:
            raise ValueError(err)
        return self


class DoorFile(_Strict):
    axis: Vec2 = Field(description="the side the cupboard's front faces, e.g. [0, -1]")
    hinge: Literal["left", "right"] = Field(description="the door's hinged edge, for someone facing the front")
    at: float = Field(description="the door's left edge, across the front from the unit's centre")
    width: Positive
    open_deg: float = Field(85.0, gt=30, le=90)
    floor: Positive
    ceiling: Positive
    slots: list[Vec2] = Field(min_length=1)
    max_object_height: Positive = 0.12
    handle_out: float = Field(0.1, ge=0.03, le=0.15)

    @model_validator(mode="after")
    def _axis(self) -> DoorFile:
        if (err := _axis_error(self.axis)) is not None:
            raise ValueError(err)
        if self.ceiling <= self.floor + self.max_object_height:
            raise ValueError(
                f"ceiling: the cavity from {self.floor} to {self.ceiling} m is too low for objects {self.max_object_height} m tall"
            )
        inner = (self.width / 2 - CupboardGeometry.wall, 0.0)
        for i, (x, _) in enumerate(self.slots):
            if abs(x) > inner[0]:
                raise ValueError(
                    f"slots.{i}: {x} lies outside the cavity's width {self.width - 2 * CupboardGeometry.wall:.2f}"
                )
        return self


def _axis_error(axis: Vec2) -> str | None:
    if sorted(abs(c) for c in axis) != [0.0, 1.0]:
        return f"axis must be a unit vector along x or y, e.g. [0, -1], not {list(axis)}"
    return None


ColorField = str | tuple[float, float, float, float]


def _color_error(color: ColorField) -> str | None:
    if isinstance(color, str) and color not in FURNITURE_COLORS:
        return f"unknown colour {color!r}; use one of {', '.join(FURNITURE_COLORS)} or [r, g, b, a]"
    return None


def _color(color: ColorField) -> Color:
    return FURNITURE_COLORS[color] if isinstance(color, str) else color


class PanelFile(_Strict):
    at: Vec2 = Field(description="centre: across the front (to the right of someone facing it) and height")
    size: tuple[Positive, Positive] = Field(description="width and height")
    color: ColorField = "white"
    handle: Literal["none", "left", "right", "top"] = "none"

    @model_validator(mode="after")
    def _color_known(self) -> PanelFile:
        if (err := _color_error(self.color)) is not None:
            raise ValueError(f"color: {err}")
        return self


class FacadeFile(_Strict):
    front: Vec2 | None = Field(None, description="the side the front faces; a container's is its axis")
    panels: list[PanelFile] = Field(min_length=1)

    @model_validator(mode="after")
    def _front(self) -> FacadeFile:
        if self.front is not None and (err := _axis_error(self.front)) is not None:
            raise ValueError(f"front: {err}")
        return self


class FurnitureFile(_Strict):
    name: Name
    kind: str = Field(min_length=1)
    style: Literal["table", "block", "sofa", "drawer_unit", "chest", "cupboard"]
    center: Vec2
    size: tuple[Positive, Positive, Positive]
    color: str | tuple[float, float, float, float] = "light"
    stand_poses: list[Pose | StandSide] = Field(default_factory=list)
    place_pose: Vec2 | None = None
    place_radius: Positive = 0.3
    slots: list[Vec2] = Field(default_factory=list)
    drawer: DrawerFile | None = None
    lid: LidFile | None = None
    door: DoorFile | None = None
    facade: FacadeFile | None = None

    @model_validator(mode="after")
    def _consistent(self) -> FurnitureFile:
        if (err := _color_error(self.color)) is not None:
            raise ValueError(f"color: {err}")
        if self.facade is not None:
            container = self.drawer or self.lid or self.door
            axis = None if container is None else container.axis
            if self.style not in ("block", "drawer_unit", "chest", "cupboard"):
                raise ValueError(
                    f"facade: only a block, a drawer_unit, a chest or a cupboard has one, not a {self.style}"
                )
            if axis is None and self.facade.front is None:
                raise ValueError("facade.front: a block's facade needs the side it faces, e.g. [0, -1]")
            if axis is not None and self.facade.front is not None and tuple(self.facade.front) != tuple(axis):
                raise ValueError(f"facade.front: a container's front is its axis {list(axis)}; omit front")
            width = self.size[1] if abs(self.facing()[0]) > 0.5 else self.size[0]
            for i, pn in enumerate(self.facade.panels):
                (u, z), (w, h) = pn.at, pn.size
                if abs(u) + w / 2 > width / 2 + 1e-9 or z - h / 2 < -1e-9 or z + h / 2 > self.size[2] + 1e-9:
                    raise ValueError(
                        f"facade.panels.{i}: {[u, z]} size {[w, h]} does not fit on the front ({width} wide, {self.size[2]} high)"
                    )
        if (self.style == "drawer_unit") != (self.drawer is not None):
            raise ValueError("drawer: a drawer_unit needs a drawer, and only a drawer_unit may have one")
        if (self.style == "chest") != (self.lid is not None):
            raise ValueError("lid: a chest needs a lid, and only a chest may have one")
        if (self.style == "cupboard") != (self.door is not None):
            raise ValueError("door: a cupboard needs a door, and only a cupboard may have one")
        if self.door is not None:
            self._check_door(self.door)
        if self.drawer is not None:
            d = self.drawer
            width, depth = (self.size[1], self.size[0]) if abs(d.axis[0]) > 0.5 else (self.size[0], self.size[1])
            wall = DrawerGeometry.wall
            if d.inner[0] + 4 * wall > width + 1e-9 or d.inner[1] + 3 * wall > depth + 1e-9:
                raise ValueError(
                    f"drawer.inner: a drawer {list(d.inner[:2])} inside does not fit in {self.name} ({width} wide, {depth} deep) with its walls"
                )
            if d.floor + d.inner[2] + 0.02 > self.size[2] - 0.01:
                raise ValueError(
                    f"drawer.floor: a drawer at {d.floor} m with {d.inner[2]} m walls does not fit under the top of {self.name}"
                )
            if d.max_object_height > d.inner[2] + 0.015:
                raise ValueError(f"drawer.max_object_height: objects that tall do not fit in the drawer of {self.name}")
        if self.lid is not None:
            turned = abs(self.lid.axis[0]) > 0.5
            width, depth = (self.size[1], self.size[0]) if turned else (self.size[0], self.size[1])
            inner = (width / 2 - 0.05, depth / 2 - 0.05)
            if self.lid.floor + self.lid.max_object_height > self.size[2] - 0.03:
                raise ValueError(f"lid.max_object_height: objects that tall do not fit under the lid of {self.name}")
            for i, (x, y) in enumerate(self.lid.slots):
                if abs(x) > inner[0] or abs(y) > inner[1]:
                    raise ValueError(f"lid.slots.{i}: {[x, y]} lies outside the chest's inside")
        if self.slots and self.place_pose is None:
            raise ValueError("place_pose: furniture with slots needs a place_pose")
        for what, xy in [("place_pose", self.place_pose), *((f"slots.{i}", s) for i, s in enumerate(self.slots))]:
            if xy is not None and not inside(self.center, self.size, xy):
                raise ValueError(f"{what}: {list(xy)} is not on top of {self.name}")
        return self

    def _check_door(self, door: DoorFile) -> None:
        width, depth = (self.size[1], self.size[0]) if abs(door.axis[0]) > 0.5 else (self.size[0], self.size[1])
        if door.at < -width / 2 - 1e-9 or door.at + door.width > width / 2 + 1e-9:
            raise ValueError(
                f"door: a door from {door.at} to {door.at + door.width} across does not fit on the front of {self.name} ({width} wide)"
            )
        if door.ceiling > self.size[2] - 0.02:
            raise ValueError(f"door.ceiling: {door.ceiling} m leaves no top on {self.name} ({self.size[2]} high)")
        for i, (_, y) in enumerate(door.slots):
            if abs(y) > (depth - CupboardGeometry.wall) / 2 - 0.05:
                raise ValueError(f"door.slots.{i}: {y} lies outside the cavity's depth")

    def facing(self) -> Vec2:
        """The side the front faces: the container's axis, the facade's front, else -y."""
        if self.drawer is not None:
            return self.drawer.axis
        if self.lid is not None:
            return self.lid.axis
        if self.door is not None:
            return self.door.axis
        if self.facade is not None and self.facade.front is not None:
            return self.facade.front
        return (0.0, -1.0)

    def open_drawer_footprint(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        if self.drawer is None:
            return None
        return drawer_footprint(self.center, self.size, self.drawer.axis, self.drawer.travel, self.drawer.handle_out)

    def swept_footprint(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """The floor an open drawer covers or a door sweeps (its bounding square), if it has either."""
        if self.door is not None:
            return door_footprint(self.center, self.size, _door_spec(self.door))
        return self.open_drawer_footprint()

    def stand_pose_list(self) -> list[Pose]:
        cx, cy = self.center
        sx, sy, _ = self.size
        out = []
        for sp in self.stand_poses:
            if isinstance(sp, StandSide):
                out.append(
                    {
                        "south": (sp.at, round(cy - sy / 2 - STAND_OFFSET, 3), HALF_PI),
                        "north": (sp.at, round(cy + sy / 2 + STAND_OFFSET, 3), -HALF_PI),
                        "west": (round(cx - sx / 2 - STAND_OFFSET, 3), sp.at, 0.0),
                        "east": (round(cx + sx / 2 + STAND_OFFSET, 3), sp.at, math.pi),
                    }[sp.side]
                )
            else:
                out.append(sp)
        return out


class BobFile(_Strict):
    table: Name
    base: Pose
    yaw: float = 0.0
    goal_area: Rect
    near_slots: list[Vec2] = Field(min_length=1)
    far_slots: list[Vec2] = Field(min_length=1)


class LayoutFile(_Strict):
    name: Name
    description: str = Field(min_length=1)
    bounds: tuple[float, float, float, float]
    walls: list[Rect] = Field(default_factory=list)
    bob: BobFile
    starts: dict[Name, Pose]  # any robot's name; a team's robot without one starts where the seed puts it
    furniture: list[FurnitureFile] = Field(min_length=2)

    @model_validator(mode="after")
    def _consistent(self) -> LayoutFile:
        xmin, xmax, ymin, ymax = self.bounds
        if not (xmin < xmax and ymin < ymax):
            raise ValueError(f"bounds: need xmin < xmax and ymin < ymax, got {list(self.bounds)}")
        names = [f.name for f in self.furniture]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise ValueError(f"furniture.{i}.name: {n!r} is used twice")
        table = next((f for f in self.furniture if f.name == self.bob.table), None)
        if table is None:
            raise ValueError(f"bob.table: no furniture named {self.bob.table!r}; furniture: {', '.join(names)}")
        if table.style != "table" or table.place_pose is None:
            raise ValueError(f"bob.table: {table.name} must be a table with a place_pose")
        gx, gy, gsx, gsy = self.bob.goal_area
        if not (
            inside(table.center, table.size, (gx - gsx / 2, gy - gsy / 2))
            and inside(table.center, table.size, (gx + gsx / 2, gy + gsy / 2))
        ):
            raise ValueError(f"bob.goal_area: {list(self.bob.goal_area)} does not lie on {table.name}")
        for what in ("near_slots", "far_slots"):
            for i, xy in enumerate(getattr(self.bob, what)):
                if not inside(table.center, table.size, xy):
                    raise ValueError(f"bob.{what}.{i}: {list(xy)} is not on {table.name}")
        self._check_reach(table)
        containers = [f.name for f in self.furniture if f.drawer is not None or f.lid is not None or f.door is not None]
        if len(containers) < MIN_CONTAINERS:
            raise ValueError(
                f"furniture: a layout needs at least {MIN_CONTAINERS} closed containers a target can hide in "
                f"(drawer_unit, chest or cupboard); it has {len(containers)}{': ' + ', '.join(containers) if containers else ''}"
            )
        elsewhere = sum(len(f.slots) for f in self.furniture if f.name != table.name)
        if elsewhere < 5:
            raise ValueError(
                f"furniture: slots away from {table.name} number {elsewhere}; 6-object episodes need at least 5"
            )
        self._check_overlaps()
        obstacles = [(f"walls.{i}", (w[0], w[1]), (w[2], w[3])) for i, w in enumerate(self.walls)]
        obstacles += [
            (f"furniture.{i} ({f.name})", f.center, (f.size[0], f.size[1])) for i, f in enumerate(self.furniture)
        ]
        for i, f in enumerate(self.furniture):
            swept = f.open_drawer_footprint()
            if swept is not None:
                obstacles.append((f"furniture.{i} ({f.name}) with its drawer open", *swept))
        poses = [(f"starts.{r}", s) for r, s in self.starts.items()]
        for i, f in enumerate(self.furniture):
            if not f.stand_poses:
                raise ValueError(
                    f"furniture.{i}.stand_poses: {f.name} has none; every piece of furniture needs one (agents read furniture without one as a task fixture)"
                )
            poses += [(f"furniture.{i}.stand_poses.{j} ({f.name})", sp) for j, sp in enumerate(f.stand_pose_list())]
        sweeps = [
            (f"furniture.{i} ({f.name}) with its door swinging open", door_sweep(f.center, f.size, _door_spec(f.door)))
            for i, f in enumerate(self.furniture)
            if f.door
        ]
        for what, (x, y, _yaw) in poses:
            if not (
                xmin + ROBOT_CLEARANCE <= x <= xmax - ROBOT_CLEARANCE
                and ymin + ROBOT_CLEARANCE <= y <= ymax - ROBOT_CLEARANCE
            ):
                raise ValueError(f"{what}: ({x}, {y}) is off the floor or too close to its edge")
            for name, c, sz in obstacles:
                if inside(c, sz, (x, y), margin=ROBOT_CLEARANCE - 0.01):
                    raise ValueError(f"{what}: ({x}, {y}) is within {ROBOT_CLEARANCE} m of {name}")
            outline, arm = chassis_outline((x, y, _yaw)), home_outline((x, y, _yaw))
            for name, boxes in sweeps:
                if any(inside_turned(c, sz, yaw, pt, DOOR_CLEARANCE) for c, sz, yaw in boxes for pt in outline):
                    raise ValueError(f"{what}: a chassis at ({x}, {y}) would be within {DOOR_CLEARANCE} m of {name}")
                c, sz, yaw = boxes[-1]  # the door open: the arm in its carry posture clears it
                if any(inside_turned(c, sz, yaw, pt, DOOR_CLEARANCE) for pt in arm):
                    raise ValueError(
                        f"{what}: an arm in its carry posture at ({x}, {y}) would be within {DOOR_CLEARANCE} m of the open door of {name.split(' with ')[0]}"
                    )
        return self

    def _check_overlaps(self) -> None:
        """No piece of furniture may stand in another or in a wall (touching is fine): a pillar
        through a table would load, and every action near it would fail with no hint why."""
        pieces = [(f"furniture.{i} ({f.name})", f.center, (f.size[0], f.size[1])) for i, f in enumerate(self.furniture)]
        walls = [(f"walls.{i}", (w[0], w[1]), (w[2], w[3])) for i, w in enumerate(self.walls)]
        for i, (what, c, sz) in enumerate(pieces):
            for other, oc, osz in pieces[i + 1 :] + walls:
                depth = overlap(c, sz, oc, osz)
                if depth > OVERLAP_TOLERANCE:
                    raise ValueError(
                        f"{what} overlaps {other} by {depth:.2f} m: move it or shrink it (furniture may touch, not intersect)"
                    )
        # a door swinging open must not hit a wall, other furniture or another drawer or door standing open
        swept = [
            (f"furniture.{i} ({f.name}) with its door swinging open", i, s)
            for i, f in enumerate(self.furniture)
            if f.door is not None and (s := f.swept_footprint()) is not None
        ]
        opened = [
            (f"furniture.{i} ({f.name}) open", i, s)
            for i, f in enumerate(self.furniture)
            if (s := f.swept_footprint()) is not None
        ]
        for what, i, (c, sz) in swept:
            others = [(o, oc, osz) for j, (o, oc, osz) in enumerate(pieces) if j != i] + walls
            others += [(o, *s) for o, j, s in opened if j != i]
            for other, oc, osz in others:
                depth = overlap(c, sz, oc, osz)
                if depth > OVERLAP_TOLERANCE:
                    raise ValueError(
                        f"{what} overlaps {other} by {depth:.2f} m: move it, narrow its door or hinge it on the other side"
                    )

    def _check_reach(self, table: FurnitureFile) -> None:
        """Bob's slots and goal area against his reach (see the module docstring)."""
        bx, by, _ = self.bob.base
        if not inside(table.center, table.size, (bx, by)):
            raise ValueError(f"bob.base: {list(self.bob.base)} is not on {table.name}")

        def dist(x: float, y: float) -> float:
            return math.hypot(x - bx, y - by)

        for i, (x, y) in enumerate(self.bob.near_slots):
            if not 0.3 <= dist(x, y) <= ARM_REACH - 0.03:
                raise ValueError(
                    f"bob.near_slots.{i}: {[x, y]} is {dist(x, y):.2f} m from Bob's arm base; near slots lie 0.3 to {ARM_REACH - 0.03:.2f} m from it"
                )
        for i, (x, y) in enumerate(self.bob.far_slots):
            if dist(x, y) <= FAR_SLOT:
                raise ValueError(
                    f"bob.far_slots.{i}: {[x, y]} is {dist(x, y):.3f} m from Bob's arm base; far slots lie beyond {FAR_SLOT} m from it "
                    "(his prompt says he picks best within 1 m, so an object out of his reach must lie farther)"
                )
        gx, gy, gsx, gsy = self.bob.goal_area
        where = f"bob.goal_area: {list(self.bob.goal_area)}"
        if gsx < PANELS[0] or gsy < PANELS[1] or gsx * gsy < MIN_GOAL_AREA:
            raise ValueError(
                f"{where} is too small: it needs at least {PANELS[0]} x {PANELS[1]} m and {MIN_GOAL_AREA} m^2 (six panels, a tray for six objects)"
            )
        for sx in (-1, 1):
            for sy in (-1, 1):
                if dist(gx + sx * gsx / 2, gy + sy * gsy / 2) > GOAL_CORNER_REACH:
                    raise ValueError(
                        f"{where}: its corner {[round(gx + sx * gsx / 2, 3), round(gy + sy * gsy / 2, 3)]} is beyond {GOAL_CORNER_REACH} m from Bob's arm base"
                    )
                d = dist(gx + sx * PANEL_CENTRES[0], gy + sy * PANEL_CENTRES[1])
                if not 0.3 <= d <= ARM_REACH:
                    raise ValueError(
                        f"{where}: its centre region (the panels' centres) is {d:.2f} m from Bob's arm base; it must lie 0.3 to {ARM_REACH} m from it"
                    )

    def build(self, source: str = "") -> Layout:
        furniture = []
        for f in self.furniture:
            d, lid, door = f.drawer, f.lid, f.door
            furniture.append(
                FurnitureSpec(
                    name=f.name,
                    kind=f.kind,
                    style=f.style,
                    center=f.center,
                    size=f.size,
                    color=_color(f.color),
                    stand_poses=tuple(f.stand_pose_list()),
                    place_pose=f.place_pose,
                    place_radius=f.place_radius,
                    slots=tuple(f.slots),
                    drawer=None
                    if d is None
                    else DrawerSpec(
                        d.axis, d.travel, d.inner, d.floor, tuple(d.slots), d.max_object_height, d.handle_out
                    ),
                    lid=None
                    if lid is None
                    else LidSpec(
                        lid.axis, math.radians(lid.open_deg), lid.floor, tuple(lid.slots), lid.max_object_height
                    ),
                    door=None if door is None else _door_spec(door),
                    front=None
                    if f.facade is None or d is not None or lid is not None or door is not None
                    else f.facade.front,
                    panels=()
                    if f.facade is None
                    else tuple(Panel(*pn.at, *pn.size, _color(pn.color), pn.handle) for pn in f.facade.panels),
                )
            )
        b = self.bob
        return Layout(
            name=self.name,
            description=self.description,
            bounds=self.bounds,
            walls=tuple(self.walls),
            furniture=tuple(furniture),
            bob_table=b.table,
            bob_base=b.base,
            bob_yaw=b.yaw,
            goal_area=b.goal_area,
            near_slots=tuple(b.near_slots),
            far_slots=tuple(b.far_slots),
            starts={str(k): v for k, v in self.starts.items()},
            source=source,
        )


def _door_spec(door: DoorFile) -> DoorSpec:
    return DoorSpec(
        door.axis,
        door.hinge,
        door.at,
        door.width,
        math.radians(door.open_deg),
        door.floor,
        door.ceiling,
        tuple(door.slots),
        door.max_object_height,
        door.handle_out,
    )
