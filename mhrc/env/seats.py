"""A robot's seat in the environment: what its LLM agent would do around the model call, with
the caller in the model's place.

The prompt is `LLMPolicy`'s own (`prepare`: the robot's memory of feedback, messages and actions,
rendered by its kind's templates), so the text observation is the user prompt an LLM agent on
the bus would send; the caller's command is read by the same parser (`interpret`: an unreadable
one makes the robot wait, and its next prompt's feedback says so); the result goes back into the
memory (`record`). With an expert, the built-in heuristic (agents/heuristic.py) sees the same
observation and says what it would do.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from mhrc.agents.heuristic import Heuristic, heuristic_policy
from mhrc.agents.llm.completion import Completion, Messages
from mhrc.agents.llm_policy import LLMPolicy
from mhrc.core.protocol import Action, ActionResult, Observation
from mhrc.run.config import EpisodeConfig

from .spaces import EMPTY, is_command, printable
from .world import run_now


class CallerChooses:
    """The `LLMClient` of a seat: the environment's caller answers instead of a model, so nothing
    ever asks this one."""

    model = "env"

    async def complete(self, messages: Messages, **_: object) -> Completion:
        raise RuntimeError("in the environment the caller gives each command (step), not a model")


@dataclass
class Seat:
    """One robot: its prompts and memory, its latest observation, and its expert."""

    robot: str
    prompts: LLMPolicy
    expert: Heuristic | None
    observation: Observation | None = None
    shown: dict[str, str] = field(default_factory=lambda: dict(EMPTY))
    expert_action: str | None = None
    system: str = ""

    @classmethod
    def make(cls, robot: str, cfg: EpisodeConfig, *, expert: bool) -> Seat:
        prompts = LLMPolicy(robot, CallerChooses(), **cfg.policy_options())
        return cls(robot, prompts, heuristic_policy(robot) if expert else None)

    def see(self, obs: Observation) -> None:
        """The world gave this robot `obs`: its prompt is rendered (the memory takes in what came
        with it) and the expert decides on it."""
        self.observation = obs
        system, user = self.prompts.prepare(obs)
        self.system = printable(system["content"])
        self.shown = {"text": printable(user["content"]), "structured": printable(obs.model_dump_json())}
        if self.expert is not None:
            self.expert_action = run_now(self.expert.decide(obs)).action.call()

    def command(self, command: object) -> tuple[Action, str | None]:
        """The action `command` gives, or `wait` and why it could not be read (the robot's feedback)."""
        tick = self.observation.tick if self.observation is not None else 0
        if not is_command(command):
            command = ""  # not a string, longer than a command, or characters no command has: as unreadable as nothing
        assert isinstance(command, str)
        return self.prompts.interpret(command, tick)

    def record(self, result: ActionResult) -> None:
        """The result of this robot's action, into its memory (and its expert's)."""
        self.prompts.record(result)
        if self.expert is not None:
            self.expert.record(result)
