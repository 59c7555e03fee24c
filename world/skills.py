"""The skills that move things: navigate, move, open, pick, place.

Each takes the simulator, the acting robot and the action, runs the real planners (A* for
bases; IK and OMPL BIT* for arms), executes the result kinematically and returns a
`SkillOutcome` whose sentence comes from `feedback`. Bad arguments are failures, never
exceptions.

At the paper's fidelity motion is not exact: a base stops where seeded noise (sim.rng) puts
it, off target now and then, and a released object falls and settles under PyBullet physics,
so navigation can end off target and a placed object can miss its goal, as in Table III. The
exact_motion aid turns both off. Only a robot kind that finishes the task (Bob) places on the
task's goal fixtures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from mhrc.world.quiet import pybullet as p  # no C banner on stdout

from mhrc.core.protocol import Move, Navigate, Open, OutcomeCode, Pick, Place, SkillOutcome

from . import feedback as fb
from .arm import HOME, LOWER, UPPER, ArmPlanner, IKResult, straight
from .astar import astar, line_free, path_length
from .robots import ARM_FORWARD, CHASSIS, MAX_ARM_RANGE, RobotBody

if TYPE_CHECKING:
    from .layouts import FurnitureSpec
    from .sim import ObjectState, Sim
    from .tasks import ObjectKind

NAV_SPEED = 0.5  # m/s: simulated time of base motions
JOINT_SPEED = 1.0  # rad/s: simulated time of arm motions
SUCTION_TIME = 1.0  # s to grip or release
MAX_MOVE = 1.0  # m, the longest `move`
APPROACH = 0.12  # pre-grasp height above the grasp point
IK_RETRY_BELOW = 0.03  # m: an IK search that misses the point by less than this searches again, harder
IK_SLACK = 0.005  # m: a miss below this (0.00 m in the feedback) is an invalid goal configuration, not a distance
IK_RETRY_RESTARTS = 32  # IK restarts per tool turn when the first search just missed
IDEAL_PICK = (0.3, 0.58)  # horizontal arm-base-to-object distances a corrective move aims for
PULL_STEPS = 16  # IK waypoints along a drawer's travel or a lid's swing
LID_CLEARANCE = 0.04  # the tool holds a lid's handle this far above its (tilting) top
LID_GRASP_TRIES = 12  # grasp configurations tried for a lid before giving up
SPOT_GAP = 0.02  # clearance between placed objects' footprints
HANDOVER_CLEARANCE = 0.2  # m between a handed-over object and the hand of the robot that put it there
TIP_CLEARANCE = 0.015  # the closed fingertips reach this far below the suction point
# motion noise (off with the exact_motion aid), drawn from sim.rng: where a base stops is its goal
# plus an error of Rayleigh-distributed length (most stops within a few cm) or, now and then, a slip
NAV_SIGMA = 0.015  # m: the Rayleigh scale of an ordinary stop's error (mean 1.9 cm; over 5 cm 0.4%)
NAV_SLIP_P = 0.03  # the chance that a base slips
NAV_SLIP = (0.11, 0.3)  # m: how far a slip takes it from its goal (then pulled back onto free floor)
OFF_TARGET = 0.1  # m: navigate and move fail when the base stops farther than this from the goal
ROUTE_POINTS = 40  # at most this many points of a navigate's route go into its outcome (for viewers)
# a released object falls under gravity from where the tool lets go of it, that point off by a small
# error (Rayleigh-distributed length again) or, now and then, by a slip of the object off the suction cup
RELEASE_SIGMA = 0.003  # m: the Rayleigh scale of an ordinary release's error
RELEASE_SLIP_P = 0.1  # the chance that the object slips as it is let go
RELEASE_SLIP = (0.02, 0.04)  # m: how far a slip shifts it (a solid never reaches the next colour panel)
SETTLE_STEPS = 480  # at most 2 s of PyBullet time (240 Hz) for a released object to come to rest
SETTLE_STILL = 12  # steps in a row nearly still that count as at rest
GRAVITY = 9.81
ROLLING_FRICTION = 0.005  # m: what stops a tipped disc or a ball rolling (PyBullet's default is none)


# --------------------------------------------------------------------------- bases


def _motion_error(sim: Sim, slip_p: float, slip: tuple[float, float], sigma: float) -> tuple[float, float]:
    """One draw from sim.rng: with chance `slip_p` a slip of a length in `slip`, else a small
    error (Rayleigh, scale `sigma`), in a uniform direction; none with the exact_motion aid."""
    if "exact_motion" in sim.aids:
        return 0.0, 0.0
    slipped, size, heading = sim.rng.random(3)
    if slipped < slip_p:
        dist = slip[0] + (slip[1] - slip[0]) * size
    else:
        dist = sigma * math.sqrt(-2.0 * math.log1p(-size))
    return dist * math.cos(2 * math.pi * heading), dist * math.sin(2 * math.pi * heading)


def advice(sim: Sim) -> bool:
    """Whether failed actions' feedback may say what to do next (the feedback_advice aid; not the paper's)."""
    return "feedback_advice" in sim.aids


def base_error(sim: Sim) -> tuple[float, float]:
    """Where a base stops relative to its goal: one draw per navigate or move."""
    return _motion_error(sim, NAV_SLIP_P, NAV_SLIP, NAV_SIGMA)


def stop_near(sim: Sim, goal: tuple[float, float], error: tuple[float, float]) -> tuple[float, float]:
    """The base's real stop: `goal` plus `error`, drawn back toward the goal until the stop is on
    free floor and reachable from the goal in a straight line (never inside furniture)."""
    for k in range(20):
        s = 1.0 - k / 20
        x, y = goal[0] + s * error[0], goal[1] + s * error[1]
        if sim.grid.free(x, y) and line_free(sim.grid, goal, (x, y)):
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


def navigate(sim: Sim, r: RobotBody, a: Navigate) -> SkillOutcome:
    error = base_error(sim)
    f = sim.layout.get(a.target)
    if f is None:
        if a.target in sim.fixtures:
            return SkillOutcome.fail(OutcomeCode.NOT_NAVIGABLE, fb.not_navigable(a.target, sim.layout.bob_table, advice=advice(sim)))
        belief = sim.belief(r.name, a.target)
        if belief is not None:  # an object: point to where the robot believes it lies, not where it is
            on = belief.on
            where = sim.layout.get(sim.layout.bob_table if sim.on_bob_table(on) else on or "")
            where_name = where.name if where is not None and where.stand_poses else None
            return SkillOutcome.fail(OutcomeCode.NOT_NAVIGABLE, fb.not_navigable(a.target, where_name, advice=advice(sim)))
        navigable = [g.name for g in sim.layout.furniture if g.stand_poses]
        return SkillOutcome.fail(OutcomeCode.TARGET_UNKNOWN, fb.unknown_furniture(a.target, navigable, advice=advice(sim)))
    if not f.stand_poses:
        return SkillOutcome.fail(OutcomeCode.NOT_NAVIGABLE, fb.not_navigable(f.name, None))
    if a.stand_pose >= len(f.stand_poses):
        return SkillOutcome.fail(OutcomeCode.STAND_POSE_INVALID, fb.stand_pose_invalid(f.name, len(f.stand_poses), a.stand_pose))
    assert r.base is not None
    goal = f.stand_poses[a.stand_pose]
    if not sim.grid.free(r.base[0], r.base[1]):
        return SkillOutcome.fail(OutcomeCode.START_INVALID, fb.start_invalid())
    if not sim.grid.free(goal[0], goal[1]):
        return SkillOutcome.fail(OutcomeCode.GOAL_INVALID, fb.goal_invalid(f.name, a.stand_pose))
    path = astar(sim.grid, (r.base[0], r.base[1]), (goal[0], goal[1]))
    if path is None:
        return SkillOutcome.fail(OutcomeCode.NO_PATH, fb.no_path(f.name, a.stand_pose))
    for x, y in path[1:-1]:  # kinematic: the base visits the waypoints, heading along the path
        r.set_base((x, y, r.base[2]))
    sx, sy = stop_near(sim, (goal[0], goal[1]), error)
    r.set_base((sx, sy, goal[2]))
    off = math.hypot(sx - goal[0], sy - goal[1])
    length = path_length(path) + off
    sim.look_at(r.name, f.name)  # on target or not, the robot stands by f and sees it
    drawn = route(path, (sx, sy))
    if off > OFF_TARGET:
        return SkillOutcome.fail(
            OutcomeCode.OFF_TARGET, fb.off_target(f.name, a.stand_pose, off, (sx, sy), advice=advice(sim)),
            sim_time=length / NAV_SPEED, distance=round(off, 3), x=round(sx, 3), y=round(sy, 3), path_length=round(length, 3),
        ).model_copy(update={"path": drawn})  # fmt: skip
    seen = None if f.container is not None and not sim.is_open(f.name) else sim.objects_on(f.name)
    text = fb.reached(f.name, a.stand_pose, seen, container=f.container is not None, can_open="open" in r.kind.skills, advice=advice(sim))
    out = SkillOutcome.ok(text, sim_time=length / NAV_SPEED, path_length=round(length, 3), distance=round(off, 3))
    return out.model_copy(update={"path": drawn})


def _move_blocked(sim: Sim, x: float, y: float, dx: float, dy: float) -> bool:
    return not (sim.grid.free(x, y) and line_free(sim.grid, (x, y), (x + dx, y + dy)))


def move(sim: Sim, r: RobotBody, a: Move) -> SkillOutcome:
    assert r.base is not None
    error = base_error(sim)
    d = math.hypot(a.dx, a.dy)
    if d > MAX_MOVE + 1e-9:
        return SkillOutcome.fail(OutcomeCode.GOAL_INVALID, fb.move_too_long(d, MAX_MOVE))
    x, y, yaw = r.base
    if not sim.grid.free(x, y):
        return SkillOutcome.fail(OutcomeCode.START_INVALID, fb.start_invalid())
    if _move_blocked(sim, x, y, a.dx, a.dy):
        return SkillOutcome.fail(OutcomeCode.GOAL_INVALID, fb.move_blocked(a.dx, a.dy))
    sx, sy = stop_near(sim, (x + a.dx, y + a.dy), error)
    r.set_base((sx, sy, yaw))
    off = math.hypot(sx - x - a.dx, sy - y - a.dy)
    moved = (sx - x, sy - y)
    t = (d + off) / NAV_SPEED
    if off > OFF_TARGET:
        return SkillOutcome.fail(OutcomeCode.OFF_TARGET, fb.move_off_target(a.dx, a.dy, off, moved), sim_time=t, distance=round(off, 3), dx=round(moved[0], 3), dy=round(moved[1], 3))
    return SkillOutcome.ok(fb.moved(*moved), sim_time=t, distance=round(math.hypot(*moved), 3), dx=round(moved[0], 3), dy=round(moved[1], 3))


# --------------------------------------------------------------------------- arms: shared


@dataclass
class Reach:
    """A plan to a pose above a point, the straight descent onto it, or why there is none."""

    path: list[np.ndarray] | None = None
    descent: list[np.ndarray] | None = None
    failure: SkillOutcome | None = None
    distance: float = 0.0  # how far the tool tip stays from the point when it cannot reach it


def planner_for(sim: Sim, r: RobotBody, base: tuple[float, float, float] | None = None) -> ArmPlanner:
    """The shadow planner, set up for r's arm: its base pose, its own chassis, the other arms.

    `base` plans as if a mobile robot stood there instead. Bases do not collide with each
    other (navigation ignores robots, as the paper's platform does), so other robots'
    bodies are left out; their arms are not.
    """
    pl = sim.planner
    for other in sim.bots.values():
        if other is r:
            pl.hide_other_arm(other.name)
        elif other.kind.has_arm:
            oab = other.arm_base()
            assert oab is not None
            pl.set_other_arm(other.name, oab, other.arm_yaw(), other.q)
    base = base or r.base
    if base is None:
        assert r.fixed_arm is not None
        pl.set_base(r.fixed_arm, r.fixed_yaw)
        pl.hide_box("chassis")
    else:
        x, y, yaw = base
        pl.set_base((x + ARM_FORWARD * math.cos(yaw), y + ARM_FORWARD * math.sin(yaw), CHASSIS[2]), yaw)
        pl.set_box("chassis", (x, y, CHASSIS[2] / 2), (CHASSIS[0] / 2, CHASSIS[1] / 2, CHASSIS[2] / 2 - 0.01), yaw)
    return pl


def horizontal(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def _solve_above_and_at(
    pl: ArmPlanner, above: tuple[float, float, float], point: tuple[float, float, float], yaw: float, seed: np.ndarray, restarts: int = 8
) -> tuple[IKResult, IKResult]:
    """Verified IK for the pose above `point`, then for `point` seeded by it (the pose above's
    result twice when it has none)."""
    sol_above = pl.solve(above, yaw, seed, restarts)
    sol_at = pl.solve(point, yaw, sol_above.q, restarts) if sol_above.q is not None else sol_above
    return sol_above, sol_at


def reach_point(
    sim: Sim, r: RobotBody, point: tuple[float, float, float], what: str, tool_yaw: float | None = None, *, any_yaw: bool = False
) -> Reach:
    """IK (verified) for `point` and a point above it, then BIT* from r's arm to the one above.

    The tool points down, turned to `tool_yaw` (default: the arm base's heading). IK is a
    randomised search: when it ends within IK_RETRY_BELOW of the point without a verified pose (a
    near miss, e.g. low and close to the arm's base), it searches again with more restarts and, with
    `any_yaw` (a suction pick, where the tool's turn does not matter), with the tool turned by
    quarter turns. A near miss that remains is an invalid goal configuration, never "too far".
    """
    pl = planner_for(sim, r)
    ab = r.arm_base()
    assert ab is not None
    yaw = r.arm_yaw() if tool_yaw is None else tool_yaw
    if horizontal(ab, point) > MAX_ARM_RANGE:
        return Reach(distance=horizontal(ab, point) - 0.75)
    above = (point[0], point[1], point[2] + APPROACH)
    sol_above, sol_at = _solve_above_and_at(pl, above, point, yaw, r.q)
    if (sol_above.q is None or sol_at.q is None) and not sol_at.collided and sol_at.error < IK_RETRY_BELOW:
        turns = (0.0, math.pi / 2, -math.pi / 2, math.pi) if any_yaw else (0.0,)
        for turn in turns:
            again = _solve_above_and_at(pl, above, point, _wrap(yaw + turn), r.q, IK_RETRY_RESTARTS)
            if again[0].q is not None and again[1].q is not None:
                (sol_above, sol_at), yaw = again, _wrap(yaw + turn)
                break
            sol_at = min(sol_at, again[1], key=lambda s: (not s.collided, s.error))
    q_above, q_at = sol_above.q, sol_at.q
    if q_above is None or q_at is None:
        if sol_at.collided:  # the pose exists, but every solution found collides
            return Reach(failure=SkillOutcome.fail(OutcomeCode.CONFIG_INVALID, fb.config_invalid(what, "goal")))
        if sol_at.error < IK_SLACK:  # "0.00 m away" would be no distance the robot could act on
            return Reach(failure=SkillOutcome.fail(OutcomeCode.CONFIG_INVALID, fb.no_goal_configuration(what, sol_at.error)))
        return Reach(distance=sol_at.error)
    descent = cartesian_descent(pl, above, point, yaw, q_above, q_at)
    if not all(pl.valid(q) for q in descent[1:-1]):
        return Reach(failure=SkillOutcome.fail(OutcomeCode.PLAN_FAILED, fb.plan_failed(what)))
    res = pl.plan(r.q, q_above)
    if res.path is None:
        if res.reason in ("start_invalid", "goal_invalid"):
            which = res.reason.split("_")[0]
            return Reach(failure=SkillOutcome.fail(OutcomeCode.CONFIG_INVALID, fb.config_invalid(what, which)))
        return Reach(failure=SkillOutcome.fail(OutcomeCode.PLAN_FAILED, fb.plan_failed(what)))
    return Reach(path=res.path, descent=descent)


def cartesian_descent(
    pl: ArmPlanner, above: tuple[float, float, float], point: tuple[float, float, float], yaw: float, q_above: np.ndarray, q_at: np.ndarray, steps: int = 8
) -> list[np.ndarray]:
    """Joint waypoints that keep the tool on the vertical line from `above` down to `point`,
    each IK solution seeded by the one before (a joint-space straight line can swing the
    elbow into the table close to the arm's base); the joint-space line if IK loses the way."""
    path = [q_above]
    for k in range(1, steps):
        s = k / steps
        goal = (point[0], point[1], above[2] + (point[2] - above[2]) * s)
        q = pl.ik(goal, yaw, path[-1], restarts=1)
        if q is None or float(np.max(np.abs(q - path[-1]))) > 0.5:
            return straight(q_above, q_at, steps)
        path.append(q)
    path.append(q_at)
    return path


def retract(sim: Sim, r: RobotBody) -> float:
    """Back to the carry posture: planned, or straight in joint space if no plan is found."""
    res = planner_for(sim, r).plan(r.q, HOME)
    path = res.path if res.path is not None else straight(r.q, HOME, 12)
    return r.run(path, JOINT_SPEED)


def corrective_move(sim: Sim, r: RobotBody, point: tuple[float, float, float]) -> tuple[float, float] | None:
    """The shortest collision-free base shift (<= MAX_MOVE) after which IK reaches `point` well."""
    assert r.base is not None
    x, y, yaw = r.base
    fx, fy = ARM_FORWARD * math.cos(yaw), ARM_FORWARD * math.sin(yaw)
    steps = np.round(np.arange(-MAX_MOVE, MAX_MOVE + 1e-9, 0.05), 3)
    cands = sorted(
        ((float(dx), float(dy)) for dx in steps for dy in steps if math.hypot(dx, dy) <= MAX_MOVE),
        key=lambda d: (round(math.hypot(*d), 6), d),
    )
    tried = 0
    for dx, dy in cands:
        dist = math.hypot(point[0] - (x + dx + fx), point[1] - (y + dy + fy))
        if not IDEAL_PICK[0] <= dist <= IDEAL_PICK[1] or _move_blocked(sim, x, y, dx, dy):
            continue
        pl = planner_for(sim, r, base=(x + dx, y + dy, yaw))
        ok = pl.ik((point[0], point[1], point[2] + APPROACH), yaw, HOME, restarts=4) is not None
        ok = ok and pl.ik(point, yaw, HOME, restarts=4) is not None
        if ok:
            return dx, dy
        tried += 1
        if tried >= 12:
            break
    return None


def _too_far(sim: Sim, r: RobotBody, point: tuple[float, float, float], name: str, distance: float) -> SkillOutcome:
    """The paper's too-far pick: the end effector's distance and, for a mobile manipulator, the
    object's offsets from the base centre along x and y; the solved move only with its aid."""
    distance = round(distance, 2)  # centimetres, in the sentence and the details alike
    details: dict[str, float | str] = {"distance": distance}
    offset = fix = None
    if r.kind.mobile and r.base is not None:
        offset = (round(point[0] - r.base[0], 2), round(point[1] - r.base[1], 2))
        details.update(offset_x=offset[0], offset_y=offset[1])
        if "solved_move" in sim.aids:
            fix = corrective_move(sim, r, point)
    if fix is not None:
        details.update(dx=round(fix[0], 3), dy=round(fix[1], 3))
    return SkillOutcome(succeeded=False, code=OutcomeCode.TOO_FAR, feedback=fb.too_far(name, distance, offset, fix), details=details)


# --------------------------------------------------------------------------- open


def open_(sim: Sim, r: RobotBody, a: Open) -> SkillOutcome:
    f = sim.layout.get(a.target)
    if f is None:
        if a.target in sim.fixtures or a.target in sim.known_objects(r.name):
            return SkillOutcome.fail(OutcomeCode.NOT_OPENABLE, fb.not_openable(a.target))
        return SkillOutcome.fail(OutcomeCode.TARGET_UNKNOWN, fb.unknown_furniture(a.target, sim.furniture_names(), advice=advice(sim)))
    if f.container is None:
        return SkillOutcome.fail(OutcomeCode.NOT_OPENABLE, fb.not_openable(f.name))
    if sim.is_open(f.name):
        return SkillOutcome.fail(OutcomeCode.ALREADY_OPEN, fb.already_open(f.name))
    if r.holding is not None:
        return SkillOutcome.fail(OutcomeCode.GRIPPER_FULL, fb.hands_full_to_open(f.name, r.holding, advice=advice(sim)))
    if f.lid is not None or f.door is not None:
        return _open_lid(sim, r, f)
    hx, hy, hz = sim.handle_position(f.name)
    handle = (hx, hy, hz + TIP_CLEARANCE)
    ab = r.arm_base()
    assert ab is not None
    reach = reach_point(sim, r, handle, f"the handle of {f.name}")
    if reach.failure is not None:
        return reach.failure
    if reach.path is None or reach.descent is None:
        return SkillOutcome.fail(
            OutcomeCode.OUT_OF_REACH, fb.handle_out_of_reach(f.name, horizontal(ab, handle), mobile="navigate" in r.kind.skills, advice=advice(sim)),
            distance=round(reach.distance, 3), horizontal_distance=round(horizontal(ab, handle), 3),
        )  # fmt: skip
    q0 = r.q.copy()
    t = r.run(reach.path + reach.descent, JOINT_SPEED)
    # move the handle along the joint's path (a drawer's line, a lid's arc), the arm following IK waypoints
    pl = planner_for(sim, r)
    spec = f.container
    yaw = r.arm_yaw()
    pulled = 0.0
    for s in np.linspace(0.0, spec.travel, PULL_STEPS + 1)[1:]:
        sim.set_container(f.name, float(s))  # the drawer or lid (handle held) moves out of the planner's way
        hx, hy, hz = sim.handle_position(f.name)
        q = pl.ik((hx, hy, hz + TIP_CLEARANCE), yaw, r.q, restarts=3)
        if q is None or float(np.max(np.abs(q - r.q))) > 0.6:
            sim.set_container(f.name, pulled)
            break
        t += r.run([r.q, q], JOINT_SPEED)
        pulled = float(s)
    if pulled < spec.travel - 1e-6:
        sim.set_container(f.name, 0.0)
        t += r.run(straight(r.q, q0, 10), JOINT_SPEED)
        return SkillOutcome.fail(OutcomeCode.OUT_OF_REACH, fb.pull_failed(f.name), sim_time=t, pulled=round(pulled, 3))
    return _opened(sim, r, f, pl, yaw, t, pulled)


def _opened(sim: Sim, r: RobotBody, f: FurnitureSpec, pl: ArmPlanner, yaw: float, t: float, travel: float) -> SkillOutcome:
    """Let go of the handle of an opened container: lift, retract, look inside."""
    lift = pl.ik((r.tip()[0], r.tip()[1], r.tip()[2] + 0.08), yaw, r.q, restarts=2)
    if lift is not None:
        t += r.run(straight(r.q, lift, 5), JOINT_SPEED)
    t += retract(sim, r)
    sim.look_at(r.name, f.name)
    inside = [(n, sim.position(sim.objects[n])) for n in sim.objects_on(f.name)]
    return SkillOutcome.ok(fb.opened(f.name, inside), sim_time=t + 2 * SUCTION_TIME, travel=round(travel, 3))


def _swing(f: FurnitureSpec) -> tuple[float, float, float]:
    """A lid's or a side-hinged door's angle (rad), how far above its handle the tool holds it,
    and how the tool turns per radian of swing (a door's handle turns about the vertical hinge)."""
    if f.lid is not None:
        return f.lid.angle, LID_CLEARANCE, 0.0
    assert f.door is not None
    return f.door.angle, TIP_CLEARANCE, -f.cupboard_geometry().side


def _lid_arc(sim: Sim, pl: ArmPlanner, f: FurnitureSpec, values: np.ndarray, seed: np.ndarray, yaw: float) -> list[np.ndarray]:
    """Joint waypoints that keep the tool on the handle while the lid or door passes through
    `values` (rad, in either order), starting from an IK solution seeded by `seed`, as far as IK
    follows without a jump. The lid or door is left shut again."""
    _, clearance, turn = _swing(f)
    path: list[np.ndarray] = []
    for v in values:
        sim.set_container(f.name, float(v))
        hx, hy, hz = sim.handle_position(f.name)
        q = pl.ik((hx, hy, hz + clearance), yaw + turn * float(v), path[-1] if path else seed, restarts=1)
        if q is None or (path and float(np.max(np.abs(q - path[-1]))) > 0.6):
            break
        path.append(q)
    sim.set_container(f.name, 0.0)
    return path


def _open_lid(sim: Sim, r: RobotBody, f: FurnitureSpec) -> SkillOutcome:
    """Grip the handle of a lid (and swing it up) or of a side-hinged door (and swing it out).
    Several grasp configurations are tried, each checked along the whole arc before the arm
    moves: the first that follows it is used."""
    angle, clearance, _ = _swing(f)
    pl = planner_for(sim, r)
    yaw = r.arm_yaw()
    ab = r.arm_base()
    assert ab is not None
    hx, hy, hz = sim.handle_position(f.name)
    handle = (hx, hy, hz + clearance)
    above = (hx, hy, handle[2] + APPROACH)
    if horizontal(ab, handle) > MAX_ARM_RANGE:
        return SkillOutcome.fail(
            OutcomeCode.OUT_OF_REACH, fb.handle_out_of_reach(f.name, horizontal(ab, handle), mobile="navigate" in r.kind.skills, advice=advice(sim)),
            horizontal_distance=round(horizontal(ab, handle), 3),
        )  # fmt: skip
    values = np.linspace(0.0, angle, PULL_STEPS + 1)
    followed, grasped = 0, False
    for k in range(LID_GRASP_TRIES):
        seed = HOME if k == 0 else pl.rng.uniform(LOWER, UPPER)
        # the open end is the harder pose: solve it first and follow the arc back down, else up
        arc = _lid_arc(sim, pl, f, values[::-1], seed, yaw)[::-1]
        if len(arc) < len(values):
            arc = _lid_arc(sim, pl, f, values, seed, yaw)
        grasped = grasped or bool(arc)
        followed = max(followed, len(arc) - 1)
        if len(arc) < len(values):
            continue
        q_at = arc[0]
        # onto the handle from above if the arm can come down on it, else straight to the grasp
        q_above = pl.ik(above, yaw, q_at, restarts=4)
        descent = cartesian_descent(pl, above, handle, yaw, q_above, q_at) if q_above is not None else []
        if q_above is None or not all(pl.valid(q) for q in descent[1:-1]):
            q_above, descent = q_at, []
        res = pl.plan(r.q, q_above)
        if res.path is None:
            continue
        t = r.run(res.path + descent, JOINT_SPEED)
        for v, q in zip(values[1:], arc[1:]):
            sim.set_container(f.name, float(v))
            t += r.run([r.q, q], JOINT_SPEED)
        return _opened(sim, r, f, pl, yaw + _swing(f)[2] * angle, t, angle)
    if not grasped:  # within range, yet no arm configuration grips the handle from this base pose
        return SkillOutcome.fail(OutcomeCode.OUT_OF_REACH, fb.no_grip(f.name, horizontal(ab, handle)), horizontal_distance=round(horizontal(ab, handle), 3))
    return SkillOutcome.fail(OutcomeCode.OUT_OF_REACH, fb.pull_failed(f.name), pulled=round(followed * angle / PULL_STEPS, 3))


# --------------------------------------------------------------------------- pick


def pick(sim: Sim, r: RobotBody, a: Pick) -> SkillOutcome:
    if r.holding is not None:
        return SkillOutcome.fail(OutcomeCode.GRIPPER_FULL, fb.gripper_full(r.holding, advice=advice(sim)))
    known = sim.known_objects(r.name)
    if a.obj not in known:
        return SkillOutcome.fail(OutcomeCode.OBJECT_UNKNOWN, fb.object_unknown(a.obj, sorted(known), advice=advice(sim)))
    obj = sim.objects[a.obj]
    if obj.held_by is not None:
        return SkillOutcome.fail(OutcomeCode.OBJECT_UNKNOWN, fb.held_by_other(obj.name, obj.held_by))
    if obj.inside and obj.on is not None and not sim.is_open(obj.on):
        can_open = "open" in r.kind.skills
        return SkillOutcome.fail(OutcomeCode.NOT_REACHABLE_CONTAINER, fb.in_closed_container(obj.name, obj.on, can_open=can_open, advice=advice(sim)))
    x, y, z = sim.position(obj)
    top = (x, y, z + obj.kind.height / 2 + TIP_CLEARANCE)
    reach = reach_point(sim, r, top, obj.name, any_yaw=True)  # a suction cup grips at any turn of the tool
    if reach.failure is not None:
        return reach.failure
    if reach.path is None or reach.descent is None:
        return _too_far(sim, r, top, obj.name, reach.distance)
    t = r.run(reach.path + reach.descent, JOINT_SPEED)
    sim.grasp(r, obj)
    t += r.run(list(reversed(reach.descent)), JOINT_SPEED)
    t += retract(sim, r)
    return SkillOutcome.ok(fb.picked(obj.name), sim_time=t + SUCTION_TIME)


# --------------------------------------------------------------------------- place


def half_extent(kind: ObjectKind, yaw: float, gap: float = SPOT_GAP) -> tuple[float, float]:
    """Half the x and y extent of an upright object turned by `yaw`, plus half of `gap`."""
    fx, fy = kind.shape.footprint
    c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
    return (c * fx + s * fy) / 2 + gap / 2, (s * fx + c * fy) / 2 + gap / 2


def surface_top(sim: Sim, fixture: str, without: ObjectState | None = None) -> float:
    """Where the next object set on `fixture` comes to rest: its surface, or for a stacking
    fixture the highest top of what lies on it (measured, so a slice lying askew counts as it lies)."""
    fx = sim.fixtures[fixture]
    top = sim.table_top() + fx.thickness
    if not fx.stack:
        return top
    if "exact_motion" in sim.aids:  # objects lie exactly as set down: the stack is the sum of their heights
        return sim.fixture_top(fixture, without=without)
    tops = [p.getAABB(o.body, physicsClientId=sim.cid)[1][2] for o in sim.objects.values() if o.on == fixture and o.held_by is None and o is not without]
    return max([top, *tops])


def free_spots(sim: Sim, location: str, held: ObjectState) -> tuple[list[tuple[float, float, float]], float] | None:
    """Spots (x, y, yaw) at `location` where `held` fits without touching anything, best first, and the surface z."""
    lay = sim.layout
    fx = sim.fixtures.get(location)
    if fx is not None and fx.stack:  # a stack grows at the fixture's centre
        return [(fx.center[0], fx.center[1], 0.0)], surface_top(sim, fx.name, without=held)
    if fx is not None:
        (cx, cy), (sx, sy) = fx.center, fx.size
        inset = 0.015 if fx.rim else 0.0
        top = sim.fixture_top(fx.name)
        x0, x1, y0, y1 = cx - sx / 2 + inset, cx + sx / 2 - inset, cy - sy / 2 + inset, cy + sy / 2 - inset
        center = (x1, y1) if fx.rim else (cx, cy)  # fill a tray from its far corner
        avoid_goal_area = False
    else:
        f = lay.get(location)
        if f is None or f.place_pose is None:
            return None
        top = f.top
        x0, x1 = f.center[0] - f.size[0] / 2 + 0.02, f.center[0] + f.size[0] / 2 - 0.02
        y0, y1 = f.center[1] - f.size[1] / 2 + 0.02, f.center[1] + f.size[1] / 2 - 0.02
        center = f.place_pose
        avoid_goal_area = f.name == lay.bob_table
    radius = math.inf if fx is not None else lay.get(location).place_radius  # type: ignore[union-attr]
    boxes = []
    for o in sim.objects.values():
        if o is held or o.held_by is not None:
            continue
        ox, oy, oz = sim.position(o)
        if abs(oz - o.kind.height / 2 - top) < 0.15:
            boxes.append(((ox, oy), half_extent(o.kind, sim.yaw(o))))
    if avoid_goal_area:
        boxes.append((lay.goal_area[:2], (lay.goal_area[2] / 2, lay.goal_area[3] / 2)))
    out: list[tuple[float, float, float]] = []
    for yaw in (0.0, math.pi / 2):
        hx, hy = half_extent(held.kind, yaw)
        for x in np.arange(x0 + hx, x1 - hx + 1e-9, 0.02):
            for y in np.arange(y0 + hy, y1 - hy + 1e-9, 0.02):
                c = (round(float(x), 4), round(float(y), 4))
                if math.hypot(c[0] - center[0], c[1] - center[1]) > radius:
                    continue
                if not any(_overlaps(c, (hx, hy), b, h) for b, h in boxes):
                    out.append((c[0], c[1], yaw))
    if fx is not None and fx.rim:
        # pack a tray tightly: keep what it holds within the smallest rectangle from its far corner
        inside = [b for b in boxes if fx.contains_xy(*b[0])]
        used_x = max((x1 - (b[0] - h[0]) for b, h in inside), default=0.0)
        used_y = max((y1 - (b[1] - h[1]) for b, h in inside), default=0.0)

        def area(c: tuple[float, float, float]) -> float:
            hx, hy = half_extent(held.kind, c[2])
            return round(max(used_x, x1 - (c[0] - hx)) * max(used_y, y1 - (c[1] - hy)), 6)

        out.sort(key=lambda c: (area(c), round(math.hypot(c[0] - center[0], c[1] - center[1]), 6), c[2], c[0], c[1]))
    else:
        out.sort(key=lambda c: (round(math.hypot(c[0] - center[0], c[1] - center[1]), 6), c[2], c[0], c[1]))
    return out, top


def _overlaps(a: tuple[float, float], ha: tuple[float, float], b: tuple[float, float], hb: tuple[float, float]) -> bool:
    return abs(a[0] - b[0]) < ha[0] + hb[0] and abs(a[1] - b[1]) < ha[1] + hb[1]


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def tool_yaw_for(r: RobotBody, object_yaw: float) -> float:
    """The tool heading that sets the held object down at `object_yaw`, nearest the arm's heading."""
    base = object_yaw - r.held_yaw
    return min((base + k * math.pi for k in (-2, -1, 0, 1, 2)), key=lambda y: abs(_wrap(y - r.arm_yaw())))


def release_error(sim: Sim) -> tuple[float, float]:
    """How far (x, y) from where the tool lets go a released object starts to fall: one draw per release."""
    return _motion_error(sim, RELEASE_SLIP_P, RELEASE_SLIP, RELEASE_SIGMA)


def settle(sim: Sim, obj: ObjectState) -> int:
    """Let a just released object come to rest under gravity (PyBullet physics, at most
    SETTLE_STEPS steps); the simulation steps it alone. Every other object is static while it
    does (mass 0), only it feels gravity (so no arm sags and no lid falls), and whatever it
    nudged (arms, containers, a wheeled base) is set back afterwards. Returns the steps taken."""
    cid = sim.cid
    others = [o for o in sim.objects.values() if o is not obj]
    masses = [p.getDynamicsInfo(o.body, -1, physicsClientId=cid)[0] for o in others]
    for o in others:
        p.changeDynamics(o.body, -1, mass=0.0, physicsClientId=cid)
    mass = p.getDynamicsInfo(obj.body, -1, physicsClientId=cid)[0]
    # what tips over slides and rolls a little, not across the table (Bullet multiplies the two
    # bodies' friction coefficients: 1.0 against the furniture's default 0.5 makes 0.5)
    p.changeDynamics(
        obj.body, -1, lateralFriction=1.0, rollingFriction=ROLLING_FRICTION, spinningFriction=ROLLING_FRICTION, physicsClientId=cid
    )  # fmt: skip
    p.resetBaseVelocity(obj.body, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
    still, steps = 0, 0
    while steps < SETTLE_STEPS and still < SETTLE_STILL:
        pos, _ = p.getBasePositionAndOrientation(obj.body, physicsClientId=cid)
        p.applyExternalForce(obj.body, -1, (0.0, 0.0, -GRAVITY * mass), pos, p.WORLD_FRAME, physicsClientId=cid)
        p.stepSimulation(physicsClientId=cid)
        steps += 1
        v, w = p.getBaseVelocity(obj.body, physicsClientId=cid)
        still = still + 1 if steps > 10 and math.hypot(*v) < 2e-3 and math.hypot(*w) < 2e-2 else 0
    p.resetBaseVelocity(obj.body, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
    for o, m in zip(others, masses):
        p.changeDynamics(o.body, -1, mass=m, physicsClientId=cid)
        p.resetBaseVelocity(o.body, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
    for bot in sim.bots.values():
        if bot.kind.has_arm:
            bot.set_arm(bot.q)
        elif bot.base is not None:
            bot.set_base(bot.base)
            p.resetBaseVelocity(bot.body, (0, 0, 0), (0, 0, 0), physicsClientId=cid)
    for name, value in sim.opening.items():
        p.resetJointState(sim.scene.bodies[name], sim.scene.joints[name], value, physicsClientId=cid)
    return steps


def _handover_margin(sim: Sim, spot: tuple[float, ...]) -> float:
    """How far `spot` lies inside the band on Bob's table from which he picks (sim.within_handover)."""
    bob = next((b for b in sim.bots.values() if b.kind.finishes_task), None)
    ab = bob.arm_base() if bob is not None else None
    if bob is None or ab is None or bob.kind.reach is None:
        return math.inf
    d = horizontal(spot, ab)
    return min(d - 0.3, bob.kind.reach - 0.03 - d)


def place(sim: Sim, r: RobotBody, a: Place) -> SkillOutcome:
    if r.holding is None:
        return SkillOutcome.fail(OutcomeCode.GRIPPER_EMPTY, fb.gripper_empty(a.obj))
    if a.obj != r.holding:
        return SkillOutcome.fail(OutcomeCode.WRONG_OBJECT, fb.wrong_object(r.holding, a.obj))
    held = sim.objects[r.holding]
    if a.location in sim.fixtures and not r.kind.finishes_task:  # the paper: only Bob finishes the task
        finisher = next((b.name for b in sim.bots.values() if b.kind.finishes_task), "bob")
        return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, fb.not_a_finisher(held.name, a.location, sim.layout.bob_table, finisher, advice=advice(sim)))
    places = [n for n in sim.place_names() if r.kind.finishes_task or n not in sim.fixtures]
    f = sim.layout.get(a.location)
    if f is not None and f.place_pose is None:
        return SkillOutcome.fail(OutcomeCode.LOCATION_UNKNOWN, fb.not_a_surface(f.name, places, advice=advice(sim)))
    spots = free_spots(sim, a.location, held)
    if spots is None:
        return SkillOutcome.fail(OutcomeCode.LOCATION_UNKNOWN, fb.location_unknown(a.location, places, advice=advice(sim)))
    cands, top = spots
    if a.location == sim.layout.bob_table:
        cands = [c for c in cands if sim.within_handover(c)] or cands
        if "exact_motion" not in sim.aids and not r.kind.finishes_task:  # a slip as it is let go must not carry it out of the finisher's reach
            cands = [c for c in cands if _handover_margin(sim, c) >= RELEASE_SLIP[1] + 3 * RELEASE_SIGMA] or cands
        if r.kind.mobile:  # not under where this arm's hand will hover once it has retracted: Bob could not reach past it
            hand = r.tip()
            cands = [c for c in cands if horizontal(c, hand) >= HANDOVER_CLEARANCE] or cands
    if not cands:
        return SkillOutcome.fail(OutcomeCode.PLACE_FAILED, fb.no_free_spot(a.location))
    ab = r.arm_base()
    assert ab is not None
    can_go = "navigate" in r.kind.skills and f is not None and bool(f.stand_poses)  # may be told to navigate there
    reachable = [c for c in cands if horizontal(ab, c) <= MAX_ARM_RANGE - 0.1]
    if not reachable:
        nearest = min(horizontal(ab, c) for c in cands)
        return SkillOutcome.fail(OutcomeCode.TOO_FAR, fb.place_out_of_reach(a.location, nearest, mobile=can_go, advice=advice(sim)), distance=round(nearest, 3))
    failure: SkillOutcome | None = None
    tries = 0
    for x, y, yaw in reachable:
        point = (x, y, top + held.kind.height + TIP_CLEARANCE + 0.002)
        tool = _wrap(tool_yaw_for(r, yaw))
        reach = reach_point(sim, r, point, f"the spot on {a.location}", tool_yaw=tool)
        if reach.path is None or reach.descent is None:
            failure = failure or reach.failure
            tries += 1
            if tries >= 8:
                break
            continue
        t = r.run(reach.path + reach.descent, JOINT_SPEED)
        sim.release(r, held, (x, y, top), yaw, a.location, release_error(sim))
        t += r.run(list(reversed(reach.descent)), JOINT_SPEED)
        t += retract(sim, r)
        if not sim.settled_at(held, a.location):
            pos = sim.position(held)
            return SkillOutcome.fail(
                OutcomeCode.PLACE_FAILED, fb.place_failed(held.name, a.location, held.on, pos), sim_time=t + SUCTION_TIME,
                on=held.on or "floor", x=round(pos[0], 3), y=round(pos[1], 3), z=round(pos[2], 3),
            )  # fmt: skip
        return SkillOutcome.ok(fb.placed(held.name, a.location), sim_time=t + SUCTION_TIME)
    if failure is not None:
        return failure
    nearest = min(horizontal(ab, c) for c in reachable)
    return SkillOutcome.fail(OutcomeCode.TOO_FAR, fb.place_out_of_reach(a.location, nearest, mobile=can_go, advice=advice(sim)), distance=round(nearest, 3))
