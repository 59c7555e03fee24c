"""The policy interface every robot agent drives: observation in, one action out."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from mhrc.core.protocol import Action, ActionResult, Observation
from mhrc.core.protocol.thoughts import Coordination, ReplyFailure

__all__ = ["Decision", "Policy"]


@dataclass(frozen=True)
class Decision:
    """One chosen action and what led to it (published as the robot's thought)."""

    action: Action
    prompt: str | None = None
    reply: str | None = None
    parse_error: str | None = None
    prompt_tokens: int = 0
    completion_tokens: int = 0
    latency: float = 0.0
    reasoning: str | None = None
    reasoning_tokens: int = 0
    finish_reason: str | None = None
    schema_hash: str | None = None
    ttft: float | None = None  # seconds to the reply's first token, where streamed
    failure: ReplyFailure | None = None  # why no action came of the step (parse_error says it for people)
    coordination: Coordination | None = None  # what a protocol other than the paper's decided for this robot


class Policy(Protocol):
    """Chooses a robot's next action from that robot's own observation only.

    A policy may also have `world_event(event)`: its agent calls it with every world event
    (`mhrc.core.protocol.WorldEvent`: ticks, robots attached and detached, the episode's end), as
    every participant hears them; a central planner hears a teammate detach there. It may have
    `aclose()` too: awaited once its episode is over, by whoever built it (a protocol's policies
    close their model clients there; mhrc.run.coordinated.close_seats)."""

    name: str

    async def decide(self, obs: Observation) -> Decision: ...

    def record(self, result: ActionResult) -> None:
        """Called with the result of the action this policy chose last."""
        ...
