"""Where a team's mobile robots start (issue 33: a world for several robots).

Each mobile robot starts where its team spec says (`start = [x, y, yaw]`), else where the layout
names it (`starts`), else at a pose chosen from the seed among free floor cells. A free cell is
one the ground bases' occupancy grid leaves free (walls, furniture, open drawers and the floor
doors sweep, grown by the team's widest ground footprint: the grid ground bases navigate on),
in the floor region that reaches Bob's table (no walled-off pocket), clear of every stand pose
(a robot starting there would occupy it) and of every other robot's start (their footprints
apart). A drone starts hovering above such a cell. The choice depends on the seed and the
layout alone, robot after robot in the team's order: the same seed gives the same poses.

A start the spec or the layout gives is checked too: on free floor (in free air, for a flier)
and apart from the other starts. The world refuses the team (TeamError NO_ROOM, one line) when
a given start is not, or when no free cell is left for a robot.
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from mhrc.core.team import TeamError, TeamProblem, TeamSpec

from .astar import Grid
from .furniture import Layout
from .kinds import KINDS, RobotKind
from .occupancy import occupancy

__all__ = ["START_GAP", "STAND_CLEARANCE", "check_placement", "floor_margin", "place_team", "reachable"]

Pose = tuple[float, float, float]

START_GAP = 0.1  # m between two robots' footprints where they start
STAND_CLEARANCE = 0.5  # m from a chosen start to every stand pose: a robot starting there would occupy it


def reachable(grid: Grid, seeds: list[tuple[float, float]]) -> np.ndarray:
    """The free cells of `grid` a base can reach from any of `seeds` (a flood fill, 4-connected:
    the same cells as A*'s 8-connected moves without corner cutting)."""
    free = ~grid.blocked
    reached = np.zeros_like(free)
    for x, y in seeds:
        i, j = grid.cell(x, y)
        if grid.inside(i, j) and free[i, j]:
            reached[i, j] = True
    while True:
        grown = reached.copy()
        grown[1:, :] |= reached[:-1, :]
        grown[:-1, :] |= reached[1:, :]
        grown[:, 1:] |= reached[:, :-1]
        grown[:, :-1] |= reached[:, 1:]
        grown &= free
        if (grown == reached).all():
            return reached
        reached = grown


def _apart(kind: RobotKind, xy: tuple[float, float], others: list[tuple[str, RobotKind, Pose]]) -> str | None:
    """The first robot of `others` whose footprint comes within START_GAP of one of `kind` at `xy`."""
    for name, k, (x, y, _) in others:
        if math.hypot(x - xy[0], y - xy[1]) < kind.footprint + k.footprint + START_GAP:
            return name
    return None


def place_team(layout: Layout, team: TeamSpec, seed: int, grid: Grid) -> dict[str, Pose]:
    """Every mobile robot's start pose, by name (see the module docstring); `grid` is the ground
    bases' occupancy grid of the episode. TeamError NO_ROOM when the team cannot be placed."""
    kinds = {r.name: KINDS[r.kind] for r in team.robots}
    mobile = [r for r in team.robots if kinds[r.name].mobile]
    air = occupancy(layout, max(k.footprint for k in kinds.values()), furniture=False)
    placed: list[tuple[str, RobotKind, Pose]] = []
    for r in mobile:  # the starts given first: a chosen one keeps clear of them all
        given = r.start if r.start is not None else layout.starts.get(r.name)
        if given is None:
            continue
        kind, (x, y, _) = kinds[r.name], given
        where = "the team" if r.start is not None else f"the {layout.name} layout"
        if not (air if kind.flies else grid).free(x, y):
            raise TeamError(
                TeamProblem.NO_ROOM,
                f"--team {team.name}: {r.name}'s start ({x:g}, {y:g}) from {where} is on an obstacle or off the map",
            )
        if (other := _apart(kind, (x, y), placed)) is not None:
            raise TeamError(
                TeamProblem.NO_ROOM,
                f"--team {team.name}: {r.name}'s start ({x:g}, {y:g}) from {where} is too close to {other}'s start",
            )
        placed.append((r.name, kind, (float(x), float(y), float(given[2]))))
    choose = [r for r in mobile if r.name not in {n for n, _, _ in placed}]
    if choose:
        home = [(sx, sy) for sx, sy, _ in (layout.get(layout.bob_table) or layout.furniture[0]).stand_poses]
        stands = [(sx, sy) for f in layout.furniture for sx, sy, _ in f.stand_poses]
        floor = reachable(grid, home)
        if not floor.any():  # Bob's table has no free stand pose: the floor any stand pose reaches
            floor = reachable(grid, stands)
        xs = grid.x0 + (np.arange(grid.blocked.shape[0]) + 0.5) * grid.res
        ys = grid.y0 + (np.arange(grid.blocked.shape[1]) + 0.5) * grid.res
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        for sx, sy in stands:
            floor &= np.hypot(gx - sx, gy - sy) >= STAND_CLEARANCE
        rng = np.random.default_rng([seed, zlib.crc32(layout.name.encode()), 0x53544152])
        for r in choose:
            kind = kinds[r.name]
            free = floor.copy()
            for _, k, (ox, oy, _) in placed:
                free &= np.hypot(gx - ox, gy - oy) >= kind.footprint + k.footprint + START_GAP
            cells = np.argwhere(free)
            if len(cells) == 0:
                raise TeamError(
                    TeamProblem.NO_ROOM,
                    f"--team {team.name}: the {layout.name} layout has no free floor left to start {r.name} "
                    f"({len(placed)} robots placed); give it a start in the team file (start = [x, y, yaw])",
                )
            i, j = cells[int(rng.integers(len(cells)))]
            x, y = grid.center(int(i), int(j))
            yaw = float(rng.integers(8)) * math.pi / 4 - math.pi
            placed.append((r.name, kind, (round(x, 3), round(y, 3), round(yaw, 4))))
    return {name: pose for name, _, pose in placed}


def floor_margin(team: TeamSpec) -> float:
    """How far the floor's grid grows every obstacle: the widest ground robot's footprint."""
    return max(KINDS[r.kind].footprint for r in team.robots if not KINDS[r.kind].flies)


def check_placement(layout: Layout, team: TeamSpec, seed: int) -> None:
    """TeamError NO_ROOM unless `team` can start on `layout` with `seed`: the placement the world
    makes, without building anything (the floor's grid is geometry alone), so that a team the
    layout cannot place is refused before anything starts."""
    place_team(layout, team, seed, occupancy(layout, floor_margin(team)))
