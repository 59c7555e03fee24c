"""What a robot is told each step: its view of the furniture, the objects, its teammates and their messages."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from mhrc.core.protocol.base import Message, _Model

# --------------------------------------------------------------------------- observation


class Pose2D(_Model):
    x: float
    y: float
    yaw: float = 0.0


class FurnitureView(_Model):
    name: str
    kind: str
    position: tuple[float, float, float]
    yaw: float = 0.0
    openable: bool = False
    is_open: bool | None = None  # None where the furniture cannot open; in a robot's view, as it last saw it
    stand_poses: list[Pose2D] = Field(default_factory=list)
    place_pose: tuple[float, float, float] | None = None


class ObjectView(_Model):
    """An object as one robot last saw it or was last told of it (its scene graph is its memory);
    ground truth only in observers' views and with the live_state aid."""

    name: str
    position: tuple[float, float, float]
    yaw: float | None = Field(
        None,
        description="its orientation about the vertical axis (radians) when seen; None in traces before it was sent",
    )
    on: str | None = Field(None, description="furniture (or receptacle) the object lies on or in")
    inside: bool = Field(False, description="inside a container rather than on a surface")
    held_by: str | None = None
    last_seen_on: str | None = Field(
        None,
        description="the robot looked again where it believed the object was and it was gone: this is that place, "
        "`position` is where it was last seen, `on` is None, where it is now is unknown",
    )
    told_by: str | None = Field(None, description="the belief came from this robot's message, not the robot's own eyes")


class RobotMessage(Message):
    """A `communicate` message from one robot to another, delivered by the world."""

    kind: Literal["message"] = "message"
    sender: str
    to: str
    content: str
    tick: int


class RobotStatus(_Model):
    name: str
    kind: str
    skills: list[str]
    base: Pose2D | None = None  # None for a fixed arm (Bob)
    arm_base: tuple[float, float, float] | None = None
    reach: float | None = Field(None, description="arm reach in metres, None without an arm")
    holding: str | None = None


class Observation(_Model):
    """One robot's own view of the world: its partial scene graph, status and new messages."""

    robot: str
    tick: int
    status: RobotStatus
    furniture: list[FurnitureView]
    objects: list[ObjectView]
    task_brief: str
    task_detail: str
    targets: list[str] = Field(default_factory=list, description="the task's object list (Bob only)")
    goals: dict[str, str] = Field(
        default_factory=dict, description="target -> where it must end: tray, panel, board (Bob only)"
    )
    ordered: bool = Field(
        False, description="whether the targets must reach their goals in the listed order (a sandwich)"
    )
    task_status: str | None = Field(None, description="progress text (Bob only)")
    teammates: dict[str, list[str]] = Field(
        default_factory=dict,
        description="robot -> its skills, for the teammates attached now (one whose agent left is not listed)",
    )
    new_messages: list[RobotMessage] = Field(default_factory=list)
