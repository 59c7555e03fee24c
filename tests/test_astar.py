"""The occupancy grid and 8-connected A*: optimal octile paths, no corner cutting, smoothing."""

from __future__ import annotations

import heapq
import math

import numpy as np
import pytest

from mhrc.world.astar import SQRT2, Grid, astar, line_free, path_length, smooth
from mhrc.world.occupancy import occupancy
from mhrc.world.scene import LAYOUTS


def _dijkstra(grid: Grid, s: tuple[int, int], g: tuple[int, int]) -> float:
    """Reference shortest 8-connected cost (cells), no corner cutting."""
    b = grid.blocked
    dist = {s: 0.0}
    q = [(0.0, s)]
    while q:
        d, (i, j) = heapq.heappop(q)
        if (i, j) == g:
            return d
        if d > dist[(i, j)]:
            continue
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                ni, nj = i + di, j + dj
                if (di, dj) == (0, 0) or not grid.inside(ni, nj) or b[ni, nj]:
                    continue
                if di and dj and (b[i + di, j] or b[i, j + dj]):
                    continue
                nd = d + (SQRT2 if di and dj else 1.0)
                if nd < dist.get((ni, nj), math.inf):
                    dist[(ni, nj)] = nd
                    heapq.heappush(q, (nd, (ni, nj)))
    return math.inf


def _cells(grid: Grid, pts: list[tuple[float, float]]) -> list[tuple[int, int]]:
    return [grid.cell(*p) for p in pts]


def test_empty_grid_path_is_the_straight_line() -> None:
    grid = Grid.empty(0, 5, 0, 5, 0.05)
    path = astar(grid, (0.5, 0.5), (4.5, 3.5))
    assert path is not None and path[0] == (0.5, 0.5) and path[-1] == (4.5, 3.5)
    assert path_length(path) == pytest.approx(5.0, abs=1e-9)  # smoothed to one segment


@pytest.mark.parametrize("seed", range(6))
def test_raw_path_cost_matches_dijkstra_on_random_grids(seed: int) -> None:
    rng = np.random.default_rng(seed)
    grid = Grid(0.0, 0.0, 1.0, rng.random((30, 24)) < 0.28)
    grid.blocked[1, 1] = grid.blocked[28, 22] = False
    raw = astar(grid, (1.5, 1.5), (28.5, 22.5), smoothed=False)
    best = _dijkstra(grid, (1, 1), (28, 22))
    if raw is None:
        assert best == math.inf
        return
    cells = _cells(grid, raw)
    cost = sum(SQRT2 if (a[0] != b[0] and a[1] != b[1]) else 1.0 for a, b in zip(cells, cells[1:]))
    assert cost == pytest.approx(best)
    for a, b in zip(cells, cells[1:]):
        assert max(abs(a[0] - b[0]), abs(a[1] - b[1])) == 1, "8-connected steps only"
        assert not grid.blocked[b]
        if a[0] != b[0] and a[1] != b[1]:  # diagonal: both side cells free
            assert not grid.blocked[b[0], a[1]] and not grid.blocked[a[0], b[1]]


def test_no_corner_cutting_between_touching_blocks() -> None:
    grid = Grid(0.0, 0.0, 1.0, np.zeros((3, 3), dtype=bool))
    grid.blocked[1, 0] = grid.blocked[0, 1] = True  # (0,0) touches (1,1) only diagonally
    assert astar(grid, (0.5, 0.5), (1.5, 1.5)) is None


def test_a_closed_room_has_no_path() -> None:
    grid = Grid.empty(0, 4, 0, 4, 0.1)
    grid.add_box(2.0, 2.0, 1.2, 1.2)
    grid.blocked[grid.cell(2.0, 2.0)] = False
    i, j = grid.cell(2.0, 2.0)
    grid.blocked[i - 1 : i + 2, j - 1 : j + 2] = False  # a pocket inside the box
    assert astar(grid, (0.3, 0.3), (2.0, 2.0)) is None


def test_smoothing_keeps_paths_free_and_never_longer() -> None:
    grid = Grid.empty(0, 6, 0, 4, 0.05)
    grid.add_box(3.0, 1.2, 0.2, 2.4)  # a wall from the bottom with a gap at the top
    raw = astar(grid, (1.0, 1.0), (5.0, 1.0), smoothed=False)
    assert raw is not None
    short = smooth(grid, raw)
    assert path_length(short) <= path_length(raw) + 1e-9
    assert len(short) < len(raw)
    assert all(line_free(grid, a, b) for a, b in zip(short, short[1:]))


def test_inflation_margin_grows_boxes() -> None:
    grid = Grid.empty(0, 4, 0, 4, 0.05)
    grid.add_box(2.0, 2.0, 1.0, 1.0, margin=0.3)
    assert not grid.free(2.0 + 0.5 + 0.25, 2.0)  # within the margin
    assert grid.free(2.0 + 0.5 + 0.35, 2.0)  # beyond it
    assert not grid.free(-1.0, 2.0)  # off the map


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_every_stand_pose_is_free_and_reachable_from_every_start(scene: str) -> None:
    lay = LAYOUTS[scene]
    grid = occupancy(lay, 0.3)
    for robot, start in lay.starts.items():
        assert grid.free(start[0], start[1]), f"{robot} starts on an obstacle"
        for f in lay.furniture:
            for i, (x, y, _) in enumerate(f.stand_poses):
                assert grid.free(x, y), f"{f.name} stand pose {i} is on an obstacle"
                assert astar(grid, start[:2], (x, y)) is not None, f"{robot} cannot reach {f.name} pose {i}"


def _astar_by_pairs(
    grid: Grid, start: tuple[float, float], goal: tuple[float, float]
) -> list[tuple[float, float]] | None:
    """The search as it was written before it ran on flat indices: over (i, j) pairs, bounds checked."""
    s, g = grid.cell(*start), grid.cell(*goal)
    b = grid.blocked
    if s == g:
        return [start, goal]
    openq: list[tuple[float, float, tuple[int, int]]] = [(0.0, 0.0, s)]
    came: dict[tuple[int, int], tuple[int, int]] = {}
    cost = {s: 0.0}
    steps = [(1, 0, 1.0), (-1, 0, 1.0), (0, 1, 1.0), (0, -1, 1.0)]
    steps += [(1, 1, SQRT2), (1, -1, SQRT2), (-1, 1, SQRT2), (-1, -1, SQRT2)]
    nx, ny = b.shape
    while openq:
        _, c, cur = heapq.heappop(openq)
        if cur == g:
            break
        if c > cost.get(cur, math.inf):
            continue
        i, j = cur
        for di, dj, w in steps:
            ni, nj = i + di, j + dj
            if not (0 <= ni < nx and 0 <= nj < ny) or b[ni, nj]:
                continue
            if di and dj and (b[i + di, j] or b[i, j + dj]):
                continue
            nc = c + w
            if nc < cost.get((ni, nj), math.inf):
                cost[(ni, nj)] = nc
                came[(ni, nj)] = cur
                dx, dy = abs(ni - g[0]), abs(nj - g[1])
                h = (dx + dy) + (SQRT2 - 2) * min(dx, dy)  # added to nc after: (nc + dx + dy) + ... rounds otherwise
                heapq.heappush(openq, (nc + h, nc, (ni, nj)))
    if g not in came:
        return None
    cells = [g]
    while cells[-1] != s:
        cells.append(came[cells[-1]])
    cells.reverse()
    return [start] + [grid.center(*c) for c in cells[1:-1]] + [goal]


@pytest.mark.parametrize("seed", range(8))
def test_the_same_path_as_the_search_over_cell_pairs(seed: int) -> None:
    """Ties included: many equally short paths cross an open grid, and the one chosen decides
    where a robot drives (and so an episode's rows)."""
    rng = np.random.default_rng(seed)
    grid = Grid(-1.0, 2.0, 0.05, rng.random((40, 31)) < (0.05 + 0.05 * seed))
    pts = grid.x0 + rng.random((12, 2)) * np.array(grid.blocked.shape) * grid.res
    for a, b in zip(pts[:6], pts[6:]):
        start = (float(a[0]), float(a[1] - grid.x0 + grid.y0))
        goal = (float(b[0]), float(b[1] - grid.x0 + grid.y0))
        want = _astar_by_pairs(grid, start, goal)
        assert astar(grid, start, goal, smoothed=False) == want
        assert astar(grid, start, goal) == (None if want is None else smooth(grid, want))


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_the_same_paths_in_the_layouts(scene: str) -> None:
    lay = LAYOUTS[scene]
    grid = occupancy(lay, 0.3)
    for start in lay.starts.values():
        for f in lay.furniture:
            for x, y, _ in f.stand_poses:
                assert astar(grid, start[:2], (x, y), smoothed=False) == _astar_by_pairs(grid, start[:2], (x, y))


def test_line_free_samples_as_grid_free_does() -> None:
    rng = np.random.default_rng(3)
    grid = Grid(0.0, 0.0, 0.05, rng.random((30, 30)) < 0.02)
    for _ in range(300):
        a, b = tuple(rng.uniform(-0.2, 1.7, 2)), tuple(rng.uniform(-0.2, 1.7, 2))
        n = max(2, int(math.hypot(b[0] - a[0], b[1] - a[1]) / (grid.res * 0.5)) + 1)
        want = all(grid.free(a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t) for t in np.linspace(0.0, 1.0, n))
        assert line_free(grid, a, b) == want
