"""Every payload on the mhrc bus, as pydantic models.

The world and the agents share nothing but this module. Each message is JSON with a `v`
field (the protocol version); `decode()` turns raw bytes into a model or raises
`ProtocolError` with a reason, so a malformed message is rejected, never a crash.
"""

from __future__ import annotations

import uuid
from enum import Enum
from typing import Annotated, Any, Literal, NamedTuple, TypeVar, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

PROTOCOL_VERSION = 2  # 2: the world's `snapshot` event; every version-1 message is still valid
SUPPORTED_VERSIONS = (1, 2)


class ProtocolError(ValueError):
    """A payload that is not a valid message of the expected kind."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Message(_Model):
    """Base of every top-level bus payload: carries the protocol version."""

    v: Literal[1, 2] = 2  # PROTOCOL_VERSION; a version-1 message reads as it always did


# --------------------------------------------------------------------------- actions
# The paper's skills, with their arguments. `skill` discriminates the union.


class Navigate(_Model):
    skill: Literal["navigate"] = "navigate"
    target: str = Field(description="furniture name from the scene graph")
    stand_pose: int = Field(0, ge=0, description="index of the target's stand pose")

    def call(self) -> str:
        return f"navigate({self.target}, {self.stand_pose})"


class Move(_Model):
    skill: Literal["move"] = "move"
    dx: float = Field(description="metres along the world x axis")
    dy: float = Field(description="metres along the world y axis")

    def call(self) -> str:
        return f"move({self.dx:.2f}, {self.dy:.2f})"


class Open(_Model):
    skill: Literal["open"] = "open"
    target: str

    def call(self) -> str:
        return f"open({self.target})"


class Pick(_Model):
    skill: Literal["pick"] = "pick"
    obj: str

    def call(self) -> str:
        return f"pick({self.obj})"


class Place(_Model):
    skill: Literal["place"] = "place"
    obj: str
    location: str = Field(description="furniture or receptacle name, e.g. table_0 or tray")

    def call(self) -> str:
        return f"place({self.obj}, {self.location})"


class Communicate(_Model):
    skill: Literal["communicate"] = "communicate"
    content: str = Field(min_length=1, max_length=4000)
    to: str

    def call(self) -> str:
        return f"communicate({self.content!r}, {self.to})"


class Wait(_Model):
    skill: Literal["wait"] = "wait"

    def call(self) -> str:
        return "wait()"


Action = Annotated[
    Union[Navigate, Move, Open, Pick, Place, Communicate, Wait], Field(discriminator="skill")
]
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


class SkillOutcome(_Model):
    """What one skill did, as the simulator measured it."""

    succeeded: bool
    code: OutcomeCode
    feedback: str = Field(description="the paper-style sentence the robot's agent reads")
    details: dict[str, float | str] = Field(default_factory=dict)
    sim_time: float = Field(0.0, ge=0.0, description="simulated seconds the skill took")
    path: list[tuple[float, float]] | None = Field(
        None, description="navigate: the base's planned route in metres, start to stop (a few dozen points at most), for viewers"
    )

    @classmethod
    def ok(cls, feedback: str, *, sim_time: float = 0.0, **details: Any) -> SkillOutcome:
        return cls(succeeded=True, code=OutcomeCode.OK, feedback=feedback, details=details, sim_time=sim_time)

    @classmethod
    def fail(cls, code: OutcomeCode, feedback: str, *, sim_time: float = 0.0, **details: Any) -> SkillOutcome:
        return cls(succeeded=False, code=code, feedback=feedback, details=details, sim_time=sim_time)


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
    goals: dict[str, str] = Field(default_factory=dict, description="target -> where it must end: tray, panel, board (Bob only)")
    ordered: bool = Field(False, description="whether the targets must reach their goals in the listed order (a sandwich)")
    task_status: str | None = Field(None, description="progress text (Bob only)")
    teammates: dict[str, list[str]] = Field(default_factory=dict, description="robot -> its skills, for the teammates attached now (one whose agent left is not listed)")
    new_messages: list[RobotMessage] = Field(default_factory=list)


# --------------------------------------------------------------------------- action exchange


def new_goal_id() -> str:
    return uuid.uuid4().hex[:16]


class ActionRequest(Message):
    kind: Literal["action_request"] = "action_request"
    goal_id: str = Field(default_factory=new_goal_id, pattern=r"^[A-Za-z0-9_-]{1,64}$")
    robot: str
    agent_id: str
    tick: int = Field(ge=0, description="the tick of the observation the action was planned on")
    action: Action


EPISODE_OVER = "the episode is over"  # an ActionAck's reason for a request that came after the episode's end


class RejectCode(str, Enum):
    """Why the world rejected an action request, for programs (`ActionAck.reason` says it for people)."""

    MALFORMED = "malformed"  # the payload is not an ActionRequest
    WRONG_KEY = "wrong_key"  # a request for one robot sent on another robot's key
    NO_SUCH_ROBOT = "no_such_robot"  # the robot is not in this episode
    EPISODE_OVER = "episode_over"  # the episode has ended
    NOT_ATTACHED = "not_attached"  # nobody is attached to the robot: attach first
    OTHER_AGENT = "other_agent"  # the robot is attached to another agent
    STALE_TICK = "stale_tick"  # planned on another tick than the world's (or, async, the robot's)
    TICK_TAKEN = "tick_taken"  # the robot already submitted an action for this tick
    NOT_YOUR_TURN = "not_your_turn"  # sequential: another robot's turn
    BUSY = "busy"  # async: the robot's previous action has not finished


OUT_OF_STEP = frozenset({RejectCode.STALE_TICK, RejectCode.TICK_TAKEN, RejectCode.NOT_YOUR_TURN})  # attach again for the current tick


class Rejection(NamedTuple):
    """A rejection as the world builds its ack: the code and the sentence."""

    code: RejectCode
    reason: str


class ActionAck(Message):
    kind: Literal["action_ack"] = "action_ack"
    goal_id: str
    robot: str
    accepted: bool
    reason: str = ""
    code: RejectCode | None = Field(None, description="why the request was rejected, for programs (None when accepted); `reason` says it for people")


class ActionResult(Message):
    kind: Literal["action_result"] = "action_result"
    goal_id: str
    robot: str
    tick: int
    action: Action
    outcome: SkillOutcome
    observation: Observation
    done: bool = False
    started: float | None = Field(None, ge=0.0, description="simulated seconds on the world's clock when the action began (DESIGN.md, \"Time\")")
    ended: float | None = Field(None, ge=0.0, description="simulated seconds on the world's clock when it ended: `started` plus its duration")


# --------------------------------------------------------------------------- attach


class AttachRequest(Message):
    kind: Literal["attach_request"] = "attach_request"
    robot: str
    agent_id: str


class AttachReply(Message):
    kind: Literal["attach_reply"] = "attach_reply"
    robot: str
    accepted: bool
    reason: str = ""
    tick: int = 0
    horizon: int = 0
    observation: Observation | None = None
    wait_turn: bool = Field(
        False,
        description="the robot plans only when it is its turn (the sequential schedule): no observation now, "
        "it comes with a Turn on the robot's turn key",
    )


class Turn(Message):
    """The world's word that it is `robot`'s turn to plan, for a robot with no result pending
    (after attaching with wait_turn); `observation` is the world as it is now."""

    kind: Literal["turn"] = "turn"
    robot: str
    tick: int
    observation: Observation


# --------------------------------------------------------------------------- world events


class Metrics(_Model):
    """Per-episode metrics, as the paper defines them (see mhrc.core.metrics)."""

    success: bool
    partial_success: float = Field(ge=0.0, le=1.0)
    placed: int
    total: int
    temporal_steps: int
    action_steps: int = Field(description="actions of all robots, `wait` excluded")
    action_steps_per_robot: dict[str, int]
    failed_actions: dict[str, int] = Field(default_factory=dict, description="skill -> failures")
    messages: int = 0
    wall_time: float = 0.0
    sim_time: float = 0.0
    lower_bound: int | None = Field(None, description="a lower bound on TS for this episode (world/bound.py)")
    makespan: float = Field(0.0, ge=0.0, description="simulated seconds from the start to the end of the episode on the world's clock")


class EpisodeStarted(Message):
    kind: Literal["episode_started"] = "episode_started"
    run: str
    task: str
    scene: str
    seed: int
    n_objects: int
    robots: list[str]
    horizon: int
    scheduler: Literal["sequential", "lockstep", "async"] = "lockstep"
    time_scale: float | None = Field(None, ge=0.0, description="async: simulated seconds per wall second, 0 as fast as possible")
    step_seconds: float | None = Field(
        None, gt=0.0, description="async: the simulated seconds one step stands for: the horizon is horizon x step_seconds, TS is makespan / step_seconds rounded up"
    )
    lower_bound: int | None = None
    fidelity: str = Field("paper", description="`paper`, or `aids:` and the aids this episode ran with (mhrc.core.fidelity)")
    aids: list[str] = Field(default_factory=list)


class TickClosed(Message):
    kind: Literal["tick"] = "tick"
    tick: int = Field(description="the tick whose actions just executed")
    actions: dict[str, str] = Field(description="robot -> action call")
    outcomes: dict[str, bool] = Field(description="robot -> succeeded")
    placed: int
    total: int


class RobotAttached(Message):
    kind: Literal["robot_attached"] = "robot_attached"
    robot: str
    agent_id: str
    tick: int


class RobotDetached(Message):
    kind: Literal["robot_detached"] = "robot_detached"
    robot: str
    tick: int
    reason: str
    agent_id: str | None = None  # the agent let go (None from worlds before it was sent): it may attach again


class EpisodeDone(Message):
    kind: Literal["episode_done"] = "episode_done"
    run: str
    reason: Literal["success", "horizon", "no_agents", "stopped"]
    metrics: Metrics
    final_results: dict[str, str] = Field(
        default_factory=dict,
        description="robot -> goal id of the last result the world published to it: "
        "results travel on other keys, so an agent that sees this event first still waits for that result",
    )
    targets: list[str] = Field(
        default_factory=list, description="the task's target objects, in task order: said only once the episode is over (for reports)"
    )
    goals: dict[str, str] = Field(default_factory=dict, description="target -> the fixture it had to end on (for reports)")
    ordered: bool = Field(False, description="whether the targets had to reach their goals in order (a sandwich)")


class RobotPose(_Model):
    """Where a robot is: its base (a fixed arm: its arm's base) and what it holds."""

    x: float
    y: float
    yaw: float = 0.0
    holding: str | None = None


class ObjectPose(_Model):
    x: float
    y: float
    z: float
    on: str | None = None
    inside: bool = False
    held_by: str | None = None


class Snapshot(Message):
    """Ground truth after the world executed actions (and once at the start, with no goals):
    every robot's pose, every object's position, every container's state. For viewers and
    videos (mhrc show); agents never see it in their observations."""

    kind: Literal["snapshot"] = "snapshot"
    tick: int = Field(description="the tick the actions were executed at (async: the acting robot's own tick)")
    goals: list[str] = Field(default_factory=list, description="goal ids of the actions just executed, in order; their results say who did what")
    robots: dict[str, RobotPose]
    objects: dict[str, ObjectPose]
    open: dict[str, bool] = Field(default_factory=dict, description="openable furniture -> open")


WorldEvent = Annotated[
    Union[EpisodeStarted, TickClosed, RobotAttached, RobotDetached, EpisodeDone, Snapshot],
    Field(discriminator="kind"),
]
WORLD_EVENT_ADAPTER: TypeAdapter[WorldEvent] = TypeAdapter(WorldEvent)


class WorldState(Message):
    """Answer of the `world/state` queryable: a snapshot for late joiners and observers."""

    kind: Literal["world_state"] = "world_state"
    run: str
    task: str
    scene: str
    seed: int
    tick: int
    horizon: int
    started: bool
    done: bool
    attached: dict[str, str] = Field(description="robot -> agent id")
    robots: list[str]
    furniture: list[FurnitureView]
    objects: list[ObjectView]
    placed: int
    total: int


# --------------------------------------------------------------------------- thoughts


LLM_ERROR_PREFIX = "llm error: "  # a Thought.parse_error that starts so: the model was unreachable, not misunderstood


class Thought(Message):
    """What an agent considered before acting: for observers and the recorder."""

    kind: Literal["thought"] = "thought"
    robot: str
    tick: int
    policy: str
    prompt: str | None = None
    reply: str | None = None
    action: str | None = None
    parse_error: str | None = None
    prompt_tokens: int = 0
    completion_tokens: int = 0
    latency: float = 0.0
    reasoning: str | None = Field(None, description="a reasoning model's thoughts (reasoning field or <think> block), apart from the reply")
    reasoning_tokens: int = 0
    finish_reason: str | None = Field(None, description="the server's: stop, length (cut at max_tokens), ...")
    schema_hash: str | None = Field(None, description="with --structured: hash of the JSON Schema the reply had to follow")
    ttft: float | None = Field(None, description="seconds to the reply's first token (prompt processing, mostly), where it was streamed")


class Generating(Message):
    """A robot's model call that is taking a while, as the server has answered it so far: live
    status for the console (`mhrc up`), sent every few seconds of a long call; not recorded."""

    kind: Literal["generating"] = "generating"
    robot: str
    tick: int
    elapsed: float = Field(description="seconds since the call began, retries included")
    tokens: int = Field(0, description="tokens streamed so far in this attempt (0: the server is still reading the prompt)")
    attempt: int = Field(1, description="HTTP attempt of this call (retries included)")


# --------------------------------------------------------------------------- codec

M = TypeVar("M", bound=BaseModel)


def encode(model: BaseModel) -> bytes:
    return model.model_dump_json().encode()


def decode(data: bytes | str, model: type[M]) -> M:
    """Parse `data` as `model`, raising ProtocolError with a readable reason."""
    try:
        return model.model_validate_json(data)
    except ValidationError as exc:
        raise ProtocolError(_reason(exc)) from None


def decode_event(data: bytes | str) -> WorldEvent:
    try:
        return WORLD_EVENT_ADAPTER.validate_json(data)
    except ValidationError as exc:
        raise ProtocolError(_reason(exc)) from None


def parse_action(obj: Any) -> Action:
    """Validate a dict (e.g. from JSON) as one of the skill actions."""
    try:
        return ACTION_ADAPTER.validate_python(obj)
    except ValidationError as exc:
        raise ProtocolError(_reason(exc)) from None


def _reason(exc: ValidationError) -> str:
    parts = []
    for err in exc.errors()[:5]:
        loc = ".".join(str(p) for p in err["loc"]) or "payload"
        parts.append(f"{loc}: {err['msg']}")
    return "; ".join(parts)
