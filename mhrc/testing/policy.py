"""`ScriptedPolicy`: a robot that plays a fixed list of commands in the paper's syntax."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from mhrc.agents.parse import parse_command
from mhrc.agents.policy import Decision
from mhrc.core.protocol import Action, ActionResult, Observation, Wait

__all__ = ["ScriptedPolicy"]


class ScriptedPolicy:
    """A `Policy` playing a fixed list of commands in the paper's syntax, in order.

    ``ScriptedPolicy(["navigate(table_0, 0)", "pick(apple)"])``: each command is parsed at once
    with the LLM robots' own parser (`mhrc.agents.parse.parse_command`; a ``Command:`` label is
    optional), so a typo fails here, not mid-episode. When the list is done the robot waits;
    with ``until``, it also waits while ``until(observation)`` is false, and plays its next
    command at the first observation that makes it true. Every `ActionResult` is kept in
    `results`, every observation planned on in `observations`.
    """

    def __init__(
        self, commands: Iterable[str], *, until: Callable[[Observation], bool] | None = None, name: str = "script"
    ) -> None:
        self.name = name
        self.commands = list(commands)
        self.actions: list[Action] = []
        for i, command in enumerate(self.commands):
            try:
                self.actions.append(parse_command(f"Command: {command}"))
            except ValueError as exc:
                raise ValueError(f"scripted command {i} ({command!r}): {exc}") from None
        self.until = until
        self.results: list[ActionResult] = []
        self.observations: list[Observation] = []

    @property
    def remaining(self) -> int:
        """Commands not played yet."""
        return len(self.actions)

    async def decide(self, obs: Observation) -> Decision:
        self.observations.append(obs)
        if not self.actions or (self.until is not None and not self.until(obs)):
            return Decision(action=Wait())
        return Decision(action=self.actions.pop(0))

    def record(self, result: ActionResult) -> None:
        self.results.append(result)
