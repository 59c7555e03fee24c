"""Replaying a recorded episode without the model: each robot's recorded replies, in order.

The recorder keeps every thought (prompt, reply, usage) in the trace. A `ReplayClient`
answers the robot's n-th call with its n-th recorded reply, after checking that the prompt it
is given is the one recorded: a replay that drifts stops with ReplayMismatch instead of
silently diverging.
"""

from __future__ import annotations

from pathlib import Path

from mhrc.trace import read_trace

from .llm import Completion, LLMError, Messages


class ReplayMismatch(RuntimeError):
    """The replayed episode asked something the recorded one did not."""


class ReplayClient:
    def __init__(self, trace: str | Path, robot: str) -> None:
        self.model = "replay"
        self.robot = robot
        suffix = f"/agent/{robot}/thought"
        self._thoughts = [line["msg"] for line in read_trace(trace) if line["key"].endswith(suffix)]
        if not self._thoughts or self._thoughts[0].get("prompt") is None:
            raise ReplayMismatch(f"{trace} holds no LLM prompts for {robot}: only episodes run with --llm can be replayed")
        self.calls = 0

    async def complete(self, messages: Messages, *, temperature: float = 0.5) -> Completion:
        if self.calls >= len(self._thoughts):
            raise ReplayMismatch(f"{self.robot} asked for call {self.calls + 1}; the trace holds {len(self._thoughts)}")
        t = self._thoughts[self.calls]
        self.calls += 1
        prompt = "\n\n".join(m["content"] for m in messages)
        if prompt != t["prompt"]:
            raise ReplayMismatch(f"{self.robot}'s prompt at call {self.calls} (tick {t['tick']}) differs from the recorded one")
        if t.get("reply") is None:  # the model failed in the recorded run: fail the same way
            raise LLMError(str(t.get("parse_error") or "recorded model failure").removeprefix("llm error: "))
        return Completion(t["reply"], t.get("prompt_tokens", 0), t.get("completion_tokens", 0), t.get("latency", 0.0))
