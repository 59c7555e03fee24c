"""The base planners' occupancy grid of a layout: walls and furniture footprints, grown by a
margin. Data only, no simulator: placing a team and checking a layout need it before anything is
built (world/scene.py builds the bodies and this grid together)."""

from __future__ import annotations

import math

import numpy as np

from .astar import Grid
from .furniture import Layout, door_sweep


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
