"""Replaying a recorded episode without the model: each robot's recorded replies, in order.

The recorder keeps every thought (prompt, reply, token usage) in the trace, on keys ending
`/agent/<robot>/thought`. A `ReplayClient` answers the robot's n-th call with its n-th
recorded reply, after checking that the prompt it is given (the messages' contents joined as
`prompt_text` joins them, which is what a Thought records) equals the recorded one. Equal
prompts at every call prove the episode is reproduced exactly; the first difference stops the
replay with ReplayMismatch, naming the call, tick and first differing line.

Before the first call, `check_templates` compares the first recorded prompt with the templates
the replaying policy renders from: a trace recorded with other prompts (an older mhrc's prompt
set, or other --prompts) is refused up front, saying so, instead of running until its first step.
"""

from __future__ import annotations

import re
from collections import defaultdict
from collections.abc import Mapping
from pathlib import Path
from string import Template

from mhrc.core.jsontypes import JsonObject
from mhrc.core.protocol import LLM_ERROR_PREFIX, Thought
from mhrc.core.protocol.thoughts import ReplyFailure
from mhrc.core.records import TraceLine, read_records

from .llm.completion import DEFAULT_TEMPERATURE, Completion, LLMError, Messages, prompt_text

THOUGHT_SUFFIX = "/agent/{robot}/thought"


class ReplayMismatch(RuntimeError):
    """The replayed episode asked something the recorded one did not."""


def _words(text: str) -> str:
    return " ".join(text.split())


def literal_parts(template: Template) -> list[str]:
    """The template's own text between its placeholders, whitespace collapsed ("$$" as "$")."""
    parts, at = [], 0
    for m in template.pattern.finditer(template.template):
        parts.append(template.template[at : m.start()] + ("$" if m.group("escaped") is not None else ""))
        at = m.end()
    parts.append(template.template[at:])
    return [w for p in parts if (w := _words(p))]


def _first_difference(got: str, want: str) -> str:
    a, b = got.splitlines(), want.splitlines()
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return f"line {i + 1}: recorded {y[:160]!r}, now {x[:160]!r}"
    return f"the recorded prompt has {len(b)} lines, this one {len(a)}"


class ReplayClient:
    """One robot's recorded replies, handed out in order against matching prompts."""

    def __init__(self, trace: str | Path, robot: str, *, thoughts: list[TraceLine] | None = None) -> None:
        self.model = "replay"
        self.robot = robot
        self.trace = Path(trace)
        if thoughts is None:
            suffix = THOUGHT_SUFFIX.format(robot=robot)
            thoughts = [
                line for line in read_records(trace) if line.key.endswith(suffix) and isinstance(line.msg, Thought)
            ]
        self._lines = thoughts
        self._thoughts = [line.msg for line in thoughts if isinstance(line.msg, Thought)]
        if not self._thoughts or self._thoughts[0].prompt is None:
            raise ReplayMismatch(
                f"{trace} holds no LLM prompts for {robot}: only episodes run with an LLM policy can be replayed"
            )
        self.calls = 0

    def check_templates(self, templates: Mapping[str, Template]) -> None:
        """ReplayMismatch unless the first recorded prompt holds the text of every template, in
        order: a prompt rendered from other templates cannot be replayed step by step."""
        recorded = _words(self._thoughts[0].prompt or "")
        at = 0
        for name, template in templates.items():
            for part in literal_parts(template):
                found = recorded.find(part, at)
                if found < 0:
                    shown = re.sub(r"\s+", " ", part)[:120]
                    raise ReplayMismatch(
                        f"{self.trace} was recorded with other prompts than the ones {self.robot} is given now: its first "
                        f"prompt (tick {self._thoughts[0].tick}) lacks {shown!r} from {name}, so its replies no longer "
                        "match (an older mhrc's prompt set, or other --prompts); record the episode again to replay it"
                    )
                at = found + len(part)

    @property
    def remaining(self) -> int:
        """Recorded calls not replayed yet (0 once the whole episode was reproduced)."""
        return len(self._thoughts) - self.calls

    async def complete(
        self, messages: Messages, *, temperature: float = DEFAULT_TEMPERATURE, schema: JsonObject | None = None
    ) -> Completion:
        if self.calls >= len(self._thoughts):
            raise ReplayMismatch(
                f"{self.robot} asked for call {self.calls + 1}; {self.trace} holds {len(self._thoughts)}"
            )
        t = self._thoughts[self.calls]
        self.calls += 1
        prompt = prompt_text(messages)
        if prompt != t.prompt:
            raise ReplayMismatch(
                f"{self.robot}'s prompt at call {self.calls} (tick {t.tick}) differs from the one recorded "
                f"in {self.trace}: {_first_difference(prompt, t.prompt or '')}"
            )
        if t.reply is None:  # the model stayed down in the recorded run: fail the same way
            reason = t.parse_error or "recorded model failure"
            raise LLMError(
                reason.removeprefix(LLM_ERROR_PREFIX) if t.failure is ReplyFailure.MODEL_UNREACHABLE else reason
            )
        return Completion(
            t.reply,
            t.prompt_tokens,
            t.completion_tokens,
            t.latency,
            finish_reason=t.finish_reason,
            reasoning=t.reasoning,
            reasoning_tokens=t.reasoning_tokens,
        )


def replay_clients(trace: str | Path) -> dict[str, ReplayClient]:
    """A ReplayClient for every robot whose LLM thoughts the trace holds."""
    by_robot: dict[str, list[TraceLine]] = defaultdict(list)
    for line in read_records(trace):
        parts = line.key.rsplit("/", 3)
        if len(parts) == 4 and parts[1] == "agent" and parts[3] == "thought" and isinstance(line.msg, Thought):
            by_robot[parts[2]].append(line)
    clients = {
        r: ReplayClient(trace, r, thoughts=ts)
        for r, ts in by_robot.items()
        if isinstance(ts[0].msg, Thought) and ts[0].msg.prompt is not None
    }
    if not clients:
        raise ReplayMismatch(f"{trace} holds no LLM thoughts: only episodes run with an LLM policy can be replayed")
    return clients
