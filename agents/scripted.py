"""A scripted stand-in for an LLM: an LLMPolicy whose model answers from a list.

For tests and demos of the plumbing: the replies are the model's "judgement"; prompt
rendering, parsing, format feedback and the agent loop are the real ones.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from mhrc.core.protocol import ActionResult

from .llm import DEFAULT_TEMPERATURE, ScriptedClient
from .llm_policy import LLMPolicy


class ScriptedPolicy(LLMPolicy):
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
