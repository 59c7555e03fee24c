"""The layout file's schema: pydantic models of `scenes/<name>.json`, every field and every
cross-field rule checked (the format and the rules are documented in layouts.py), built into
the frozen specs of furniture.py. Here the layout as a whole: Bob's table, slots and goal area
within his reach, stand poses and starts clear of walls, furniture and swinging doors, nothing
overlapping, enough containers; one piece of furniture alone is furniture_schema.py's.

Errors are ValueErrors naming the field; layouts.parse_layout adds the file.
"""

from __future__ import annotations

import math

from pydantic import Field, model_validator

from .assets import Panel
from .furniture import (
    DrawerSpec,
    FurnitureSpec,
    Layout,
    LidSpec,
    Vec2,
    chassis_outline,
    door_sweep,
    home_outline,
    inside,
    inside_turned,
    overlap,
)
from .furniture_schema import FurnitureFile, Name, Pose, Positive, Strict, color_of, door_spec
from .kinds import KINDS

ROBOT_CLEARANCE = 0.3  # a stand pose or start must be this far from walls and furniture
_BOB_REACH = KINDS["tabletop_arm"].reach  # Bob's conservative horizontal reach: an arm's kind has one
assert _BOB_REACH is not None
ARM_REACH: float = _BOB_REACH
FAR_SLOT = 1.0  # far slots lie beyond this from Bob's arm base, his position in his prompt: it tells him he picks best within 1 m
# (the paper's appendix: ideal pick distance about 1 m), so what the task puts "out of his reach" must lie beyond it
GOAL_CORNER_REACH = 0.8  # every corner of the goal area lies within this of Bob's arm base
PANELS = (0.34, 0.22)  # the sort task's six panels, 3 x 2 at a 0.12 m pitch: their extent
PANEL_CENTRES = (0.12, 0.06)  # the panels' centres lie within +- these of the goal area's centre
MIN_GOAL_AREA = 0.17  # m^2: a tray this big holds six of the pack task's objects
MIN_CONTAINERS = 2  # closed containers a target can hide in, in every layout
DOOR_CLEARANCE = 0.03  # m between a swinging door and a chassis at a stand pose or start
OVERLAP_TOLERANCE = 0.01  # m: footprints that share less than this (touching, rounding) do not count as overlapping

Rect = tuple[float, float, Positive, Positive]


class BobFile(Strict):
    table: Name
    base: Pose
    yaw: float = 0.0
    goal_area: Rect
    near_slots: list[Vec2] = Field(min_length=1)
    far_slots: list[Vec2] = Field(min_length=1)


class LayoutFile(Strict):
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
            (f"furniture.{i} ({f.name}) with its door swinging open", door_sweep(f.center, f.size, door_spec(f.door)))
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
            body, reach = _radius((x, y), outline), _radius((x, y), arm)
            for name, boxes in sweeps:
                if any(
                    inside_turned(c, sz, yaw, pt, DOOR_CLEARANCE)
                    for c, sz, yaw in boxes
                    if _within((x, y), body, c, sz)
                    for pt in outline
                ):
                    raise ValueError(f"{what}: a chassis at ({x}, {y}) would be within {DOOR_CLEARANCE} m of {name}")
                c, sz, yaw = boxes[-1]  # the door open: the arm in its carry posture clears it
                if _within((x, y), reach, c, sz) and any(inside_turned(c, sz, yaw, pt, DOOR_CLEARANCE) for pt in arm):
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
                    color=color_of(f.color),
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
                    door=None if door is None else door_spec(door),
                    front=None
                    if f.facade is None or d is not None or lid is not None or door is not None
                    else f.facade.front,
                    panels=()
                    if f.facade is None
                    else tuple(Panel(*pn.at, *pn.size, color_of(pn.color), pn.handle) for pn in f.facade.panels),
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


def _radius(center: Vec2, points: list[Vec2]) -> float:
    """How far the farthest of `points` lies from `center`."""
    return max(math.hypot(px - center[0], py - center[1]) for px, py in points)


def _within(center: Vec2, radius: float, box: Vec2, size: tuple[float, ...]) -> bool:
    """Whether a point within `radius` of `center` can come within DOOR_CLEARANCE of a box (centre,
    size, any turn): False only when none can, so that a layout's door check (inside_turned for
    every outline point, about 50,000 of them for the kitchen's doors) skips the boxes out of reach
    and says what it said before; 1 mm of slack against rounding."""
    gap = math.hypot(size[0], size[1]) / 2 + DOOR_CLEARANCE + radius + 1e-3
    return math.hypot(box[0] - center[0], box[1] - center[1]) <= gap
