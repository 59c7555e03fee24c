"""The description function: one robot's own Observation as the text sections of its prompt.

It reads nothing but that robot's `Observation`, so a prompt never shows what the robot has
not seen or been told. Every number is rounded to centimetres and whole degrees, so the
text (and a replayed prompt) is stable across platforms.

By default the text holds what the paper's scene graph and status hold: positions,
orientations, open or closed, stand poses, place poses, the gripper. With `hints` (the
prompt_hints aid) it adds what the paper leaves to the model: each furniture's kind, which
furniture is no navigation target, each object's distance from the robot's arm base, and
where that arm base is and how far it reaches.
"""

from __future__ import annotations

import math

from mhrc.core.protocol import FurnitureView, ObjectView, Observation

from .parse import SIGNATURES

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
        parts.append("open" if f.is_open else "closed (open it to see inside)")
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
    """`- name: where it lies, position`; with `hints`, its distance from the robot's arm base
    (or base); with the reach_labels aid, whether that is within the arm's reach (the paper's
    prompts leave both to the model). An object the robot looked for and no longer found where
    it was gets neither place nor distance; one it knows only from a message says who told it."""
    told = f" ({o.told_by.capitalize()} told you)" if o.told_by else ""
    if o.last_seen_on and not (o.on or o.held_by):
        return f"- {o.name}: no longer on {o.last_seen_on}, where it was last seen at {_xyz(o.position)}; where it is now is unknown{told}"
    if o.held_by:
        where = "in your gripper" if o.held_by == obs.robot else f"held by {o.held_by}"
    elif o.on:
        where = f"inside {o.on}" if o.inside else (f"in the {o.on}" if o.on == "tray" else f"on {o.on}")
    else:
        where = "on the floor"
    text = f"- {o.name}: {where}{told}, at {_xyz(o.position)}"
    if o.held_by:
        return text
    s = obs.status
    if s.arm_base is not None and s.reach is not None:
        d = _flat(o.position, s.arm_base)
        if hints:
            text += f", {d:.2f} m from your arm base"
        if reach_labels:
            text += " (within your reach)" if d <= s.reach else " (out of your reach)"
    elif s.base is not None and hints:
        text += f", {_flat(o.position, (s.base.x, s.base.y)):.2f} m from you"
    return text


def scene_graph(obs: Observation, reach_labels: bool = False, hints: bool = False) -> str:
    """Furniture (always known), then the objects this robot knows of."""
    navigates = "navigate" in obs.status.skills
    lines = ["Furniture:"] + [furniture_line(f, navigates, hints) for f in obs.furniture]
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
    """Position and orientation, where the robot stands, gripper; with `hints`, the arm base and
    its reach."""
    s = obs.status
    lines = [f"You are {s.name.capitalize()}, a {s.kind}. Current step: {obs.tick}."]
    if s.base is not None:
        at = standing_at(obs)
        lines.append(f"Position: ({s.base.x:.2f}, {s.base.y:.2f}); orientation: yaw {_deg(s.base.yaw)}" + (f"; at {at}." if at else "; not at any stand pose."))
    else:
        where = f" at {_xyz(s.arm_base)}" if s.arm_base is not None else ""
        lines.append(f"Your base is fixed{where}: you cannot move.")
    if hints and s.arm_base is not None and s.reach is not None:
        lines.append(f"Arm base: {_xyz(s.arm_base)}; reach about {s.reach:.2f} m from it.")
    if "pick" in s.skills:
        lines.append(f"Gripper: holding {s.holding}." if s.holding else "Gripper: empty.")
    return "\n".join(lines)


def task_text(obs: Observation) -> str:
    """Brief and detailed task; Bob's object list."""
    lines = [f"Task: {obs.task_brief}", f"Details: {obs.task_detail}"]
    if obs.targets:
        lines.append(f"Object list: {', '.join(obs.targets)}.")
    return "\n".join(lines)


def progress_text(obs: Observation) -> str:
    """The latest task progress status (Bob's), or a placeholder for robots without one."""
    return obs.task_status or "(no progress report for you)"


def teammates(obs: Observation, absent: tuple[str, ...] = ()) -> str:
    """`- Name: signature, signature` for every teammate present in this episode."""
    present = {n: s for n, s in obs.teammates.items() if n not in absent}
    lines = [f"- {n.capitalize()}: {', '.join(SIGNATURES.get(k, k) for k in s)}" for n, s in present.items()]
    return "\n".join(lines) or "- nobody: you are on your own"
