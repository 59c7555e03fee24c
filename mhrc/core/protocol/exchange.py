"""The action exchange (request, ack with its reject code, result) and attaching a robot to the world."""

from __future__ import annotations

import uuid
from enum import Enum
from typing import Literal, NamedTuple

from pydantic import Field

from mhrc.core.protocol.actions import Action, SkillOutcome
from mhrc.core.protocol.base import MAX_AGENT_ID, MAX_INT, MAX_NAME, Message
from mhrc.core.protocol.observation import Observation

# --------------------------------------------------------------------------- action exchange


GOAL_ID = rf"^[A-Za-z0-9_-]{{1,{MAX_NAME}}}$"  # what a goal id may be


def new_goal_id() -> str:
    return uuid.uuid4().hex[:16]


class ActionRequest(Message):
    kind: Literal["action_request"] = "action_request"
    goal_id: str = Field(default_factory=new_goal_id, pattern=GOAL_ID)
    robot: str = Field(max_length=MAX_NAME)
    agent_id: str = Field(max_length=MAX_AGENT_ID)
    tick: int = Field(ge=0, le=MAX_INT, description="the tick of the observation the action was planned on")
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
    DUPLICATE_GOAL = (
        "duplicate_goal"  # the robot sent this goal id before in this episode: each goal executes at most once
    )


OUT_OF_STEP = frozenset(
    {RejectCode.STALE_TICK, RejectCode.TICK_TAKEN, RejectCode.NOT_YOUR_TURN}
)  # attach again for the current tick


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
    code: RejectCode | None = Field(
        None, description="why the request was rejected, for programs (None when accepted); `reason` says it for people"
    )


class ActionResult(Message):
    kind: Literal["action_result"] = "action_result"
    goal_id: str
    robot: str
    tick: int
    action: Action
    outcome: SkillOutcome
    observation: Observation
    done: bool = False
    started: float | None = Field(
        None,
        ge=0.0,
        description='simulated seconds on the world\'s clock when the action began (docs/architecture.md, "Time")',
    )
    ended: float | None = Field(
        None, ge=0.0, description="simulated seconds on the world's clock when it ended: `started` plus its duration"
    )


# --------------------------------------------------------------------------- attach


class AttachRequest(Message):
    kind: Literal["attach_request"] = "attach_request"
    robot: str = Field(max_length=MAX_NAME)
    agent_id: str = Field(max_length=MAX_AGENT_ID)


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
