"""The LLM form of `centralized`: one model call per decision round, whose reply names one
command per robot (COHERENT's proposal-execution-feedback loop, SMART-LLM's central assignment).

The prompt (prompts/centralized_system.txt and centralized_user.txt) lists every robot's
observation as the paper's prompts render it (scene graph, status, skills), its last feedback,
and the messages it received. The reply has one line per robot, ``alice: navigate(table_1)``.
A robot whose line is missing or cannot be read (an unknown skill, bad arguments, a robot that is
not one of them) waits this round, and the problem is its feedback in the next prompt; the other
robots' commands still run.

Rounds follow the world's schedule as the heuristic planner's do (centralized.py): lockstep, one
call per tick once every robot brought its observation; sequential, one call at the first turn of
a tick, its commands kept for the later turns of that tick; async, one call per request.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from string import Template

from mhrc.core.protocol import Action, ActionResult, Coordination, Observation, Wait
from mhrc.core.protocol.thoughts import ReplyFailure

from .. import structured as json_mode
from ..llm.completion import Completion, LLMClient, LLMError, LLMFatalError, close_client, prompt_text
from ..observation import robot_status, scene_graph, task_text
from ..parse import ReplyFormatError, parse_command
from ..policy import Decision, Policy
from .base import Seating
from .centralized import PLANNER, CentralPlanner, Seat

__all__ = ["LLMCentralPlanner", "build_centralized", "parse_round", "round_prompt"]

ROUND_INSTRUCTIONS = (
    'Answer with one JSON object and nothing else: {"analysis": "...", "commands": {"<robot>": {"skill": "...", ...}}}, '
    "one command for every robot, each with that robot's own skills and names from its own scene graph (for example "
    '{"skill": "navigate", "furniture": "table_1", "stand_pose": 0} or {"skill": "wait"}). '
    "This JSON object replaces the lines naming each robot's command."
)
LINE = re.compile(r"^\s*[-*]?\s*([A-Za-z][A-Za-z0-9_]*)\s*:\s*(.+?)\s*$")


def _template(name: str) -> str:
    return resources.files("mhrc.prompts").joinpath(name).read_text(encoding="utf-8")


def round_analysis_bound(max_tokens: object, robots: int) -> int:
    """Characters a structured round's analysis may take so that every robot's command still fits
    in a reply of `max_tokens` (json_mode.analysis_bound, with a command's room for each robot)."""
    if not isinstance(max_tokens, int):
        return json_mode.analysis_bound(None)
    return json_mode.analysis_bound(max_tokens - json_mode.COMMAND_TOKENS * (robots - 1))


def parse_round(reply: str, robots: tuple[str, ...]) -> tuple[dict[str, Action], dict[str, str]]:
    """The commands a reply names, robot -> action, and robot -> why its command could not be
    read (missing, or not a skill call); lines naming no robot of the team are ignored."""
    commands: dict[str, Action] = {}
    problems: dict[str, str] = {}
    by_name = {r.lower(): r for r in robots}
    for line in reply.splitlines():
        m = LINE.match(line)
        if m is None or m.group(1).lower() not in by_name:
            continue
        robot = by_name[m.group(1).lower()]
        if robot in commands:
            continue
        try:
            commands[robot] = parse_command(m.group(2))
            problems.pop(robot, None)
        except ReplyFormatError as e:
            problems[robot] = f"your command {m.group(2)!r} could not be read: {e}"
    for r in robots:
        if r not in commands and r not in problems:
            problems[r] = "the planner named no command for you"
    return commands, problems


def round_prompt(
    robots: tuple[str, ...], obs: dict[str, Observation], feedback: dict[str, str]
) -> list[dict[str, str]]:
    """The round's chat: the system text, and every robot's observation, feedback and messages."""
    task = next((o for o in obs.values() if o.targets), None)
    blocks = []
    for r in robots:
        o = obs.get(r)
        if o is None:
            blocks.append(f"## {r}\nNot heard from yet: give it wait().")
            continue
        said = "\n".join(f"- from {m.sender}: {m.content}" for m in o.new_messages) or "none"
        blocks.append(
            f"## {r}\n### Status\n{robot_status(o)}\n### Skills\n{', '.join(o.status.skills)}\n"
            f"### Scene graph\n{scene_graph(o)}\n### Feedback\n{feedback.get(r, 'none yet')}\n### Messages\n{said}"
        )
    words = {
        "robots": ", ".join(robots),
        "robot_names": ", ".join(robots),
        "task": task_text(task) if task is not None else "(the finisher has not reported the task yet)",
        "robots_block": "\n\n".join(blocks),
    }
    system = Template(_template("centralized_system.txt")).safe_substitute(words)
    user = Template(_template("centralized_user.txt")).safe_substitute(words)
    return [{"role": "system", "content": system}, {"role": "user", "content": user}]


@dataclass
class LLMCentralPlanner(CentralPlanner):
    """The central planner whose rounds are one model call each (see the module docstring)."""

    client: LLMClient | None = None
    feedback: dict[str, str] = field(default_factory=dict)  # robot -> its last result's feedback
    unread: dict[str, str] = field(default_factory=dict)  # robot -> why the last call's command for it was not run
    calls: int = 0
    _cached: dict[int, dict[str, Action]] = field(default_factory=dict)  # sequential: tick -> the call's commands
    _for: dict[str, tuple[str, Completion]] = field(default_factory=dict)  # robot -> the call its turn made
    structured: bool = False  # --structured: the reply is one JSON object, each robot's command from its own schema
    max_analysis: int = json_mode.MAX_ANALYSIS
    _schema_hash: str | None = None  # the last call's schema, with --structured
    _failed: str | None = None  # why the last call gave no reply (the model did not answer)

    async def aclose(self) -> None:
        """The episode is over: the model client is closed (its connections with it), once for all the seats."""
        client, self.client = self.client, None
        await close_client(client)

    async def plan(self, asking: tuple[str, ...]) -> dict[str, Action]:
        tick = max(self.knowledge.obs[r].tick for r in asking)
        if self.schedule == "sequential" and tick in self._cached:
            return {r: self._cached[tick].get(r, Wait()) for r in asking}
        assert self.client is not None
        told = {r: f"{self.unread[r]}; you waited instead" if r in self.unread else f for r, f in self.feedback.items()}
        told |= {r: f"{p}; you waited instead" for r, p in self.unread.items() if r not in told}
        messages = round_prompt(self.robots, self.knowledge.obs, told)
        schema = None
        if self.structured:  # each heard robot's command from its own skills and scene graph (agents/structured.py)
            heard = [self.knowledge.obs[r] for r in self.robots if r in self.knowledge.obs]
            schema = json_mode.round_schema(heard, max_analysis=self.max_analysis)
            messages[-1]["content"] = messages[-1]["content"].rstrip("\n") + "\n" + ROUND_INSTRUCTIONS
            self._schema_hash = json_mode.schema_hash(schema)
        self.calls += 1
        self.rounds += 1
        try:
            done = await self.client.complete(messages, schema=schema)
        except LLMFatalError:
            raise
        except LLMError as exc:  # the model did not answer: every robot waits this round and is told why
            said = f"the planner's model did not answer: {exc}"[:300]
            self.unread = dict.fromkeys(self.robots, said)
            self._cached = {tick: {}}
            self._failed = said
            return {r: Wait() for r in asking}
        self._failed = None
        commands, self.unread = self._read(done.text)
        self._cached = {tick: commands}
        prompt = prompt_text(messages)
        self._for[asking[0]] = (prompt, done)
        return {r: commands.get(r, Wait()) for r in asking}

    def _read(self, text: str) -> tuple[dict[str, Action], dict[str, str]]:
        """The round's commands and each unread robot's problem, from lines or (--structured) JSON."""
        if not self.structured:
            return parse_round(text, self.robots)
        try:
            commands, problems = json_mode.parse_round_structured(text, self.robots)
        except ReplyFormatError as exc:  # no commands object at all: every robot's problem
            return {}, {r: f"the planner's reply could not be read: {exc}" for r in self.robots}
        return commands, {r: f"your command could not be read: {p}" for r, p in problems.items()}

    def record(self, robot: str, result: ActionResult) -> None:
        super().record(robot, result)
        self.feedback[robot] = result.outcome.feedback

    def decision(self, robot: str, action: Action) -> Decision:
        made = self._for.pop(robot, None)
        told = Coordination(job=None if isinstance(action, Wait) else action.call(), by=PLANNER)
        if made is None and self._failed is not None:  # a thought that says the model did not answer, as a robot's own
            return Decision(
                action=action, parse_error=self._failed, failure=ReplyFailure.MODEL_UNREACHABLE, coordination=told
            )
        if made is None:
            return Decision(action=action, reasoning=f"round {self.rounds}: the planner's command", coordination=told)
        prompt, done = made
        return Decision(
            coordination=told,
            schema_hash=self._schema_hash if self.structured else None,
            action=action,
            prompt=prompt,
            reply=done.text,
            prompt_tokens=done.prompt_tokens,
            completion_tokens=done.completion_tokens,
            latency=done.latency,
            reasoning=done.reasoning,
            finish_reason=done.finish_reason,
        )


def build_centralized(seating: Seating) -> Mapping[str, Policy]:
    """One planner for `seating.robots`, a seat of it for each: the LLM form's when the seating
    names a model, else the heuristic form (centralized.py)."""
    if seating.model is not None:
        from ..llm.model_spec import make_client  # here: the heuristic form needs no HTTP client

        client = make_client(seating.model, seating.base_url, **dict(seating.client_options))
        planner: CentralPlanner = LLMCentralPlanner(
            seating.robots,
            seating.schedule,
            client=client,
            structured=seating.structured,
            max_analysis=round_analysis_bound(seating.client_options.get("max_tokens"), len(seating.robots)),
        )
    else:
        planner = CentralPlanner(seating.robots, seating.schedule)
    return {r: Seat(r, planner) for r in seating.robots}
