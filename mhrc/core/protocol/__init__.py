"""Every payload on the mhrc bus, as pydantic models.

The world and the agents share nothing but this package. Each message is JSON with a `v`
field (the protocol version); `decode()` turns raw bytes into a model or raises
`ProtocolError` with a reason, so a malformed message is rejected, never a crash.

The names are imported here in the order they are defined (`mhrc schema` lists the
payloads in that order): base, actions, observation, exchange, events, thoughts.
"""

# ruff: noqa: F401

from mhrc.core.protocol.actions import (
    ACTION_ADAPTER,
    SKILLS,
    Action,
    Communicate,
    Move,
    Navigate,
    Open,
    OutcomeCode,
    Pick,
    Place,
    SkillOutcome,
    Wait,
    parse_action,
)
from mhrc.core.protocol.base import PROTOCOL_VERSION, SUPPORTED_VERSIONS, Message, ProtocolError, decode, encode
from mhrc.core.protocol.events import (
    WORLD_EVENT_ADAPTER,
    EpisodeDone,
    EpisodeStarted,
    Metrics,
    MotionNoise,
    ObjectPose,
    RobotAttached,
    RobotDetached,
    RobotPose,
    ScenarioEvent,
    Snapshot,
    TeamRecord,
    TickClosed,
    WorldEvent,
    WorldState,
    decode_event,
)
from mhrc.core.protocol.exchange import (
    EPISODE_OVER,
    OUT_OF_STEP,
    ActionAck,
    ActionRequest,
    ActionResult,
    AttachReply,
    AttachRequest,
    RejectCode,
    Rejection,
    Turn,
    new_goal_id,
)
from mhrc.core.protocol.observation import FurnitureView, ObjectView, Observation, Pose2D, RobotMessage, RobotStatus
from mhrc.core.protocol.thoughts import LLM_ERROR_PREFIX, Coordination, Generating, Thought

__all__ = [
    "PROTOCOL_VERSION",
    "SUPPORTED_VERSIONS",
    "ProtocolError",
    "Message",
    "Navigate",
    "Move",
    "Open",
    "Pick",
    "Place",
    "Communicate",
    "Wait",
    "Action",
    "ACTION_ADAPTER",
    "SKILLS",
    "OutcomeCode",
    "SkillOutcome",
    "Pose2D",
    "FurnitureView",
    "ObjectView",
    "RobotMessage",
    "RobotStatus",
    "Observation",
    "new_goal_id",
    "ActionRequest",
    "EPISODE_OVER",
    "RejectCode",
    "OUT_OF_STEP",
    "Rejection",
    "ActionAck",
    "ActionResult",
    "AttachRequest",
    "AttachReply",
    "Turn",
    "Metrics",
    "EpisodeStarted",
    "MotionNoise",
    "TeamRecord",
    "TickClosed",
    "RobotAttached",
    "RobotDetached",
    "EpisodeDone",
    "RobotPose",
    "ObjectPose",
    "Snapshot",
    "ScenarioEvent",
    "WorldEvent",
    "WORLD_EVENT_ADAPTER",
    "WorldState",
    "LLM_ERROR_PREFIX",
    "Thought",
    "Coordination",
    "Generating",
    "encode",
    "decode",
    "decode_event",
    "parse_action",
]
