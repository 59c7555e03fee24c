"""The description function: one robot's own observation as text for its prompt.

It reads nothing but the robot's `Observation`, so a prompt can never leak what the robot
has not seen.
"""

from __future__ import annotations

import math

from mhrc.protocol import Observation


def _xyz(p: tuple[float, float, float]) -> str:
    return f"({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f})"


def scene_graph(obs: Observation) -> str:
    lines = []
    for f in obs.furniture:
        parts = [f"position {_xyz(f.position)}", f"yaw {math.degrees(f.yaw):.0f} deg"]
        if f.openable:
            parts.append("state open" if f.is_open else "state closed")
        if f.stand_poses:
            poses = ", ".join(f"{i}: ({s.x:.2f}, {s.y:.2f}, yaw {math.degrees(s.yaw):.0f} deg)" for i, s in enumerate(f.stand_poses))
            parts.append(f"stand poses [{poses}]")
        if f.place_pose:
            parts.append(f"place pose {_xyz(f.place_pose)}")
        lines.append(f"- {f.name} ({f.kind}): " + "; ".join(parts))
    if obs.objects:
        lines.append("Objects you know of:")
        for o in obs.objects:
            where = f"held by {o.held_by}" if o.held_by else (f"inside {o.on}" if o.inside else f"on {o.on}" if o.on else "on the floor")
            lines.append(f"- {o.name}: position {_xyz(o.position)}, {where}")
    else:
        lines.append("Objects you know of: none yet.")
    return "\n".join(lines)


def robot_status(obs: Observation) -> str:
    s = obs.status
    parts = [f"You are {s.name}, a {s.kind}."]
    if s.base is not None:
        parts.append(f"Base pose: ({s.base.x:.2f}, {s.base.y:.2f}), yaw {math.degrees(s.base.yaw):.0f} deg.")
    if s.arm_base is not None:
        parts.append(f"Arm base at {_xyz(s.arm_base)}, reach about {s.reach:.2f} m.")
    if "pick" in s.skills:
        parts.append(f"Gripper: holding {s.holding}." if s.holding else "Gripper: empty.")
    return " ".join(parts)


def task_text(obs: Observation) -> str:
    lines = [f"Task: {obs.task_brief}", f"Details: {obs.task_detail}"]
    if obs.targets:
        lines.append(f"Object list: {', '.join(obs.targets)}.")
    if obs.task_status:
        lines.append(f"Latest task progress: {obs.task_status}")
    return "\n".join(lines)


def teammates(obs: Observation) -> str:
    return "\n".join(f"- {name}: {', '.join(skills)}" for name, skills in obs.teammates.items()) or "- nobody"
