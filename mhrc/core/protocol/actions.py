"""The paper's skills as actions (`skill` discriminates the union) and their outcomes."""

from __future__ import annotations

from enum import Enum
from typing import Annotated, Any, Literal, Union

from pydantic import Field, TypeAdapter, ValidationError

from mhrc.core.protocol.base import MAX_INT, MAX_MOVE, MAX_NAME, ProtocolError, _Model, _reason

# --------------------------------------------------------------------------- actions
# The paper's skills, with their arguments. `skill` discriminates the union.


class Navigate(_Model):
    skill: Literal["navigate"] = "navigate"
    target: str = Field(max_length=MAX_NAME, description="furniture name from the scene graph")
    stand_pose: int = Field(0, ge=0, le=MAX_INT, description="index of the target's stand pose")

    def call(self) -> str:
        return f"navigate({self.target}, {self.stand_pose})"


class Move(_Model):
    skill: Literal["move"] = "move"
    dx: float = Field(ge=-MAX_MOVE, le=MAX_MOVE, allow_inf_nan=False, description="metres along the world x axis")
    dy: float = Field(ge=-MAX_MOVE, le=MAX_MOVE, allow_inf_nan=False, description="metres along the world y axis")

    def call(self) -> str:
        return f"move({self.dx:.2f}, {self.dy:.2f})"


class Open(_Model):
    skill: Literal["open"] = "open"
    target: str = Field(max_length=MAX_NAME)

    def call(self) -> str:
        return f"open({self.target})"


class Pick(_Model):
    skill: Literal["pick"] = "pick"
    obj: str = Field(max_length=MAX_NAME)

    def call(self) -> str:
        return f"pick({self.obj})"


class Place(_Model):
    skill: Literal["place"] = "place"
    obj: str = Field(max_length=MAX_NAME)
    location: str = Field(max_length=MAX_NAME, description="furniture or receptacle name, e.g. table_0 or tray")

    def call(self) -> str:
        return f"place({self.obj}, {self.location})"


class Communicate(_Model):
    skill: Literal["communicate"] = "communicate"
    content: str = Field(min_length=1, max_length=4000)
    to: str = Field(max_length=MAX_NAME)

    def call(self) -> str:
        return f"communicate({self.content!r}, {self.to})"


class Wait(_Model):
    skill: Literal["wait"] = "wait"

    def call(self) -> str:
        return "wait()"


Action = Annotated[Union[Navigate, Move, Open, Pick, Place, Communicate, Wait], Field(discriminator="skill")]
ACTION_ADAPTER: TypeAdapter[Action] = TypeAdapter(Action)
SKILLS = ("navigate", "move", "open", "pick", "place", "communicate", "wait")


# --------------------------------------------------------------------------- outcomes


class OutcomeCode(str, Enum):
    """Why a skill succeeded or failed (the rows of the paper's feedback table)."""

    OK = "ok"
    NOT_CAPABLE = "not_capable"  # the robot lacks this skill
    TARGET_UNKNOWN = "target_unknown"  # not in the robot's scene graph
    NOT_NAVIGABLE = "not_navigable"  # target exists but has no stand poses
    STAND_POSE_INVALID = "stand_pose_invalid"  # no stand pose with that index
    START_INVALID = "start_invalid"  # base start pose on an obstacle or off the map
    GOAL_INVALID = "goal_invalid"  # goal pose on an obstacle or off the map
    NO_PATH = "no_path"
    OFF_TARGET = "off_target"  # final pose too far from the goal
    OCCUPIED = "occupied"  # another robot stands at the goal stand pose (one robot per stand pose)
    ALREADY_OPEN = "already_open"
    NOT_OPENABLE = "not_openable"
    OUT_OF_REACH = "out_of_reach"  # furniture or object beyond the arm's reach
    GRIPPER_FULL = "gripper_full"
    GRIPPER_EMPTY = "gripper_empty"
    OBJECT_UNKNOWN = "object_unknown"
    CONFIG_INVALID = "config_invalid"  # arm planner: start or goal configuration invalid
    PLAN_FAILED = "plan_failed"  # arm planner found no collision-free motion
    TOO_FAR = "too_far"  # end effector could not get close enough to the object
    WRONG_OBJECT = "wrong_object"  # place names an object other than the held one
    PLACE_FAILED = "place_failed"  # object did not end up at the target
    LOCATION_UNKNOWN = "location_unknown"
    NOT_REACHABLE_CONTAINER = "closed_container"  # object inside a closed container
    RECIPIENT_UNKNOWN = "recipient_unknown"
    FORMAT_ERROR = "format_error"  # the policy's reply could not be parsed into an action
    BROKEN_DOWN = "broken_down"  # a scenario's breakdown: only communicate and wait work for now


class SkillOutcome(_Model):
    """What one skill did, as the simulator measured it."""

    succeeded: bool
    code: OutcomeCode
    feedback: str = Field(description="the paper-style sentence the robot's agent reads")
    details: dict[str, float | str] = Field(default_factory=dict)
    sim_time: float = Field(0.0, ge=0.0, description="simulated seconds the skill took")
    path: list[tuple[float, float]] | None = Field(
        None,
        description="navigate: the base's planned route in metres, start to stop (a few dozen points at most), for viewers",
    )

    @classmethod
    def ok(cls, feedback: str, *, sim_time: float = 0.0, **details: Any) -> SkillOutcome:
        return cls(succeeded=True, code=OutcomeCode.OK, feedback=feedback, details=details, sim_time=sim_time)

    @classmethod
    def fail(cls, code: OutcomeCode, feedback: str, *, sim_time: float = 0.0, **details: Any) -> SkillOutcome:
        return cls(succeeded=False, code=code, feedback=feedback, details=details, sim_time=sim_time)


def parse_action(obj: Any) -> Action:
    """Validate a dict (e.g. from JSON) as one of the skill actions."""
    try:
        return ACTION_ADAPTER.validate_python(obj)
    except ValidationError as exc:
        raise ProtocolError(_reason(exc)) from None
