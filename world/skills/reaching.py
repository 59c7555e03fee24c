"""What the arm skills share: a verified IK pose above a point and the straight descent onto
it, a BIT* plan to get there (in the shadow planning client, set up for the acting arm),
the retract to the carry posture, and the paper's too-far failure with its corrective move.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mhrc.core.protocol import OutcomeCode, SkillOutcome

from .. import feedback as fb
from ..arm import HOME, ArmPlanner, IKResult, straight
from ..kinds import ARM_FORWARD, CHASSIS, MAX_ARM_RANGE
from ..robots import RobotBody
from .context import SkillContext
from .navigation import MAX_MOVE, move_blocked

JOINT_SPEED = 1.0  # rad/s: simulated time of arm motions
SUCTION_TIME = 1.0  # s to grip or release
APPROACH = 0.12  # pre-grasp height above the grasp point
IK_RETRY_BELOW = 0.03  # m: an IK search that misses the point by less than this searches again, harder
IK_SLACK = 0.005  # m: a miss below this (0.00 m in the feedback) is an invalid goal configuration, not a distance
IK_RETRY_RESTARTS = 32  # IK restarts per tool turn when the first search just missed
IDEAL_PICK = (0.3, 0.58)  # horizontal arm-base-to-object distances a corrective move aims for
TIP_CLEARANCE = 0.015  # the closed fingertips reach this far below the suction point


@dataclass
class Reach:
    """A plan to a pose above a point, the straight descent onto it, or why there is none."""

    path: list[np.ndarray] | None = None
    descent: list[np.ndarray] | None = None
    failure: SkillOutcome | None = None
    distance: float = 0.0  # how far the tool tip stays from the point when it cannot reach it


def planner_for(ctx: SkillContext, r: RobotBody, base: tuple[float, float, float] | None = None) -> ArmPlanner:
    """The shadow planner, set up for r's arm: its base pose, its own chassis, the other arms.

    `base` plans as if a mobile robot stood there instead. Bases do not collide with each
    other (navigation ignores robots, as the paper's platform does), so other robots'
    bodies are left out; their arms are not.
    """
    pl = ctx.world.planner
    for other in ctx.world.bots.values():
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
    pl: ArmPlanner,
    above: tuple[float, float, float],
    point: tuple[float, float, float],
    yaw: float,
    seed: np.ndarray,
    restarts: int = 8,
) -> tuple[IKResult, IKResult]:
    """Verified IK for the pose above `point`, then for `point` seeded by it (the pose above's
    result twice when it has none)."""
    sol_above = pl.solve(above, yaw, seed, restarts)
    sol_at = pl.solve(point, yaw, sol_above.q, restarts) if sol_above.q is not None else sol_above
    return sol_above, sol_at


def reach_point(
    ctx: SkillContext,
    r: RobotBody,
    point: tuple[float, float, float],
    what: str,
    tool_yaw: float | None = None,
    *,
    any_yaw: bool = False,
) -> Reach:
    """IK (verified) for `point` and a point above it, then BIT* from r's arm to the one above.

    The tool points down, turned to `tool_yaw` (default: the arm base's heading). IK is a
    randomised search: when it ends within IK_RETRY_BELOW of the point without a verified pose (a
    near miss, e.g. low and close to the arm's base), it searches again with more restarts and, with
    `any_yaw` (a suction pick, where the tool's turn does not matter), with the tool turned by
    quarter turns. A near miss that remains is an invalid goal configuration, never "too far".
    """
    pl = planner_for(ctx, r)
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
            again = _solve_above_and_at(pl, above, point, wrap(yaw + turn), r.q, IK_RETRY_RESTARTS)
            if again[0].q is not None and again[1].q is not None:
                (sol_above, sol_at), yaw = again, wrap(yaw + turn)
                break
            sol_at = min(sol_at, again[1], key=lambda s: (not s.collided, s.error))
    q_above, q_at = sol_above.q, sol_at.q
    if q_above is None or q_at is None:
        if sol_at.collided:  # the pose exists, but every solution found collides
            return Reach(failure=SkillOutcome.fail(OutcomeCode.CONFIG_INVALID, fb.config_invalid(what, "goal")))
        if sol_at.error < IK_SLACK:  # "0.00 m away" would be no distance the robot could act on
            return Reach(
                failure=SkillOutcome.fail(OutcomeCode.CONFIG_INVALID, fb.no_goal_configuration(what, sol_at.error))
            )
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
    pl: ArmPlanner,
    above: tuple[float, float, float],
    point: tuple[float, float, float],
    yaw: float,
    q_above: np.ndarray,
    q_at: np.ndarray,
    steps: int = 8,
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


def retract(ctx: SkillContext, r: RobotBody) -> float:
    """Back to the carry posture: planned, or straight in joint space if no plan is found."""
    res = planner_for(ctx, r).plan(r.q, HOME)
    path = res.path if res.path is not None else straight(r.q, HOME, 12)
    return r.run(path, JOINT_SPEED)


def corrective_move(ctx: SkillContext, r: RobotBody, point: tuple[float, float, float]) -> tuple[float, float] | None:
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
        if not IDEAL_PICK[0] <= dist <= IDEAL_PICK[1] or move_blocked(ctx, x, y, dx, dy):
            continue
        pl = planner_for(ctx, r, base=(x + dx, y + dy, yaw))
        ok = pl.ik((point[0], point[1], point[2] + APPROACH), yaw, HOME, restarts=4) is not None
        ok = ok and pl.ik(point, yaw, HOME, restarts=4) is not None
        if ok:
            return dx, dy
        tried += 1
        if tried >= 12:
            break
    return None


def too_far(
    ctx: SkillContext, r: RobotBody, point: tuple[float, float, float], name: str, distance: float
) -> SkillOutcome:
    """The paper's too-far pick: the end effector's distance and, for a mobile manipulator, the
    object's offsets from the base centre along x and y; the solved move only with its aid."""
    distance = round(distance, 2)  # centimetres, in the sentence and the details alike
    details: dict[str, float | str] = {"distance": distance}
    offset = fix = None
    if r.kind.mobile and r.base is not None:
        offset = (round(point[0] - r.base[0], 2), round(point[1] - r.base[1], 2))
        details.update(offset_x=offset[0], offset_y=offset[1])
        if "solved_move" in ctx.aids:
            fix = corrective_move(ctx, r, point)
    if fix is not None:
        details.update(dx=round(fix[0], 3), dy=round(fix[1], 3))
    return SkillOutcome(
        succeeded=False, code=OutcomeCode.TOO_FAR, feedback=fb.too_far(name, distance, offset, fix), details=details
    )


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi
