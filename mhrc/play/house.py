"""The play page's map of the house: the layout's walls and furniture (fixed data the robot is
given from the start: every robot's scene graph holds all the furniture) as an SVG; what moves
(the robot, the objects it knows of) the page's script draws from each observation.

Each furniture label carries its piece's box (`data-box`: x y width height in the SVG's units):
the page's script sizes the labels to read at a fixed size on screen and places each where it
overlaps no other label (page.js, `placeLabels`). Colours are `fill` attributes, not `style`:
the page's Content-Security-Policy allows no inline style attribute."""

from __future__ import annotations

import math

from mhrc.core.protocol import Observation
from mhrc.viewer.page import SCALE, MapFrame
from mhrc.viewer.scene_map import scene_map
from mhrc.viewer.wording import html_text as _e
from mhrc.world.layouts import LAYOUTS


def scene_of(obs: Observation) -> str | None:
    """The shipped layout whose furniture stands where the robot knows it (for a world started
    elsewhere, whose scene the page was not told); None when none matches."""
    known = {f.name: f.position[:2] for f in obs.furniture if f.stand_poses}
    for name, layout in LAYOUTS.items():
        there = {f.name: f.center[:2] for f in layout.furniture}
        if known and all(n in there and math.dist(xy, there[n]) < 0.05 for n, xy in known.items()):
            return name
    return None


def _label(name: str, x: float, y: float, box: str) -> str:
    return f'<text class="fname" data-label="furniture" data-box="{box}" x="{x}" y="{y}">{_e(name)}</text>'


def house_svg(scene: str | None, obs: Observation) -> str:
    """The house as an SVG element with the data the script needs to draw on it."""
    warnings: list[str] = []
    sc = scene_map(scene, {}, warnings) if scene else None
    if sc is None:  # no layout: the furniture as the robot knows it, as dots
        xs = [f.position[0] for f in obs.furniture] or [0.0]
        ys = [f.position[1] for f in obs.furniture] or [0.0]
        bounds = (min(xs) - 1, max(xs) + 1, min(ys) - 1, max(ys) + 1)
    else:
        b = sc.bounds
        bounds = (b[0] - 0.3, b[1] + 0.3, b[2] - 0.3, b[3] + 0.3)
    xmin, xmax, ymin, ymax = bounds
    w, h = round((xmax - xmin) * SCALE), round((ymax - ymin) * SCALE)

    frame = MapFrame(xmin, ymax)
    px, py, rect = frame.px, frame.py, frame.rect

    parts: list[str] = []
    if sc is not None:
        b = sc.bounds
        parts.append(rect((b[0] + b[1]) / 2, (b[2] + b[3]) / 2, b[1] - b[0], b[3] - b[2], "floor"))
        for f in sc.furniture:
            r, g, b_ = (int(255 * c) for c in f.color[:3])
            parts.append(
                rect(
                    f.x,
                    f.y,
                    f.sx,
                    f.sy,
                    "furniture",
                    f' data-name="{_e(f.name)}" fill="rgb({r},{g},{b_})"',
                )
            )
        for wx, wy, wsx, wsy in sc.walls:
            parts.append(rect(wx, wy, wsx, wsy, "wall"))
        for f in sc.furniture:
            box = f"{px(f.x - f.sx / 2)} {py(f.y + f.sy / 2)} {f.sx * SCALE:.1f} {f.sy * SCALE:.1f}"
            parts.append(_label(f.name, px(f.x), py(f.y), box))
    else:
        for fv in obs.furniture:
            x, y = px(fv.position[0]), py(fv.position[1])
            parts.append(f'<circle class="furniture" cx="{x}" cy="{y}" r="6" data-name="{_e(fv.name)}"/>')
            parts.append(_label(fv.name, x, y, f"{x - 6} {y - 6} 12 12"))
    return (
        f'<svg id="map" xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {w} {h}" data-xmin="{xmin}" data-ymax="{ymax}" '
        f'data-scale="{SCALE}" data-scene="{_e(scene or "")}"><g id="house">{"".join(parts)}</g><g id="dyn"></g></svg>'
    )
