"""Base skills: navigate to a stand pose along an A* path, move the base by a short offset.

A ground base plans on the floor's grid (walls and furniture); a flier (the drone) on the air's
(walls only: it passes over furniture) and goes to a stand pose's viewpoint, the stand pose's
x, y at its flight altitude, where it sees what a ground scout sees there. Each travels at its
kind's speed. One robot per stand pose: navigate fails, naming the occupant, when another robot
on the same level (floor or air) stands within OFF_TARGET of the goal.

By default a base stops where seeded noise puts it (`base_error`), off target now and then:
the skill then fails and says where the robot stopped, as the paper's Table III has it. The
rates are mhrc's calibration, not the paper's (mhrc.core.fidelity); `--noise off` and the
exact_motion aid turn the noise off.
"""

from __future__ import annotations

import math

from mhrc.core.fidelity import CALIBRATION
from mhrc.core.protocol import Move, Navigate, OutcomeCode, SkillOutcome

from .. import feedback as fb
from ..astar import Grid, astar, line_free, path_length
from ..robots import RobotBody
from .context import SkillContext
from .registry import skill

NAV_SPEED = 0.5  # m/s: a ground base's speed (RobotKind.speed; a drone's is its own)
MAX_MOVE = 1.0  # m, the longest `move`
# motion noise (off with --noise off or the exact_motion aid), drawn from the context's rng: where a base stops is
# its goal plus an error of Rayleigh-distributed length (most stops within a few cm) or, now and then, a slip; the
# rates are the episode's (SkillContext.noise, recorded in its trace), by default the calibration
NAV_SIGMA = (
    CALIBRATION.navigation_sigma
)  # m: the Rayleigh scale of an ordinary stop's error (mean 1.9 cm; over 5 cm 0.4%)
NAV_SLIP_P = CALIBRATION.navigation_slip  # the chance that a base slips (3%)
NAV_SLIP = (0.11, 0.3)  # m: how far a slip takes it from its goal (then pulled back onto free floor)
OFF_TARGET = 0.1  # m: navigate and move fail when the base stops farther than this from the goal
ROUTE_POINTS = 40  # at most this many points of a navigate's route go into its outcome (for viewers)


def base_error(ctx: SkillContext) -> tuple[float, float]:
    """Where a base stops relative to its goal: one draw per navigate or move."""
    return ctx.motion_error(ctx.noise.navigation_slip, NAV_SLIP, ctx.noise.navigation_sigma)


def stop_near(grid: Grid, goal: tuple[float, float], error: tuple[float, float]) -> tuple[float, float]:
    """The base's real stop: `goal` plus `error`, drawn back toward the goal until the stop is
    free on `grid` and reachable from the goal in a straight line (never inside furniture, for a
    ground base)."""
    for k in range(20):
        s = 1.0 - k / 20
        x, y = goal[0] + s * error[0], goal[1] + s * error[1]
        if grid.free(x, y) and line_free(grid, goal, (x, y)):
            return x, y
    return goal


def route(path: list[tuple[float, float]], stop: tuple[float, float]) -> list[tuple[float, float]]:
    """The route a viewer draws: the planned path, then the real stop (the goal plus the stop's
    error, in a free straight line from it), at most ROUTE_POINTS points (ends kept), rounded to
    centimetres."""
    pts = [*path, stop]
    if len(pts) > ROUTE_POINTS:
        step = (len(pts) - 1) / (ROUTE_POINTS - 1)
        pts = [pts[round(i * step)] for i in range(ROUTE_POINTS)]
    out: list[tuple[float, float]] = []
    for x, y in pts:
        q = (round(float(x), 2), round(float(y), 2))
        if not out or out[-1] != q:
            out.append(q)
    return out


@skill(Navigate)
def navigate(ctx: SkillContext, r: RobotBody, a: Navigate) -> SkillOutcome:
    error = base_error(ctx)
    f = ctx.world.layout.get(a.target)
    if f is None:
        if a.target in ctx.world.fixtures:
            return SkillOutcome.fail(
                OutcomeCode.NOT_NAVIGABLE, fb.not_navigable(a.target, ctx.world.layout.bob_table, advice=ctx.advice)
            )
        belief = ctx.knowledge.belief(r.name, a.target)
        if belief is not None:  # an object: point to where the robot believes it lies, not where it is
            on = belief.on
            where = ctx.world.layout.get(ctx.world.layout.bob_table if ctx.world.on_bob_table(on) else on or "")
            where_name = where.name if where is not None and where.stand_poses else None
            return SkillOutcome.fail(
                OutcomeCode.NOT_NAVIGABLE, fb.not_navigable(a.target, where_name, advice=ctx.advice)
            )
        navigable = [g.name for g in ctx.world.layout.furniture if g.stand_poses]
        return SkillOutcome.fail(
            OutcomeCode.TARGET_UNKNOWN, fb.unknown_furniture(a.target, navigable, advice=ctx.advice)
        )
    if not f.stand_poses:
        return SkillOutcome.fail(OutcomeCode.NOT_NAVIGABLE, fb.not_navigable(f.name, None))
    if a.stand_pose >= len(f.stand_poses):
        return SkillOutcome.fail(
            OutcomeCode.STAND_POSE_INVALID, fb.stand_pose_invalid(f.name, len(f.stand_poses), a.stand_pose)
        )
    assert r.base is not None
    goal = f.stand_poses[a.stand_pose]
    grid = ctx.world.grid_for(r)
    if not grid.free(r.base[0], r.base[1]):
        return SkillOutcome.fail(OutcomeCode.START_INVALID, fb.start_invalid())
    if not grid.free(goal[0], goal[1]):
        return SkillOutcome.fail(OutcomeCode.GOAL_INVALID, fb.goal_invalid(f.name, a.stand_pose))
    if (occupant := ctx.world.occupant(r, (goal[0], goal[1]), OFF_TARGET)) is not None:
        return SkillOutcome.fail(
            OutcomeCode.OCCUPIED, fb.occupied(f.name, a.stand_pose, occupant, advice=ctx.advice), occupant=occupant
        )
    path = astar(grid, (r.base[0], r.base[1]), (goal[0], goal[1]))
    if path is None:
        return SkillOutcome.fail(OutcomeCode.NO_PATH, fb.no_path(f.name, a.stand_pose))
    for x, y in path[1:-1]:  # kinematic: the base visits the waypoints, heading along the path
        r.set_base((x, y, r.base[2]))
    sx, sy = stop_near(grid, (goal[0], goal[1]), error)
    r.set_base((sx, sy, goal[2]))
    off = math.hypot(sx - goal[0], sy - goal[1])
    length = path_length(path) + off
    speed = r.kind.speed
    ctx.knowledge.look_at(r.name, f.name)  # on target or not, the robot stands by f and sees it
    drawn = route(path, (sx, sy))
    if off > OFF_TARGET:
        return SkillOutcome.fail(
            OutcomeCode.OFF_TARGET,
            fb.off_target(f.name, a.stand_pose, off, (sx, sy), advice=ctx.advice),
            sim_time=length / speed,
            distance=round(off, 3),
            x=round(sx, 3),
            y=round(sy, 3),
            path_length=round(length, 3),
        ).model_copy(update={"path": drawn})
    seen = None if f.container is not None and not ctx.world.is_open(f.name) else ctx.world.objects_on(f.name)
    text = fb.reached(
        f.name,
        a.stand_pose,
        seen,
        container=f.container is not None,
        can_open="open" in r.kind.skills,
        advice=ctx.advice,
    )
    out = SkillOutcome.ok(text, sim_time=length / speed, path_length=round(length, 3), distance=round(off, 3))
    return out.model_copy(update={"path": drawn})


def move_blocked(ctx: SkillContext, x: float, y: float, dx: float, dy: float) -> bool:
    return not (ctx.world.grid.free(x, y) and line_free(ctx.world.grid, (x, y), (x + dx, y + dy)))  # ground bases


@skill(Move)
def move(ctx: SkillContext, r: RobotBody, a: Move) -> SkillOutcome:
    assert r.base is not None
    error = base_error(ctx)
    d = math.hypot(a.dx, a.dy)
    if d > MAX_MOVE + 1e-9:
        return SkillOutcome.fail(OutcomeCode.GOAL_INVALID, fb.move_too_long(d, MAX_MOVE))
    x, y, yaw = r.base
    if not ctx.world.grid.free(x, y):
        return SkillOutcome.fail(OutcomeCode.START_INVALID, fb.start_invalid())
    if move_blocked(ctx, x, y, a.dx, a.dy):
        return SkillOutcome.fail(OutcomeCode.GOAL_INVALID, fb.move_blocked(a.dx, a.dy))
    sx, sy = stop_near(ctx.world.grid, (x + a.dx, y + a.dy), error)
    r.set_base((sx, sy, yaw))
    off = math.hypot(sx - x - a.dx, sy - y - a.dy)
    moved = (sx - x, sy - y)
    t = (d + off) / r.kind.speed
    if off > OFF_TARGET:
        return SkillOutcome.fail(
            OutcomeCode.OFF_TARGET,
            fb.move_off_target(a.dx, a.dy, off, moved),
            sim_time=t,
            distance=round(off, 3),
            dx=round(moved[0], 3),
            dy=round(moved[1], 3),
        )
    return SkillOutcome.ok(
        fb.moved(*moved),
        sim_time=t,
        distance=round(math.hypot(*moved), 3),
        dx=round(moved[0], 3),
        dy=round(moved[1], 3),
    )
