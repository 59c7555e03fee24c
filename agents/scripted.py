"""A scripted stand-in for an LLM: replies from a list, parsed like a real model's.

For tests and demos of the plumbing: the replies are the model's "judgement"; prompt
rendering, parsing, format feedback and the agent loop are the real ones.
"""

from __future__ import annotations

from collections.abc import Iterable

from mhrc.protocol import ActionResult

from .llm import ScriptedClient
from .llm_policy import LLMPolicy


class ScriptedPolicy(LLMPolicy):
    """An LLMPolicy whose model answers each step with the next scripted reply (then `wait()`)."""

    def __init__(self, robot: str, replies: Iterable[str], **options: object) -> None:
        super().__init__(robot, ScriptedClient(list(replies)), **options)  # type: ignore[arg-type]
        self.name = "scripted"
        self.results: list[ActionResult] = []

    @property
    def format_feedback(self) -> list[str]:
        return [f for f in self.memory.feedback if "could not be executed" in f]

    def record(self, result: ActionResult) -> None:
        super().record(result)
        self.results.append(result)
