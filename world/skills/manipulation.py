"""The gripper skills: pick an object by suction from its top, place the held object on a
free spot of a surface or a goal fixture.

By default a released object falls from the tool with a small seeded error (a slip now and then,
`release_error`: mhrc's calibration, mhrc.core.fidelity) and settles under physics
(PhysicalWorld.release), so a place can miss; with `--noise off` it falls from exactly where the
tool lets go, and the exact_motion aid sets it down without physics. Only a robot kind that finishes the task (Bob) places on
the task's goal fixtures; a helper hands over within his reach.
"""

from __future__ import annotations

import math

import numpy as np

from mhrc.core.fidelity import CALIBRATION
from mhrc.core.protocol import OutcomeCode, Pick, Place, SkillOutcome

from .. import feedback as fb
from ..kinds import MAX_ARM_RANGE
from ..physics import ObjectState, half_extent
from ..robots import RobotBody
from .context import SkillContext
from .reaching import JOINT_SPEED, SUCTION_TIME, TIP_CLEARANCE, horizontal, reach_point, retract, too_far, wrap
from .registry import skill

HANDOVER_CLEARANCE = 0.2  # m between a handed-over object and the hand of the robot that put it there
# a released object falls under gravity from where the tool lets go of it, that point off by a small
# error (Rayleigh-distributed length again) or, now and then, by a slip of the object off the suction cup;
# the rates are the episode's (SkillContext.noise), by default the calibration
RELEASE_SIGMA = CALIBRATION.release_sigma  # m: the Rayleigh scale of an ordinary release's error
RELEASE_SLIP_P = CALIBRATION.release_slip  # the chance that the object slips as it is let go (10%)
RELEASE_SLIP = (0.02, 0.04)  # m: how far a slip shifts it (a solid never reaches the next colour panel)


@skill(Pick)
def pick(ctx: SkillContext, r: RobotBody, a: Pick) -> SkillOutcome:
    if r.holding is not None:
        return SkillOutcome.fail(OutcomeCode.GRIPPER_FULL, fb.gripper_full(r.holding, advice=ctx.advice))
    known = ctx.knowledge.known_objects(r.name)
    if a.obj not in known:
        return SkillOutcome.fail(OutcomeCode.OBJECT_UNKNOWN, fb.object_unknown(a.obj, sorted(known), advice=ctx.advice))
    obj = ctx.world.objects[a.obj]
    if obj.held_by is not None:
        return SkillOutcome.fail(OutcomeCode.OBJECT_UNKNOWN, fb.held_by_other(obj.name, obj.held_by))
    if obj.inside and obj.on is not None and not ctx.world.is_open(obj.on):
        can_open = "open" in r.kind.skills
        return SkillOutcome.fail(
            OutcomeCode.NOT_REACHABLE_CONTAINER,
            fb.in_closed_container(obj.name, obj.on, can_open=can_open, advice=ctx.advice),
        )
    x, y, z = ctx.world.position(obj)
    top = (x, y, z + obj.kind.height / 2 + TIP_CLEARANCE)
    reach = reach_point(ctx, r, top, obj.name, any_yaw=True)  # a suction cup grips at any turn of the tool
    if reach.failure is not None:
        return reach.failure
    if reach.path is None or reach.descent is None:
        return too_far(ctx, r, top, obj.name, reach.distance)
    t = r.run(reach.path + reach.descent, JOINT_SPEED)
    ctx.grasp(r, obj)
    t += r.run(list(reversed(reach.descent)), JOINT_SPEED)
    t += retract(ctx, r)
    return SkillOutcome.ok(fb.picked(obj.name), sim_time=t + SUCTION_TIME)


def free_spots(
    ctx: SkillContext, location: str, held: ObjectState
) -> tuple[list[tuple[float, float, float]], float] | None:
    """Spots (x, y, yaw) at `location` where `held` fits without touching anything, best first, and the surface z."""
    lay = ctx.world.layout
    fx = ctx.world.fixtures.get(location)
    if fx is not None and fx.stack:  # a stack grows at the fixture's centre
        return [(fx.center[0], fx.center[1], 0.0)], ctx.world.surface_top(fx.name, without=held)
    if fx is not None:
        (cx, cy), (sx, sy) = fx.center, fx.size
        inset = 0.015 if fx.rim else 0.0
        top = ctx.world.fixture_top(fx.name)
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
    for o in ctx.world.objects.values():
        if o is held or o.held_by is not None:
            continue
        ox, oy, oz = ctx.world.position(o)
        if abs(oz - o.kind.height / 2 - top) < 0.15:
            boxes.append(((ox, oy), half_extent(o.kind, ctx.world.yaw(o))))
    if avoid_goal_area:
        boxes.append((lay.goal_area[:2], (lay.goal_area[2] / 2, lay.goal_area[3] / 2)))
    out: list[tuple[float, float, float]] = []
    for yaw in (0.0, math.pi / 2):
        hx, hy = half_extent(held.kind, yaw)
        xs = [round(float(x), 4) for x in np.arange(x0 + hx, x1 - hx + 1e-9, 0.02)]
        ys = [round(float(y), 4) for y in np.arange(y0 + hy, y1 - hy + 1e-9, 0.02)]
        clear = _clear(xs, ys, (hx, hy), boxes)  # [x, y]: the spot overlaps no box
        for i, cx_ in enumerate(xs):
            for j, cy_ in enumerate(ys):
                if radius < math.inf and math.hypot(cx_ - center[0], cy_ - center[1]) > radius:
                    continue
                if clear[i][j]:
                    out.append((cx_, cy_, yaw))
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


def _clear(
    xs: list[float],
    ys: list[float],
    half: tuple[float, float],
    boxes: list[tuple[tuple[float, float], tuple[float, float]]],
) -> list[list[bool]]:
    """For every spot (x, y) of xs x ys, whether a box of `half` extents there overlaps none of
    `boxes`: `_overlaps` for the whole grid of spots at once (the same comparisons, per axis)."""
    if not boxes:
        return [[True] * len(ys) for _ in xs]
    centers = np.array([b for b, _ in boxes])
    halves = np.array([h for _, h in boxes])
    near_x = np.abs(np.array(xs)[None, :] - centers[:, :1]) < half[0] + halves[:, :1]  # [box, x]
    near_y = np.abs(np.array(ys)[None, :] - centers[:, 1:]) < half[1] + halves[:, 1:]  # [box, y]
    hit = (near_x[:, :, None] & near_y[:, None, :]).any(axis=0)
    return (~hit).tolist()  # type: ignore[no-any-return]


def tool_yaw_for(r: RobotBody, object_yaw: float) -> float:
    """The tool heading that sets the held object down at `object_yaw`, nearest the arm's heading."""
    base = object_yaw - r.held_yaw
    return min((base + k * math.pi for k in (-2, -1, 0, 1, 2)), key=lambda y: abs(wrap(y - r.arm_yaw())))


def release_error(ctx: SkillContext) -> tuple[float, float]:
    """How far (x, y) from where the tool lets go a released object starts to fall: one draw per release."""
    return ctx.motion_error(ctx.noise.release_slip, RELEASE_SLIP, ctx.noise.release_sigma)


def _handover_margin(ctx: SkillContext, spot: tuple[float, ...]) -> float:
    """How far `spot` lies inside the band on Bob's table from which the robot that finishes the
    task picks (PhysicalWorld.within_handover)."""
    fin = ctx.world.finisher()
    ab = fin.arm_base() if fin is not None else None
    if fin is None or ab is None or fin.kind.reach is None:
        return math.inf
    d = horizontal(spot, ab)
    return min(d - 0.3, fin.kind.reach - 0.03 - d)


@skill(Place)
def place(ctx: SkillContext, r: RobotBody, a: Place) -> SkillOutcome:
    if r.holding is None:
        return SkillOutcome.fail(OutcomeCode.GRIPPER_EMPTY, fb.gripper_empty(a.obj))
    if a.obj != r.holding:
        return SkillOutcome.fail(OutcomeCode.WRONG_OBJECT, fb.wrong_object(r.holding, a.obj))
    held = ctx.world.objects[r.holding]
    if a.location in ctx.world.fixtures and not r.kind.finishes_task:  # the paper: only Bob finishes the task
        fin = ctx.world.finisher()
        finisher = fin.name if fin is not None else "the robot that finishes the task"
        return SkillOutcome.fail(
            OutcomeCode.NOT_CAPABLE,
            fb.not_a_finisher(held.name, a.location, ctx.world.layout.bob_table, finisher, advice=ctx.advice),
        )
    places = [n for n in ctx.world.place_names() if r.kind.finishes_task or n not in ctx.world.fixtures]
    f = ctx.world.layout.get(a.location)
    if f is not None and f.place_pose is None:
        return SkillOutcome.fail(OutcomeCode.LOCATION_UNKNOWN, fb.not_a_surface(f.name, places, advice=ctx.advice))
    spots = free_spots(ctx, a.location, held)
    if spots is None:
        return SkillOutcome.fail(
            OutcomeCode.LOCATION_UNKNOWN, fb.location_unknown(a.location, places, advice=ctx.advice)
        )
    cands, top = spots
    if a.location == ctx.world.layout.bob_table:
        cands = [c for c in cands if ctx.world.within_handover(c)] or cands
        if (
            ctx.noise.release_slip > 0 and not r.kind.finishes_task
        ):  # a slip as it is let go must not carry it out of the finisher's reach
            cands = [
                c for c in cands if _handover_margin(ctx, c) >= RELEASE_SLIP[1] + 3 * ctx.noise.release_sigma
            ] or cands
        if (
            r.kind.mobile
        ):  # not under where this arm's hand will hover once it has retracted: Bob could not reach past it
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
        return SkillOutcome.fail(
            OutcomeCode.TOO_FAR,
            fb.place_out_of_reach(a.location, nearest, mobile=can_go, advice=ctx.advice),
            distance=round(nearest, 3),
        )
    failure: SkillOutcome | None = None
    tries = 0
    for x, y, yaw in reachable:
        point = (x, y, top + held.kind.height + TIP_CLEARANCE + 0.002)
        tool = wrap(tool_yaw_for(r, yaw))
        reach = reach_point(ctx, r, point, f"the spot on {a.location}", tool_yaw=tool)
        if reach.path is None or reach.descent is None:
            failure = failure or reach.failure
            tries += 1
            if tries >= 8:
                break
            continue
        t = r.run(reach.path + reach.descent, JOINT_SPEED)
        ctx.world.release(r, held, (x, y, top), yaw, a.location, release_error(ctx))
        t += r.run(list(reversed(reach.descent)), JOINT_SPEED)
        t += retract(ctx, r)
        if not ctx.world.settled_at(held, a.location):
            pos = ctx.world.position(held)
            return SkillOutcome.fail(
                OutcomeCode.PLACE_FAILED,
                fb.place_failed(held.name, a.location, held.on, pos),
                sim_time=t + SUCTION_TIME,
                on=held.on or "floor",
                x=round(pos[0], 3),
                y=round(pos[1], 3),
                z=round(pos[2], 3),
            )
        return SkillOutcome.ok(fb.placed(held.name, a.location), sim_time=t + SUCTION_TIME)
    if failure is not None:
        return failure
    nearest = min(horizontal(ab, c) for c in reachable)
    return SkillOutcome.fail(
        OutcomeCode.TOO_FAR,
        fb.place_out_of_reach(a.location, nearest, mobile=can_go, advice=ctx.advice),
        distance=round(nearest, 3),
    )
