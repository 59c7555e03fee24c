"""Every payload on the mhrc bus, as pydantic models.

The world and the agents share nothing but this package. Each message is JSON with a `v`
field (the protocol version); `decode()` turns raw bytes into a model or raises
`ProtocolError` with a reason, so a malformed message is rejected, never a crash.

The names are imported here in the order they are defined (`mhrc schema` lists the
payloads in that order): base, actions, observation, exchange, events, thoughts.
"""

# ruff: noqa: F401

from mhrc.core.protocol.base import PROTOCOL_VERSION
from mhrc.core.protocol.base import SUPPORTED_VERSIONS
from mhrc.core.protocol.base import ProtocolError
from mhrc.core.protocol.base import Message
from mhrc.core.protocol.actions import Navigate
from mhrc.core.protocol.actions import Move
from mhrc.core.protocol.actions import Open
from mhrc.core.protocol.actions import Pick
from mhrc.core.protocol.actions import Place
from mhrc.core.protocol.actions import Communicate
from mhrc.core.protocol.actions import Wait
from mhrc.core.protocol.actions import Action
from mhrc.core.protocol.actions import ACTION_ADAPTER
from mhrc.core.protocol.actions import SKILLS
from mhrc.core.protocol.actions import OutcomeCode
from mhrc.core.protocol.actions import SkillOutcome
from mhrc.core.protocol.observation import Pose2D
from mhrc.core.protocol.observation import FurnitureView
from mhrc.core.protocol.observation import ObjectView
from mhrc.core.protocol.observation import RobotMessage
from mhrc.core.protocol.observation import RobotStatus
from mhrc.core.protocol.observation import Observation
from mhrc.core.protocol.exchange import new_goal_id
from mhrc.core.protocol.exchange import ActionRequest
from mhrc.core.protocol.exchange import EPISODE_OVER
from mhrc.core.protocol.exchange import RejectCode
from mhrc.core.protocol.exchange import OUT_OF_STEP
from mhrc.core.protocol.exchange import Rejection
from mhrc.core.protocol.exchange import ActionAck
from mhrc.core.protocol.exchange import ActionResult
from mhrc.core.protocol.exchange import AttachRequest
from mhrc.core.protocol.exchange import AttachReply
from mhrc.core.protocol.exchange import Turn
from mhrc.core.protocol.events import Metrics
from mhrc.core.protocol.events import EpisodeStarted
from mhrc.core.protocol.events import MotionNoise
from mhrc.core.protocol.events import TickClosed
from mhrc.core.protocol.events import RobotAttached
from mhrc.core.protocol.events import RobotDetached
from mhrc.core.protocol.events import EpisodeDone
from mhrc.core.protocol.events import RobotPose
from mhrc.core.protocol.events import ObjectPose
from mhrc.core.protocol.events import Snapshot
from mhrc.core.protocol.events import ScenarioEvent
from mhrc.core.protocol.events import WorldEvent
from mhrc.core.protocol.events import WORLD_EVENT_ADAPTER
from mhrc.core.protocol.events import WorldState
from mhrc.core.protocol.thoughts import LLM_ERROR_PREFIX
from mhrc.core.protocol.thoughts import Thought
from mhrc.core.protocol.thoughts import Generating
from mhrc.core.protocol.base import encode
from mhrc.core.protocol.base import decode
from mhrc.core.protocol.events import decode_event
from mhrc.core.protocol.actions import parse_action

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
    "Generating",
    "encode",
    "decode",
    "decode_event",
    "parse_action",
]
