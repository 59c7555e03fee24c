"""The description function: one robot's own Observation as the text sections of its prompt.

It reads nothing but that robot's `Observation`, so a prompt never shows what the robot has
not seen or been told. Every number is rounded to centimetres and whole degrees, so the
text (and a replayed prompt) is stable across platforms.

By default the text holds what the paper's scene graph and status hold (the appendix's
fields): furniture with position, orientation, open or closed, stand poses and place pose; each
known object's position; the robot's position, orientation and gripper. A robot that does not
navigate (the paper's Bob) sees only what lies on its table: the goal fixtures and the objects
there, no furniture of the house. With `hints` (the prompt_hints aid) it adds what the paper
leaves to the model: each furniture's kind, which furniture is no navigation target, where
each object lies and who told the robot of it, its distance from the robot's arm base, the
step, the stand pose the robot is at, and where its arm base is and how far it reaches.
"""

from __future__ import annotations

import math

from mhrc.core.protocol import FurnitureView, ObjectView, Observation
from mhrc.core.protocol.actions import CALLS

from .parse import signature

AT_POSE_TOL = 0.1  # metres: the base counts as standing at a stand pose within this (a navigation that stops
# farther away fails as off target)


def _xyz(p: tuple[float, float, float]) -> str:
    return f"({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f})"


def _deg(rad: float) -> str:
    d = round(math.degrees(rad))
    return f"{0 if d == 0 else d} deg"  # no "-0 deg"


def _flat(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


def furniture_line(f: FurnitureView, navigates: bool = True, hints: bool = False) -> str:
    """`- name: position, yaw; state; stand poses (for robots that navigate); place pose`; with
    `hints`, the kind after the name and "no stand pose (not a navigation target)"."""
    parts = [f"position {_xyz(f.position)}, yaw {_deg(f.yaw)}"]
    if f.openable:
        parts.append("open" if f.is_open else "closed (open it to see inside)" if hints else "closed")
    if navigates and f.stand_poses:
        poses = ", ".join(f"{i} = ({s.x:.2f}, {s.y:.2f}, yaw {_deg(s.yaw)})" for i, s in enumerate(f.stand_poses))
        parts.append(f"stand poses {poses}")
    elif navigates and hints:
        parts.append("no stand pose (not a navigation target)")
    if f.place_pose is not None:
        parts.append(f"place pose {_xyz(f.place_pose)}")
    kind = f" ({f.kind})" if hints else ""
    return f"- {f.name}{kind}: " + "; ".join(parts)


def object_line(o: ObjectView, obs: Observation, reach_labels: bool = False, hints: bool = False) -> str:
    """`- name: position (x, y, z), yaw N deg` (the appendix's fields: position and
    orientation, as last seen); an object the robot looked for and no longer found where it was:
    `position unknown`. With `hints`, where it lies, who told the
    robot of it and its distance from the robot's arm base (or base); with the reach_labels
    aid, whether that is within the arm's reach (the paper's prompts leave all that to the model)."""
    gone = bool(o.last_seen_on and not (o.on or o.held_by))
    if not hints:
        if gone:
            return f"- {o.name}: position unknown"
        text = f"- {o.name}: position {_xyz(o.position)}{_yaw(o)}"
        return text + _reach(o, obs) if reach_labels and not o.held_by else text
    told = f" ({o.told_by.capitalize()} told you)" if o.told_by else ""
    if gone:
        return f"- {o.name}: no longer on {o.last_seen_on}, where it was last seen at {_xyz(o.position)}; where it is now is unknown{told}"
    if o.held_by:
        where = "in your gripper" if o.held_by == obs.robot else f"held by {o.held_by}"
    elif o.on:
        where = f"inside {o.on}" if o.inside else (f"in the {o.on}" if o.on == "tray" else f"on {o.on}")
    else:
        where = "on the floor"
    text = f"- {o.name}: {where}{told}, at {_xyz(o.position)}{_yaw(o)}"
    if o.held_by:
        return text
    s = obs.status
    if s.arm_base is not None and s.reach is not None:
        text += f", {_flat(o.position, s.arm_base):.2f} m from your arm base"
    elif s.base is not None:
        text += f", {_flat(o.position, (s.base.x, s.base.y)):.2f} m from you"
    return text + _reach(o, obs) if reach_labels else text


def _yaw(o: ObjectView) -> str:
    """`, yaw N deg`: the object's orientation as seen ("" in traces from before it was sent)."""
    return f", yaw {_deg(o.yaw)}" if o.yaw is not None else ""


def _reach(o: ObjectView, obs: Observation) -> str:
    """The reach_labels aid: whether `o` lies within the robot's arm reach ("" for a robot without an arm)."""
    s = obs.status
    if s.arm_base is None or s.reach is None:
        return ""
    return " (within your reach)" if _flat(o.position, s.arm_base) <= s.reach else " (out of your reach)"


def scene_graph(obs: Observation, reach_labels: bool = False, hints: bool = False) -> str:
    """Furniture, then the objects this robot knows of. A robot that does not navigate sees
    only its table's goal fixtures (furniture without stand poses), as the appendix's Bob."""
    navigates = "navigate" in obs.status.skills
    furniture = obs.furniture if navigates else [f for f in obs.furniture if not f.stand_poses]
    lines = ["Furniture:"] + [furniture_line(f, navigates, hints) for f in furniture]
    if obs.objects:
        lines.append("Objects you know of:")
        lines += [object_line(o, obs, reach_labels, hints) for o in obs.objects]
    else:
        lines.append("Objects you know of: none yet.")
    return "\n".join(lines)


def standing_at(obs: Observation) -> str | None:
    """`stand pose i of name` when the base stands on one, else None."""
    b = obs.status.base
    if b is None:
        return None
    for f in obs.furniture:
        for i, s in enumerate(f.stand_poses):
            if math.hypot(b.x - s.x, b.y - s.y) <= AT_POSE_TOL:
                return f"stand pose {i} of {f.name}"
    return None


def robot_status(obs: Observation, hints: bool = False) -> str:
    """Position and orientation, gripper (the appendix's status); with `hints`, also the
    robot's kind, the step, the stand pose it is at, and its arm base and reach."""
    s = obs.status
    lines = [f"You are {s.name.capitalize()}, a {s.kind}. Current step: {obs.tick}."] if hints else []
    if s.base is not None:
        where = f"Position: ({s.base.x:.2f}, {s.base.y:.2f}); orientation: yaw {_deg(s.base.yaw)}"
        if hints:
            at = standing_at(obs)
            where += f"; at {at}" if at else "; not at any stand pose"
        lines.append(where + ".")
    else:
        where = f" at {_xyz(s.arm_base)}" if s.arm_base is not None else ""
        lines.append(f"Your base is fixed{where}: you cannot move.")
    if hints and s.arm_base is not None and s.reach is not None:
        lines.append(f"Arm base: {_xyz(s.arm_base)}; reach about {s.reach:.2f} m from it.")
    if "pick" in s.skills:
        lines.append(f"Gripper: holding {s.holding}." if s.holding else "Gripper: empty.")
    return "\n".join(lines)


def task_text(obs: Observation) -> str:
    """Brief and detailed task, as the world words them for this robot's role (the finisher's
    detail holds its list)."""
    return f"Brief: {obs.task_brief}\nDetails: {obs.task_detail}"


PROGRESS_TITLE = "Latest task progress"


def progress_text(obs: Observation) -> str:
    """The latest task progress status as a titled section (the finisher's; Table III's Target
    Task Status), or "" for a robot without one."""
    return f"{PROGRESS_TITLE}:\n{obs.task_status}" if obs.task_status else ""


def teammates(obs: Observation, absent: tuple[str, ...] = ()) -> str:
    """`- Name: signature, signature` for every teammate present in this episode."""
    present = {n: s for n, s in obs.teammates.items() if n not in absent}
    lines = [
        f"- {n.capitalize()}: {', '.join(signature(k) if k in CALLS else k for k in s)}" for n, s in present.items()
    ]
    return "\n".join(lines) or "- nobody: you are on your own"
