"""A scripted stand-in for an LLM: replies from a list, parsed like a real model's.

For tests and demos of the plumbing: the replies are the model's "judgement"; parsing,
feedback on malformed replies and the agent loop are the real ones.
"""

from __future__ import annotations

from collections.abc import Iterable

from mhrc.protocol import ActionResult, Observation, Wait

from .parse import ReplyFormatError, parse_command
from .policy import Decision


class ScriptedPolicy:
    """Answers each step with the next scripted reply; `wait()` once the script runs out.

    A reply that does not parse becomes a `wait` whose thought carries the format error, and
    the error is kept as feedback for the next step (`format_feedback`)."""

    name = "scripted"

    def __init__(self, replies: Iterable[str]) -> None:
        self._replies = list(replies)
        self.format_feedback: list[str] = []
        self.results: list[ActionResult] = []

    async def decide(self, obs: Observation) -> Decision:
        if not self._replies:
            return Decision(action=Wait(), reply=None)
        reply = self._replies.pop(0)
        try:
            return Decision(action=parse_command(reply), reply=reply)
        except ReplyFormatError as exc:
            self.format_feedback.append(f"Your last reply could not be executed: {exc}.")
            return Decision(action=Wait(), reply=reply, parse_error=str(exc))

    def record(self, result: ActionResult) -> None:
        self.results.append(result)
