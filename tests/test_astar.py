"""The occupancy grid and 8-connected A*: optimal octile paths, no corner cutting, smoothing."""

from __future__ import annotations

import heapq
import math

import numpy as np
import pytest

from mhrc.world.astar import SQRT2, Grid, astar, line_free, path_length, smooth
from mhrc.world.scene import LAYOUTS, occupancy


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
