"""`ScriptedLLMPolicy`: an LLMPolicy whose model answers from a list, for tests of the LLM plumbing.

The replies are the model's "judgement", in a model's own words (``"I am not sure."``,
``"Command: pick(apple)"``); prompt rendering, parsing, format feedback and the agent loop are
the real ones. Not `mhrc.testing.ScriptedPolicy`, which plays commands already parsed and
never renders a prompt: use that one to script a robot's actions, this one to script a model.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from mhrc.core.protocol import ActionResult

from .completion import DEFAULT_TEMPERATURE
from .llm_policy import LLMPolicy
from .scripted_client import ScriptedClient


class ScriptedLLMPolicy(LLMPolicy):
    """An LLMPolicy whose model answers each step with the next scripted reply (then `wait()`)."""

    def __init__(
        self,
        robot: str,
        replies: Iterable[str],
        *,
        prompts_dir: str | Path | None = None,
        temperature: float = DEFAULT_TEMPERATURE,
        feedback: bool = True,
        history: bool = True,
        prompt_cap_chars: int | None = None,
        teammates_absent: tuple[str, ...] = (),
        reach_labels: bool = False,
    ) -> None:
        super().__init__(
            robot,
            ScriptedClient(list(replies)),
            prompts_dir=prompts_dir,
            temperature=temperature,
            feedback=feedback,
            history=history,
            prompt_cap_chars=prompt_cap_chars,
            teammates_absent=teammates_absent,
            reach_labels=reach_labels,
        )
        self.results: list[ActionResult] = []

    @property
    def format_feedback(self) -> list[str]:
        """The feedback entries that report an unparseable reply."""
        return [e.text for e in self.memory.feedback if "could not be executed" in e.text]

    def record(self, result: ActionResult) -> None:
        super().record(result)
        self.results.append(result)
