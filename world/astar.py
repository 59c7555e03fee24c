"""Occupancy grid and 8-connected A* for mobile bases (octile heuristic, no corner cutting)."""

from __future__ import annotations

import functools
import heapq
import math
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

SQRT2 = math.sqrt(2.0)


@dataclass
class Grid:
    """A boolean occupancy grid over [x0, x0 + w*res) x [y0, y0 + h*res); True = blocked."""

    x0: float
    y0: float
    res: float
    blocked: np.ndarray  # shape (nx, ny)

    @classmethod
    def empty(cls, xmin: float, xmax: float, ymin: float, ymax: float, res: float = 0.05) -> Grid:
        nx, ny = int(math.ceil((xmax - xmin) / res)), int(math.ceil((ymax - ymin) / res))
        return cls(xmin, ymin, res, np.zeros((nx, ny), dtype=bool))

    def cell(self, x: float, y: float) -> tuple[int, int]:
        return int((x - self.x0) / self.res), int((y - self.y0) / self.res)

    def center(self, i: int, j: int) -> tuple[float, float]:
        return self.x0 + (i + 0.5) * self.res, self.y0 + (j + 0.5) * self.res

    def inside(self, i: int, j: int) -> bool:
        return 0 <= i < self.blocked.shape[0] and 0 <= j < self.blocked.shape[1]

    def free(self, x: float, y: float) -> bool:
        i, j = self.cell(x, y)
        return self.inside(i, j) and not self.blocked[i, j]

    def add_box(self, cx: float, cy: float, sx: float, sy: float, yaw: float = 0.0, margin: float = 0.0) -> None:
        """Block a (possibly rotated) rectangle of size sx x sy grown by `margin` on every side."""
        hx, hy = sx / 2 + margin, sy / 2 + margin
        r = math.hypot(hx, hy)
        i0, j0 = self.cell(cx - r, cy - r)
        i1, j1 = self.cell(cx + r, cy + r)
        i0, j0 = max(i0, 0), max(j0, 0)
        i1, j1 = min(i1 + 1, self.blocked.shape[0]), min(j1 + 1, self.blocked.shape[1])
        if i0 >= i1 or j0 >= j1:
            return
        xs = self.x0 + (np.arange(i0, i1) + 0.5) * self.res
        ys = self.y0 + (np.arange(j0, j1) + 0.5) * self.res
        gx, gy = np.meshgrid(xs - cx, ys - cy, indexing="ij")
        c, s = math.cos(yaw), math.sin(yaw)
        lx, ly = c * gx + s * gy, -s * gx + c * gy
        self.blocked[i0:i1, j0:j1] |= (np.abs(lx) <= hx) & (np.abs(ly) <= hy)


def astar(
    grid: Grid, start: tuple[float, float], goal: tuple[float, float], *, smoothed: bool = True
) -> list[tuple[float, float]] | None:
    """Shortest 8-connected path between two free points (cell centres, ends exact), or None.

    With `smoothed`, waypoints whose neighbours see each other in a straight line are dropped.

    The search runs on flat indices into the grid padded with a blocked border (no bounds checks),
    with the octile heuristic of every cell computed at once in numpy. A flat index orders cells as
    their (i, j) pairs do and every cost is the same sum, so it expands the cells, breaks ties and
    returns the path exactly as the search over (i, j) pairs did before it.
    """
    s, g = grid.cell(*start), grid.cell(*goal)
    if s == g:
        return [start, goal]
    nx, ny = grid.blocked.shape
    if not (0 <= s[0] < nx and 0 <= s[1] < ny):
        return None  # a start off the grid has no path
    w = ny + 2  # a padded row
    blocked: list[bool] = np.pad(grid.blocked, 1, constant_values=True).ravel().tolist()
    gi, gj = g
    dx = np.abs(np.arange(-1, nx + 1) - gi)[:, None]
    dy = np.abs(np.arange(-1, ny + 1) - gj)[None, :]
    heuristic: list[float] = ((dx + dy) + (SQRT2 - 2) * np.minimum(dx, dy)).ravel().tolist()
    # (flat offset, cost, the two side cells a diagonal step must not cut between)
    steps = [
        (w, 1.0, 0, 0),
        (-w, 1.0, 0, 0),
        (1, 1.0, 0, 0),
        (-1, 1.0, 0, 0),
        (w + 1, SQRT2, w, 1),
        (w - 1, SQRT2, w, -1),
        (-w + 1, SQRT2, -w, 1),
        (-w - 1, SQRT2, -w, -1),
    ]
    fs = (s[0] + 1) * w + s[1] + 1
    fg = (gi + 1) * w + gj + 1
    if not (0 <= gi < nx and 0 <= gj < ny) or blocked[fg]:
        return None  # never reached: the search would only have exhausted every cell first
    inf = math.inf
    cost = [inf] * len(blocked)
    came = [-1] * len(blocked)
    cost[fs] = 0.0
    openq: list[tuple[float, float, int]] = [(0.0, 0.0, fs)]
    pop, push = heapq.heappop, heapq.heappush
    while openq:
        _, c, cur = pop(openq)
        if cur == fg:
            break
        if c > cost[cur]:
            continue
        for d, wt, side_a, side_b in steps:
            n = cur + d
            if blocked[n]:
                continue
            if side_a and (blocked[cur + side_a] or blocked[cur + side_b]):
                continue  # no corner cutting
            nc = c + wt
            if nc < cost[n]:
                cost[n] = nc
                came[n] = cur
                push(openq, (nc + heuristic[n], nc, n))
    if came[fg] < 0:
        return None
    cells = [fg]
    while cells[-1] != fs:
        cells.append(came[cells[-1]])
    cells.reverse()
    pts = [start] + [grid.center(c // w - 1, c % w - 1) for c in cells[1:-1]] + [goal]
    return smooth(grid, pts) if smoothed else pts


@functools.lru_cache(maxsize=256)
def _fractions(n: int) -> np.ndarray:
    """np.linspace(0, 1, n), read-only (shared by every call)."""
    t = np.linspace(0.0, 1.0, n)
    t.flags.writeable = False
    return t


def line_free(grid: Grid, a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Whether the straight segment a-b crosses only free cells (sampled at half a cell)."""
    n = max(2, int(math.hypot(b[0] - a[0], b[1] - a[1]) / (grid.res * 0.5)) + 1)
    t = _fractions(n)
    # Grid.free of every sample at once: the same float operations, truncated toward zero as int() does
    i = ((a[0] + (b[0] - a[0]) * t - grid.x0) / grid.res).astype(np.int64)
    j = ((a[1] + (b[1] - a[1]) * t - grid.y0) / grid.res).astype(np.int64)
    nx, ny = grid.blocked.shape
    if i.min() < 0 or j.min() < 0 or i.max() >= nx or j.max() >= ny:
        return False
    return not grid.blocked[i, j].any()


def smooth(grid: Grid, pts: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Shortcut the path greedily: keep a waypoint only where the straight line is blocked."""
    out = [pts[0]]
    i = 0
    while i < len(pts) - 1:
        j = len(pts) - 1
        while j > i + 1 and not line_free(grid, pts[i], pts[j]):
            j -= 1
        out.append(pts[j])
        i = j
    return out


def path_length(pts: list[tuple[float, float]]) -> float:
    return sum(math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in pairwise(pts))
