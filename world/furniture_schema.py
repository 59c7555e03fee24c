"""One piece of furniture in a layout file (`furniture` entries of `scenes/<name>.json`): the
pydantic models of the entry and its drawer, lid, door and facade, every field and every rule
that concerns the piece alone checked (a drawer fits its unit, slots lie on its top or inside
it, a colour is known), and the floor it covers open (`swept_footprint`). The format is
documented in layouts.py; what a whole layout must be (reach, clearance, overlaps) is checked
in layout_schema.py, which builds these into the specs of furniture.py.

Errors are ValueErrors naming the field.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from .assets import Color, CupboardGeometry, DrawerGeometry
from .colors import FURNITURE_COLORS
from .furniture import DoorSpec, Vec2, door_footprint, drawer_footprint, inside

STAND_OFFSET = 0.45  # base centre to furniture edge at a stand pose
HALF_PI = math.pi / 2

Name = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=40)]
Positive = Annotated[float, Field(gt=0)]
Pose = tuple[float, float, float]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class StandSide(Strict):
    side: Literal["north", "south", "east", "west"]
    at: float = Field(description="x (north/south side) or y (east/west side) of the pose")


class DrawerFile(Strict):
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


class LidFile(Strict):
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


class DoorFile(Strict):
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


def color_of(color: ColorField) -> Color:
    return FURNITURE_COLORS[color] if isinstance(color, str) else color


class PanelFile(Strict):
    at: Vec2 = Field(description="centre: across the front (to the right of someone facing it) and height")
    size: tuple[Positive, Positive] = Field(description="width and height")
    color: ColorField = "white"
    handle: Literal["none", "left", "right", "top"] = "none"

    @model_validator(mode="after")
    def _color_known(self) -> PanelFile:
        if (err := _color_error(self.color)) is not None:
            raise ValueError(f"color: {err}")
        return self


class FacadeFile(Strict):
    front: Vec2 | None = Field(None, description="the side the front faces; a container's is its axis")
    panels: list[PanelFile] = Field(min_length=1)

    @model_validator(mode="after")
    def _front(self) -> FacadeFile:
        if self.front is not None and (err := _axis_error(self.front)) is not None:
            raise ValueError(f"front: {err}")
        return self


class FurnitureFile(Strict):
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
            return door_footprint(self.center, self.size, door_spec(self.door))
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


def door_spec(door: DoorFile) -> DoorSpec:
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
