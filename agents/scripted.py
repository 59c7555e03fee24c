"""`ScriptedLLMPolicy`: an LLMPolicy whose model answers from a list, for tests of the LLM plumbing.

The replies are the model's "judgement", in a model's own words (``"I am not sure."``,
``"Command: pick(apple)"``); prompt rendering, parsing, format feedback and the agent loop are
the real ones. Not `mhrc.testing.ScriptedPolicy`, which plays commands already parsed and
never renders a prompt: use that one to script a robot's actions, this one to script a model.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from mhrc.core.protocol import ActionResult

from .llm.scripted_client import ScriptedClient
from .llm_policy import UNREADABLE_TAG, LLMPolicy


class ScriptedLLMPolicy(LLMPolicy):
    """An LLMPolicy whose model answers each step with the next scripted reply (then `wait()`)."""

    def __init__(self, robot: str, replies: Iterable[str], **options: Any) -> None:
        """`options`: LLMPolicy's keyword options (prompts_dir, feedback, history, ...)."""
        super().__init__(robot, ScriptedClient(list(replies)), **options)
        self.results: list[ActionResult] = []

    @property
    def format_feedback(self) -> list[str]:
        """The feedback entries that report an unparseable reply."""
        return [e.text for e in self.memory.feedback if e.tag == UNREADABLE_TAG]

    def record(self, result: ActionResult) -> None:
        super().record(result)
        self.results.append(result)
