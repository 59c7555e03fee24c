"""What the report's map draws of the house: its bounds, walls, furniture footprints, goal area
and the task's fixtures, from the scene's layout (mhrc.world.layouts)."""

from __future__ import annotations

from dataclasses import dataclass

from mhrc.world.layouts import Layout, get_layout


@dataclass(frozen=True)
class Piece:
    """A piece of furniture as the map draws it: its footprint (centre and size, m), its colour, and
    an openable one's footprint with its drawer pulled out (centre x, y and size x, y)."""

    name: str
    kind: str
    style: str
    x: float
    y: float
    sx: float
    sy: float
    openable: bool
    color: tuple[float, ...]
    open_footprint: tuple[float, float, float, float] | None = None


@dataclass(frozen=True)
class Fixture:
    """A task's fixture on Bob's table, where the snapshots put it."""

    name: str
    x: float
    y: float


@dataclass(frozen=True)
class SceneMap:
    """What the map draws of the house (mhrc.world's Layout, in the map's terms)."""

    name: str
    bounds: tuple[float, float, float, float]  # xmin, xmax, ymin, ymax
    walls: tuple[tuple[float, float, float, float], ...]  # centre x, y and size x, y each
    furniture: list[Piece]
    bob_table: str
    bob_base: tuple[float, float]  # Bob's arm base on his table (x, y)
    goal_area: tuple[float, float, float, float]  # centre x, y and size x, y
    fixtures: list[Fixture]
    tallest: float  # the highest top of any furniture (m): what a flier clears

    def centre(self, name: str | None) -> tuple[float, float] | None:
        """The centre of the furniture `name`, if the house has it."""
        return next(((float(f.x), float(f.y)) for f in self.furniture if f.name == name), None)


def scene_map(scene: str, fixtures: dict[str, tuple[float, float]], warnings: list[str]) -> SceneMap | None:
    """What the map draws of the house: bounds, walls, furniture footprints, goal area, fixtures."""
    try:
        layout: Layout = get_layout(scene)
    except Exception as exc:  # an unknown name or a layout file that is gone: draw what the snapshots show
        warnings.append(f"scene {scene!r} could not be loaded ({exc}): the house is not drawn")
        return None
    furniture = []
    for f in layout.furniture:
        opened = f.open_drawer_footprint()
        furniture.append(
            Piece(
                name=f.name,
                kind=f.kind,
                style=f.style,
                x=f.center[0],
                y=f.center[1],
                sx=f.size[0],
                sy=f.size[1],
                openable=f.container is not None,
                color=tuple(f.color),
                open_footprint=None if opened is None else (*opened[0], *opened[1]),
            )
        )
    return SceneMap(
        name=layout.name,
        bounds=layout.bounds,
        walls=layout.walls,
        furniture=furniture,
        bob_table=layout.bob_table,
        bob_base=layout.bob_base[:2],
        goal_area=layout.goal_area,
        fixtures=[Fixture(n, x, y) for n, (x, y) in sorted(fixtures.items())],
        tallest=max((f.size[2] for f in layout.furniture), default=0.0),
    )
