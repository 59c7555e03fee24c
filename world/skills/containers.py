"""The container skill: open a drawer (pull its handle along its travel), a chest's lid or a
cupboard's side-hinged door (grip the handle and follow its arc), then look inside.
"""

from __future__ import annotations

import numpy as np

from mhrc.core.protocol import Open, OutcomeCode, SkillOutcome

from .. import feedback as fb
from ..arm import HOME, LOWER, UPPER, ArmPlanner, straight
from ..furniture import FurnitureSpec
from ..kinds import MAX_ARM_RANGE
from ..robots import RobotBody
from .context import SkillContext
from .reaching import (
    APPROACH,
    JOINT_SPEED,
    SUCTION_TIME,
    TIP_CLEARANCE,
    cartesian_descent,
    horizontal,
    planner_for,
    reach_point,
    retract,
)
from .registry import skill

PULL_STEPS = 16  # IK waypoints along a drawer's travel or a lid's swing
LID_CLEARANCE = 0.04  # the tool holds a lid's handle this far above its (tilting) top
LID_GRASP_TRIES = 12  # grasp configurations tried for a lid before giving up


@skill(Open)
def open_(ctx: SkillContext, r: RobotBody, a: Open) -> SkillOutcome:
    f = ctx.world.layout.get(a.target)
    if f is None:
        if a.target in ctx.world.fixtures or a.target in ctx.knowledge.known_objects(r.name):
            return SkillOutcome.fail(OutcomeCode.NOT_OPENABLE, fb.not_openable(a.target))
        return SkillOutcome.fail(
            OutcomeCode.TARGET_UNKNOWN, fb.unknown_furniture(a.target, ctx.world.furniture_names(), advice=ctx.advice)
        )
    if f.container is None:
        return SkillOutcome.fail(OutcomeCode.NOT_OPENABLE, fb.not_openable(f.name))
    if ctx.world.is_open(f.name):
        return SkillOutcome.fail(OutcomeCode.ALREADY_OPEN, fb.already_open(f.name))
    if r.holding is not None:
        return SkillOutcome.fail(OutcomeCode.GRIPPER_FULL, fb.hands_full_to_open(f.name, r.holding, advice=ctx.advice))
    if f.lid is not None or f.door is not None:
        return _open_lid(ctx, r, f)
    hx, hy, hz = ctx.world.handle_position(f.name)
    handle = (hx, hy, hz + TIP_CLEARANCE)
    ab = r.arm_base()
    assert ab is not None
    reach = reach_point(ctx, r, handle, f"the handle of {f.name}")
    if reach.failure is not None:
        return reach.failure
    if reach.path is None or reach.descent is None:
        return SkillOutcome.fail(
            OutcomeCode.OUT_OF_REACH,
            fb.handle_out_of_reach(
                f.name, horizontal(ab, handle), mobile="navigate" in r.kind.skills, advice=ctx.advice
            ),
            distance=round(reach.distance, 3),
            horizontal_distance=round(horizontal(ab, handle), 3),
        )
    q0 = r.q.copy()
    t = r.run(reach.path + reach.descent, JOINT_SPEED)
    # move the handle along the joint's path (a drawer's line, a lid's arc), the arm following IK waypoints
    pl = planner_for(ctx, r)
    spec = f.container
    yaw = r.arm_yaw()
    pulled = 0.0
    for s in np.linspace(0.0, spec.travel, PULL_STEPS + 1)[1:]:
        ctx.world.set_container(f.name, float(s))  # the drawer or lid (handle held) moves out of the planner's way
        hx, hy, hz = ctx.world.handle_position(f.name)
        q = pl.ik((hx, hy, hz + TIP_CLEARANCE), yaw, r.q, restarts=3)
        if q is None or float(np.max(np.abs(q - r.q))) > 0.6:
            ctx.world.set_container(f.name, pulled)
            break
        t += r.run([r.q, q], JOINT_SPEED)
        pulled = float(s)
    if pulled < spec.travel - 1e-6:
        ctx.world.set_container(f.name, 0.0)
        t += r.run(straight(r.q, q0, 10), JOINT_SPEED)
        return SkillOutcome.fail(OutcomeCode.OUT_OF_REACH, fb.pull_failed(f.name), sim_time=t, pulled=round(pulled, 3))
    return _opened(ctx, r, f, pl, yaw, t, pulled)


def _opened(
    ctx: SkillContext, r: RobotBody, f: FurnitureSpec, pl: ArmPlanner, yaw: float, t: float, travel: float
) -> SkillOutcome:
    """Let go of the handle of an opened container: lift, retract, look inside."""
    lift = pl.ik((r.tip()[0], r.tip()[1], r.tip()[2] + 0.08), yaw, r.q, restarts=2)
    if lift is not None:
        t += r.run(straight(r.q, lift, 5), JOINT_SPEED)
    t += retract(ctx, r)
    ctx.knowledge.look_at(r.name, f.name)
    inside = [(n, ctx.world.position(ctx.world.objects[n])) for n in ctx.world.objects_on(f.name)]
    return SkillOutcome.ok(fb.opened(f.name, inside), sim_time=t + 2 * SUCTION_TIME, travel=round(travel, 3))


def _swing(f: FurnitureSpec) -> tuple[float, float, float]:
    """A lid's or a side-hinged door's angle (rad), how far above its handle the tool holds it,
    and how the tool turns per radian of swing (a door's handle turns about the vertical hinge)."""
    if f.lid is not None:
        return f.lid.angle, LID_CLEARANCE, 0.0
    assert f.door is not None
    return f.door.angle, TIP_CLEARANCE, -f.cupboard_geometry().side


def _lid_arc(
    ctx: SkillContext, pl: ArmPlanner, f: FurnitureSpec, values: np.ndarray, seed: np.ndarray, yaw: float
) -> list[np.ndarray]:
    """Joint waypoints that keep the tool on the handle while the lid or door passes through
    `values` (rad, in either order), starting from an IK solution seeded by `seed`, as far as IK
    follows without a jump. The lid or door is left shut again."""
    _, clearance, turn = _swing(f)
    path: list[np.ndarray] = []
    for v in values:
        ctx.world.set_container(f.name, float(v))
        hx, hy, hz = ctx.world.handle_position(f.name)
        q = pl.ik((hx, hy, hz + clearance), yaw + turn * float(v), path[-1] if path else seed, restarts=1)
        if q is None or (path and float(np.max(np.abs(q - path[-1]))) > 0.6):
            break
        path.append(q)
    ctx.world.set_container(f.name, 0.0)
    return path


def _open_lid(ctx: SkillContext, r: RobotBody, f: FurnitureSpec) -> SkillOutcome:
    """Grip the handle of a lid (and swing it up) or of a side-hinged door (and swing it out).
    Several grasp configurations are tried, each checked along the whole arc before the arm
    moves: the first that follows it is used."""
    angle, clearance, _ = _swing(f)
    pl = planner_for(ctx, r)
    yaw = r.arm_yaw()
    ab = r.arm_base()
    assert ab is not None
    hx, hy, hz = ctx.world.handle_position(f.name)
    handle = (hx, hy, hz + clearance)
    above = (hx, hy, handle[2] + APPROACH)
    if horizontal(ab, handle) > MAX_ARM_RANGE:
        return SkillOutcome.fail(
            OutcomeCode.OUT_OF_REACH,
            fb.handle_out_of_reach(
                f.name, horizontal(ab, handle), mobile="navigate" in r.kind.skills, advice=ctx.advice
            ),
            horizontal_distance=round(horizontal(ab, handle), 3),
        )
    values = np.linspace(0.0, angle, PULL_STEPS + 1)
    followed, grasped = 0, False
    for k in range(LID_GRASP_TRIES):
        seed = HOME if k == 0 else pl.rng.uniform(LOWER, UPPER)
        # the open end is the harder pose: solve it first and follow the arc back down, else up
        arc = _lid_arc(ctx, pl, f, values[::-1], seed, yaw)[::-1]
        if len(arc) < len(values):
            arc = _lid_arc(ctx, pl, f, values, seed, yaw)
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
            ctx.world.set_container(f.name, float(v))
            t += r.run([r.q, q], JOINT_SPEED)
        return _opened(ctx, r, f, pl, yaw + _swing(f)[2] * angle, t, angle)
    if not grasped:  # within range, yet no arm configuration grips the handle from this base pose
        return SkillOutcome.fail(
            OutcomeCode.OUT_OF_REACH,
            fb.no_grip(f.name, horizontal(ab, handle)),
            horizontal_distance=round(horizontal(ab, handle), 3),
        )
    return SkillOutcome.fail(
        OutcomeCode.OUT_OF_REACH, fb.pull_failed(f.name), pulled=round(followed * angle / PULL_STEPS, 3)
    )
