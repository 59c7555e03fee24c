"""The paper's skills as actions (`skill` discriminates the union), each with its call form, and
their outcomes.

A skill's call form (`ARGS` on its model: the arguments in call order, each with the model's
field, what kind of thing it names, and the words a model writes for it) is declared here once.
Everything that reads or offers a call derives from it: the reply parser and the prompts'
signatures (mhrc.agents.parse), the structured-output schema (mhrc.agents.structured), the play
page's forms (mhrc.play.forms), the hallucination check (mhrc.analysis.diagnostics). `declare`
registers a model's call form under its skill name (`CALLS`); the shipped skills are registered
below, a test may register one of its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum, StrEnum
from typing import Annotated, Any, ClassVar, Literal, TypeVar, Union, cast

from pydantic import Field, TypeAdapter, ValidationError

from mhrc.core.protocol.base import MAX_INT, MAX_MOVE, MAX_NAME, ProtocolError, _Model, _reason

# --------------------------------------------------------------------------- call forms


class ArgKind(StrEnum):
    """What a call's argument is, and so which values a robot has for it (each reader of the form
    says which, from the robot's own observation)."""

    STAND = "stand"  # furniture with a stand pose: where a robot can go
    STAND_POSE = "stand_pose"  # the index of one of the previous argument's stand poses
    OPENABLE = "openable"  # furniture that opens
    PICKABLE = "pickable"  # an object lying somewhere, not held
    OBJECT = "object"  # an object to put down (the one held)
    PLACE = "place"  # furniture or a receptacle to put an object on
    OFFSET = "offset"  # metres along a world axis
    TEXT = "text"  # free text: a message (it takes the commas of a written call)
    TEAMMATE = "teammate"  # another robot of the team

    @property
    def names_a_thing(self) -> bool:
        """The argument names furniture or an object (a name the robot may have made up)."""
        return self in _THINGS


_THINGS = frozenset({ArgKind.STAND, ArgKind.OPENABLE, ArgKind.PICKABLE, ArgKind.OBJECT, ArgKind.PLACE})


@dataclass(frozen=True)
class Arg:
    """One argument of a skill's call: the model's `field`, its `kind`, the `word` a structured
    command names it by (the field's name if None) and the word the prompts' signature shows for
    it (`word` if None)."""

    field: str
    kind: ArgKind
    word: str | None = None
    shown: str | None = None

    @property
    def name(self) -> str:
        """The argument's name in a structured command."""
        return self.word or self.field

    @property
    def spoken(self) -> str:
        """The argument's name in the prompts' signature of the call."""
        return self.shown or self.name


class ActionModel(_Model):
    """Base of every skill's action: its call form (`ARGS`) and its call in the paper's syntax."""

    ARGS: ClassVar[tuple[Arg, ...]] = ()
    skill: str

    def call(self) -> str:
        """The action in the paper's syntax, e.g. ``navigate(table_1, 0)``."""
        return f"{self.skill}({', '.join(_written(a, getattr(self, a.field)) for a in self.ARGS)})"


def _written(arg: Arg, value: object) -> str:
    if arg.kind is ArgKind.OFFSET:
        return f"{value:.2f}"
    if arg.kind is ArgKind.TEXT:
        return repr(value)
    return str(value)


A = TypeVar("A", bound=ActionModel)
CALLS: dict[str, type[ActionModel]] = {}  # skill -> its action model, in the protocol's order


def declare(model: type[A]) -> type[A]:
    """Register `model`'s call form under its skill name (its `skill` field's default)."""
    skill = model.model_fields["skill"].default
    missing = [a.field for a in model.ARGS if a.field not in model.model_fields]
    if not isinstance(skill, str) or missing:
        raise TypeError(f"{model.__name__}: no skill name, or ARGS naming no field ({', '.join(missing)})")
    CALLS[skill] = model
    return model


def signature(skill: str) -> str:
    """The call form the prompts show, e.g. ``navigate(furniture, stand_pose_id)``."""
    return f"{skill}({', '.join(a.spoken for a in CALLS[skill].ARGS)})"


def build(skill: str, values: Mapping[str, object]) -> Action:
    """The action `skill` with its model's fields `values`, validated by its model (pydantic's
    ValidationError if they do not fit)."""
    return cast(Action, CALLS[skill].model_validate({"skill": skill, **values}))


# --------------------------------------------------------------------------- actions
# The paper's skills, with their arguments. `skill` discriminates the union.


@declare
class Navigate(ActionModel):
    ARGS = (
        Arg("target", ArgKind.STAND, word="furniture"),
        Arg("stand_pose", ArgKind.STAND_POSE, shown="stand_pose_id"),
    )
    skill: Literal["navigate"] = "navigate"
    target: str = Field(max_length=MAX_NAME, description="furniture name from the scene graph")
    stand_pose: int = Field(0, ge=0, le=MAX_INT, description="index of the target's stand pose")


@declare
class Move(ActionModel):
    ARGS = (Arg("dx", ArgKind.OFFSET), Arg("dy", ArgKind.OFFSET))
    skill: Literal["move"] = "move"
    dx: float = Field(ge=-MAX_MOVE, le=MAX_MOVE, allow_inf_nan=False, description="metres along the world x axis")
    dy: float = Field(ge=-MAX_MOVE, le=MAX_MOVE, allow_inf_nan=False, description="metres along the world y axis")


@declare
class Open(ActionModel):
    ARGS = (Arg("target", ArgKind.OPENABLE, word="furniture"),)
    skill: Literal["open"] = "open"
    target: str = Field(max_length=MAX_NAME)


@declare
class Pick(ActionModel):
    ARGS = (Arg("obj", ArgKind.PICKABLE, word="object"),)
    skill: Literal["pick"] = "pick"
    obj: str = Field(max_length=MAX_NAME)


@declare
class Place(ActionModel):
    ARGS = (Arg("obj", ArgKind.OBJECT, word="object"), Arg("location", ArgKind.PLACE))
    skill: Literal["place"] = "place"
    obj: str = Field(max_length=MAX_NAME)
    location: str = Field(max_length=MAX_NAME, description="furniture or receptacle name, e.g. table_0 or tray")


@declare
class Communicate(ActionModel):
    ARGS = (Arg("content", ArgKind.TEXT), Arg("to", ArgKind.TEAMMATE, shown="robot"))
    skill: Literal["communicate"] = "communicate"
    content: str = Field(min_length=1, max_length=4000)
    to: str = Field(max_length=MAX_NAME)


@declare
class Wait(ActionModel):
    skill: Literal["wait"] = "wait"


Action = Annotated[Union[Navigate, Move, Open, Pick, Place, Communicate, Wait], Field(discriminator="skill")]
ACTION_ADAPTER: TypeAdapter[Action] = TypeAdapter(Action)
SKILLS = tuple(CALLS)  # the protocol's skills, in its order ("navigate", ..., "wait")


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
