"""Procedural URDFs built from primitives (walls, furniture, drawer units, the tray, objects,
Alice's chassis, the drone), written to a temporary directory that lives as long as its `AssetDir`.

Every body's origin is on the floor (or, for objects, at the body's centre), axis-aligned, so
the scene can place it with a plain position and yaw.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

Color = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Box:
    """One box of a link: centre and full size in the link frame."""

    center: Vec3
    size: Vec3
    color: Color
    collide: bool = True


@dataclass(frozen=True)
class Shape:
    """The primitive an object is made of: box (sx, sy, sz), cylinder (r, r, h), sphere (r, r, 2r)
    or prism (sx, sy, sz: a triangular prism lying on its sx x sy face, ridge along y on top)."""

    kind: str
    size: Vec3

    @property
    def height(self) -> float:
        return self.size[2]

    @property
    def footprint(self) -> tuple[float, float]:
        """Full extent along x and y when the object stands upright with yaw 0."""
        if self.kind in ("box", "prism"):
            return self.size[0], self.size[1]
        return 2 * self.size[0], 2 * self.size[0]


def _f(v: float) -> str:
    return f"{v:.5g}"


def _v(v: Vec3) -> str:
    return " ".join(_f(c) for c in v)


def _material(color: Color) -> str:
    return f'<material name="c{abs(hash(color)) % 10**8}"><color rgba="{_v(color[:3])} {_f(color[3])}"/></material>'


def _boxes_xml(boxes: list[Box]) -> str:
    parts = []
    for b in boxes:
        geom = f'<origin xyz="{_v(b.center)}"/><geometry><box size="{_v(b.size)}"/></geometry>'
        parts.append(f"<visual>{geom}{_material(b.color)}</visual>")
        if b.collide:
            parts.append(f"<collision>{geom}</collision>")
    return "\n".join(parts)


def _inertial(mass: float, center: Vec3 = (0.0, 0.0, 0.0)) -> str:
    i = max(mass, 1e-3) * 0.01
    return (
        f'<inertial><origin xyz="{_v(center)}"/><mass value="{_f(mass)}"/>'
        f'<inertia ixx="{_f(i)}" iyy="{_f(i)}" izz="{_f(i)}" ixy="0" ixz="0" iyz="0"/></inertial>'
    )


def link_urdf(name: str, boxes: list[Box], mass: float = 0.0) -> str:
    """A single-link body made of boxes."""
    return f'<?xml version="1.0"?>\n<robot name="{name}">\n<link name="base">{_inertial(mass)}\n{_boxes_xml(boxes)}\n</link>\n</robot>\n'


# --------------------------------------------------------------------------- furniture


def wall_boxes(size: Vec3, color: Color) -> list[Box]:
    return [Box((0.0, 0.0, size[2] / 2), size, color)]


def table_boxes(size: Vec3, color: Color, slab: float = 0.04, leg: float = 0.06) -> list[Box]:
    """A top slab on four legs; the top surface is at size[2]."""
    sx, sy, h = size
    boxes = [Box((0.0, 0.0, h - slab / 2), (sx, sy, slab), color)]
    dark = (color[0] * 0.7, color[1] * 0.7, color[2] * 0.7, color[3])
    for ix in (-1, 1):
        for iy in (-1, 1):
            c = (ix * (sx / 2 - leg), iy * (sy / 2 - leg), (h - slab) / 2)
            boxes.append(Box(c, (leg, leg, h - slab), dark))
    return boxes


@dataclass(frozen=True)
class Panel:
    """A visual-only panel on a furniture front (an appliance door, a window, a fascia), in the
    front's frame: `u` across (to the right of someone facing the front), `z` up, both its centre."""

    u: float
    z: float
    width: float
    height: float
    color: Color
    handle: str = "none"  # none | left | right | top: a bar near that edge


PANEL_DEPTH = 0.012  # how far a panel stands out of the front
HANDLE_GREY = (0.3, 0.3, 0.3, 1.0)


def facade_boxes(depth: float, panels: tuple[Panel, ...] | list[Panel]) -> list[Box]:
    """Panels (and their handles) on the front face of a body `depth` deep in its own frame,
    where the front faces -y; each later panel stands a little further out, over the ones before.
    Looks only: none of them collides."""
    boxes = []
    for i, pn in enumerate(panels):
        out = depth / 2 + PANEL_DEPTH / 2 + 0.004 * i
        boxes.append(Box((pn.u, -out, pn.z), (pn.width, PANEL_DEPTH, pn.height), pn.color, collide=False))
        bar_y = -(out + PANEL_DEPTH / 2 + 0.015)
        if pn.handle in ("left", "right"):
            side = -1 if pn.handle == "left" else 1
            length = min(0.5, 0.4 * pn.height)
            boxes.append(
                Box(
                    (pn.u + side * (pn.width / 2 - 0.05), bar_y, pn.z),
                    (0.025, 0.03, length),
                    HANDLE_GREY,
                    collide=False,
                )
            )
        elif pn.handle == "top":
            length = min(0.4, 0.5 * pn.width)
            boxes.append(
                Box((pn.u, bar_y, pn.z + pn.height / 2 - 0.05), (length, 0.03, 0.025), HANDLE_GREY, collide=False)
            )
    return boxes


def block_boxes(size: Vec3, color: Color) -> list[Box]:
    """A solid block (counter, cabinet) whose top surface is at size[2]."""
    return [Box((0.0, 0.0, size[2] / 2), size, color)]


def sofa_boxes(size: Vec3, color: Color, back: float = 0.15) -> list[Box]:
    """A seat block of height size[2] and a backrest along the +x side."""
    sx, sy, h = size
    return [
        Box((0.0, 0.0, h / 2), (sx, sy, h), color),
        Box((sx / 2 + back / 2, 0.0, (h + 0.4) / 2), (back, sy, h + 0.4), color),
    ]


def jointed_urdf(
    name: str, carcass: list[Box], part: str, boxes: list[Box], joint: str, origin: Vec3, axis: Vec3, upper: float
) -> str:
    """A fixed carcass and one moving part (a drawer, a lid) on a joint opening from 0 to `upper`."""
    return f"""<?xml version="1.0"?>
<robot name="{name}">
<link name="carcass">{_inertial(0.0)}
{_boxes_xml(carcass)}
</link>
<link name="{part}">{_inertial(1.0)}
{_boxes_xml(boxes)}
</link>
<joint name="{part}_joint" type="{joint}">
<parent link="carcass"/><child link="{part}"/>
<origin xyz="{_v(origin)}"/><axis xyz="{_v(axis)}"/>
<limit lower="0" upper="{_f(upper)}" effort="100" velocity="1"/>
</joint>
</robot>
"""


@dataclass(frozen=True)
class DrawerGeometry:
    """A drawer unit in its own frame: the drawer slides out along -y (the front)."""

    width: float  # along x
    depth: float  # along y
    height: float
    travel: float
    inner: Vec3  # drawer inside: sx, sy, wall height
    floor: float  # z of the drawer's floor surface
    wall: float = 0.02
    handle_out: float = 0.045  # how far the handle bar stands out of the drawer's front

    @property
    def drawer_origin(self) -> Vec3:
        """The drawer link's origin (centre of its floor surface) with the drawer closed."""
        front = -self.depth / 2
        return (0.0, front + self.wall + self.inner[1] / 2, self.floor)

    @property
    def handle(self) -> Vec3:
        """Top centre of the handle bar, in the drawer link's frame."""
        return (0.0, -(self.inner[1] / 2 + self.wall + self.handle_out), self.inner[2] - 0.01)


def drawer_unit_urdf(name: str, g: DrawerGeometry, color: Color, facade: list[Box] | None = None) -> str:
    """A carcass (plinth, top, sides, back) and a drawer on a prismatic joint, handle in front;
    `facade`: visual-only boxes on the carcass (see `facade_boxes`)."""
    t = g.wall
    w, d, h = g.width, g.depth, g.height
    cavity_lo = g.floor - t  # the drawer's floor board sits on the plinth
    top_lo = g.floor + g.inner[2] + 0.02
    carcass = [
        Box((0.0, 0.0, cavity_lo / 2), (w, d, cavity_lo), color),  # plinth
        Box((0.0, 0.0, (top_lo + h) / 2), (w, d, h - top_lo), color),  # top
        Box((-(w / 2 - t / 2), 0.0, (cavity_lo + top_lo) / 2), (t, d, top_lo - cavity_lo), color),
        Box((w / 2 - t / 2, 0.0, (cavity_lo + top_lo) / 2), (t, d, top_lo - cavity_lo), color),
        Box((0.0, d / 2 - t / 2, (cavity_lo + top_lo) / 2), (w - 2 * t, t, top_lo - cavity_lo), color),
        *(facade or []),
    ]
    sx, sy, wall_h = g.inner
    panel = top_lo - g.floor - 0.005  # the front panel's top, above the drawer floor
    wood = (color[0] * 0.85, color[1] * 0.8, color[2] * 0.7, 1.0)
    drawer = [
        Box((0.0, 0.0, -t / 2), (sx + 2 * t, sy + 2 * t, t), wood),  # floor board
        Box((-(sx / 2 + t / 2), 0.0, wall_h / 2), (t, sy, wall_h), wood),
        Box((sx / 2 + t / 2, 0.0, wall_h / 2), (t, sy, wall_h), wood),
        Box((0.0, sy / 2 + t / 2, wall_h / 2), (sx + 2 * t, t, wall_h), wood),
        Box((0.0, -(sy / 2 + t / 2), (panel - t) / 2), (w - 0.01, t, panel + t), color),  # front panel
        Box(
            (0.0, g.handle[1] + (g.handle_out + 0.005) / 2, g.handle[2] - 0.01),
            (0.04, g.handle_out + 0.005, 0.02),
            (0.3, 0.3, 0.3, 1.0),
        ),  # handle stem
        Box((0.0, g.handle[1], g.handle[2] - 0.01), (0.24, 0.03, 0.02), (0.3, 0.3, 0.3, 1.0)),  # handle bar
    ]
    return jointed_urdf(name, carcass, "drawer", drawer, "prismatic", g.drawer_origin, (0.0, -1.0, 0.0), g.travel)


def slab_boxes(sx: float, sy: float, t: float, color: Color) -> list[Box]:
    """A flat slab (a panel, a cutting board) whose top surface is at z = t."""
    return [Box((0.0, 0.0, t / 2), (sx, sy, t), color)]


@dataclass(frozen=True)
class ChestGeometry:
    """A chest in its own frame: an open-topped box whose lid hinges up at the back (+y) edge;
    the front faces -y. The lid link's origin is on the hinge line; closed, it lies along -y."""

    width: float  # along x
    depth: float  # along y
    height: float  # top of the closed lid
    floor: float  # z of the inside floor
    angle: float  # rad the lid opens to
    wall: float = 0.03
    lid: float = 0.02  # lid thickness

    @property
    def rim(self) -> float:
        return self.height - self.lid

    @property
    def inner(self) -> Vec3:
        return (self.width - 2 * self.wall, self.depth - 2 * self.wall, self.rim - self.floor)

    @property
    def hinge(self) -> Vec3:
        return (0.0, self.depth / 2, self.rim)

    @property
    def handle(self) -> Vec3:
        """Top centre of the handle tab at the lid's front edge, in the lid link's frame."""
        return (0.0, -(self.depth + 0.025), self.lid)


def chest_urdf(name: str, g: ChestGeometry, color: Color, facade: list[Box] | None = None) -> str:
    """Walls and floor of an open box, and a lid on a revolute joint at its back edge;
    `facade`: visual-only boxes on the box (see `facade_boxes`)."""
    w, d, t = g.width, g.depth, g.wall
    rim = g.rim
    carcass = [
        Box((0.0, 0.0, g.floor / 2), (w, d, g.floor), color),  # plinth up to the inside floor
        Box((-(w / 2 - t / 2), 0.0, rim / 2), (t, d, rim), color),
        Box((w / 2 - t / 2, 0.0, rim / 2), (t, d, rim), color),
        Box((0.0, -(d / 2 - t / 2), rim / 2), (w - 2 * t, t, rim), color),
        Box((0.0, d / 2 - t / 2, rim / 2), (w - 2 * t, t, rim), color),
        *(facade or []),
    ]
    dark = (color[0] * 0.75, color[1] * 0.75, color[2] * 0.75, 1.0)
    hx, hy, hz = g.handle
    lid = [
        Box((0.0, -d / 2, g.lid / 2), (w, d, g.lid), dark),
        Box((hx, hy, hz - g.lid / 2), (0.24, 0.05, g.lid), (0.3, 0.3, 0.3, 1.0)),  # handle tab
    ]
    return jointed_urdf(name, carcass, "lid", lid, "revolute", g.hinge, (-1.0, 0.0, 0.0), g.angle)


@dataclass(frozen=True)
class CupboardGeometry:
    """A cupboard (a kitchen cabinet, a microwave) in its own frame, front along -y: a solid body
    with one cavity behind a side-hinged door. The door covers `u0` to `u0 + door_width` across
    the front (x), `floor` to `ceiling` high; it hinges on a vertical axis at its `hinge` edge
    (left: -x, right: +x, for someone facing the front) and swings out to `angle` rad. The door
    link's origin is on the hinge line at the front face; closed, the door lies along x."""

    width: float  # along x
    depth: float  # along y
    height: float
    u0: float  # x of the door's left edge
    door_width: float
    hinge: str  # left | right
    floor: float  # z of the cavity's floor
    ceiling: float  # z of the cavity's top
    angle: float  # rad the door opens to
    handle_out: float = 0.1  # how far the handle bar stands out of the door
    wall: float = 0.02
    door: float = 0.02  # door thickness

    @property
    def side(self) -> float:
        """+1 when the door extends towards +x from its hinge (a left hinge), else -1."""
        return 1.0 if self.hinge == "left" else -1.0

    @property
    def hinge_point(self) -> Vec3:
        return (self.u0 if self.hinge == "left" else self.u0 + self.door_width, -self.depth / 2, 0.0)

    @property
    def axis(self) -> Vec3:
        """Positive rotation swings the free edge out of the front (towards -y)."""
        return (0.0, 0.0, -self.side)

    @property
    def cavity(self) -> tuple[Vec3, Vec3]:
        """Centre (of its floor) and size of the cavity, in the body frame."""
        x0, x1 = self.u0 + self.wall, self.u0 + self.door_width - self.wall
        y0, y1 = -self.depth / 2, self.depth / 2 - self.wall
        return ((x0 + x1) / 2, (y0 + y1) / 2, self.floor), (x1 - x0, y1 - y0, self.ceiling - self.floor)

    @property
    def handle(self) -> Vec3:
        """Top centre of the handle bar near the door's free edge, in the door link's frame."""
        return (self.side * (self.door_width - 0.1), -(self.door + self.handle_out), self.ceiling - 0.06)

    @property
    def swing_radius(self) -> float:
        """How far from the hinge line the door and its handle reach."""
        return math.hypot(self.door_width, self.door + self.handle_out + 0.015)


def cupboard_urdf(name: str, g: CupboardGeometry, color: Color, facade: list[Box] | None = None) -> str:
    """A solid carcass around one cavity and its door on a revolute joint (vertical axis) at the
    hinge edge, a handle bar near the free edge; `facade`: visual-only boxes on the carcass."""
    w, d, t = g.width, g.depth, g.wall
    x0, x1 = g.u0 + t, g.u0 + g.door_width - t  # the cavity across
    mid = (g.floor + g.ceiling) / 2
    span = g.ceiling - g.floor
    carcass = [
        Box((0.0, 0.0, g.floor / 2), (w, d, g.floor), color),  # plinth up to the cavity floor
        Box((0.0, 0.0, (g.ceiling + g.height) / 2), (w, d, g.height - g.ceiling), color),  # top
        Box(((-w / 2 + x0) / 2, 0.0, mid), (x0 + w / 2, d, span), color),  # solid left of the cavity
        Box(((x1 + w / 2) / 2, 0.0, mid), (w / 2 - x1, d, span), color),  # solid right of it
        Box(((x0 + x1) / 2, d / 2 - t / 2, mid), (x1 - x0, t, span), color),  # back
        *(facade or []),
    ]
    s, hw = g.side, g.door_width
    hx, hy, hz = g.handle
    dark = (color[0] * 0.85, color[1] * 0.85, color[2] * 0.85, 1.0)
    grey = (0.3, 0.3, 0.3, 1.0)
    door = [
        Box((s * hw / 2, -g.door / 2, mid), (hw - 0.004, g.door, span), dark),
        Box((hx, hy + (g.handle_out + 0.005) / 2, hz - 0.01), (0.03, g.handle_out + 0.005, 0.02), grey),  # stem
        Box((hx, hy, hz - 0.01), (0.14, 0.03, 0.02), grey),  # bar
    ]
    return jointed_urdf(name, carcass, "door", door, "revolute", g.hinge_point, g.axis, g.angle)


def tray_boxes(sx: float, sy: float, color: Color, rim: float = 0.04, t: float = 0.01) -> list[Box]:
    """A flat tray with low rims; its floor surface is at z = t."""
    return [
        Box((0.0, 0.0, t / 2), (sx, sy, t), color),
        Box((0.0, sy / 2 - t / 2, rim / 2), (sx, t, rim), color),
        Box((0.0, -(sy / 2 - t / 2), rim / 2), (sx, t, rim), color),
        Box((sx / 2 - t / 2, 0.0, rim / 2), (t, sy, rim), color),
        Box((-(sx / 2 - t / 2), 0.0, rim / 2), (t, sy, rim), color),
    ]


# --------------------------------------------------------------------------- objects and robots


def object_urdf(name: str, shape: Shape, color: Color, mass: float = 0.1) -> str:
    """A graspable object: one primitive centred on the body origin."""
    if shape.kind == "box":
        geometry = f'<box size="{_v(shape.size)}"/>'
    elif shape.kind == "cylinder":
        geometry = f'<cylinder radius="{_f(shape.size[0])}" length="{_f(shape.size[2])}"/>'
    elif shape.kind == "sphere":
        geometry = f'<sphere radius="{_f(shape.size[0])}"/>'
    elif shape.kind == "prism":
        geometry = f'<mesh filename="{name}.obj"/>'
    else:
        raise ValueError(f"unknown shape {shape.kind!r}: use box, cylinder, sphere or prism")
    return f"""<?xml version="1.0"?>
<robot name="{name}">
<link name="base">{_inertial(mass)}
<visual><geometry>{geometry}</geometry>{_material(color)}</visual>
<collision><geometry>{geometry}</geometry></collision>
</link>
</robot>
"""


def prism_obj(size: Vec3) -> str:
    """A triangular prism as a Wavefront OBJ mesh, centred on the origin."""
    a, b, h = size[0] / 2, size[1] / 2, size[2] / 2
    verts = [(-a, -b, -h), (a, -b, -h), (a, b, -h), (-a, b, -h), (0.0, -b, h), (0.0, b, h)]
    faces = [(1, 3, 2), (1, 4, 3), (1, 2, 5), (2, 3, 6), (2, 6, 5), (3, 4, 6), (4, 1, 5), (4, 5, 6)]
    lines = [f"v {_f(x)} {_f(y)} {_f(z)}" for x, y, z in verts] + [f"f {i} {j} {k}" for i, j, k in faces]
    return "\n".join(lines) + "\n"


def write_object(assets_dir: AssetDir, name: str, shape: Shape, color: Color) -> str:
    """Write an object's URDF (and its mesh, for a prism); return the URDF's path."""
    if shape.kind == "prism":
        assets_dir.write_file(f"{name}.obj", prism_obj(shape.size))
    return assets_dir.write(f"object_{name}", object_urdf(name, shape, color))


def chassis_boxes(length: float, width: float, height: float, color: Color) -> list[Box]:
    """A wheeled box chassis; the arm mounts on its top."""
    boxes = [Box((0.0, 0.0, 0.06 + (height - 0.06) / 2), (length, width, height - 0.06), color)]
    black = (0.1, 0.1, 0.1, 1.0)
    for ix in (-1, 1):
        for iy in (-1, 1):
            boxes.append(
                Box((ix * (length / 2 - 0.09), iy * (width / 2 - 0.02), 0.06), (0.14, 0.05, 0.12), black, collide=False)
            )
    return boxes


def drone_boxes(color: Color) -> list[Box]:
    """A quadrotor seen as boxes, its origin at its centre: a body, two crossed arms, four rotor
    discs at their tips and a camera under the nose. Nothing collides (it flies above what
    the simulation steps)."""
    dark = (0.15, 0.15, 0.15, 1.0)
    span = 0.32  # arm tip to arm tip
    boxes = [
        Box((0.0, 0.0, 0.0), (0.16, 0.16, 0.06), color, collide=False),
        Box((0.0, 0.0, 0.0), (span, 0.03, 0.02), dark, collide=False),
        Box((0.0, 0.0, 0.0), (0.03, span, 0.02), dark, collide=False),
        Box((0.07, 0.0, -0.045), (0.04, 0.04, 0.03), dark, collide=False),
    ]
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        boxes.append(Box((dx * span / 2, dy * span / 2, 0.025), (0.14, 0.14, 0.008), (0.7, 0.7, 0.75, 0.8), False))
    return boxes


class AssetDir:
    """A temporary directory of generated URDFs, removed by `close()`."""

    def __init__(self) -> None:
        self.path = Path(tempfile.mkdtemp(prefix="mhrc-assets-"))
        self._written: dict[str, str] = {}

    def write(self, name: str, urdf: str) -> str:
        """Write `urdf` as `<name>.urdf` (once per name) and return its absolute path."""
        path = self.path / f"{name}.urdf"
        if self._written.get(name) != urdf:
            path.write_text(urdf, encoding="utf-8")
            self._written[name] = urdf
        return str(path)

    def write_file(self, filename: str, text: str) -> str:
        """Write another file (a mesh) beside the URDFs; return its absolute path."""
        path = self.path / filename
        path.write_text(text, encoding="utf-8")
        return str(path)

    def close(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)
