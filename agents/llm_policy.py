"""The paper's planner: render the role's prompts from the robot's own observation and memory,
ask the model, parse exactly one command.

An unparseable reply, a reply cut at max_tokens before its command, or a model that stays down
after its retries or misses the step deadline never crashes the agent: the robot waits that
step and its next prompt's feedback says so. For an unreadable reply that is all it says (Table
III has no format advice); with the feedback_advice aid it also gives the reason (bounded to
FEEDBACK_CHARS) and how to answer. What no
later step can change stops the agent with LLMFatalError instead: bad credentials, no such
model, a server that refuses --structured's response format, or a server that was down for
the robot's whole first step (refusing connections, or accepting them and never answering).

With `structured=True` each request carries a JSON Schema built from the robot's own skills
and scene graph (mhrc.agents.structured), the prompt ends with the JSON instructions instead of
"Command: ...", and the reply is parsed as JSON; the default is the paper's free text.

Templates are `string.Template` files, one set per robot kind: `<kind>_system.txt`,
`<kind>_user.txt` and (the prompt_hints aid's) `<kind>_hints.txt` in the package `mhrc.prompts`,
the kind's `KindPrompt.template` naming them (mhrc.agents.crew: the kinds, their parts, who
talks to whom). A directory of your own (`prompts_dir`, `--prompts DIR`) may hold
`<robot>_<part>.txt` for one robot and `<kind>_<part>.txt` for every robot of a kind: for each
part the robot's own file wins over its kind's, and its kind's over the package's. The
default set carries the paper's appendix (role, background, profile, constraints, skills,
response format; scene graph, status, task, histories) and nothing more: the paper's Alice, Bob
and David are the mobile_manipulator, tabletop_arm and mobile_base templates filled for the
paper's team. Placeholders (* required):

any     $robot      the robot's name, capitalized (Alice)
        $finisher, $fetchers, $scouts, $contacts and their forms _or, _s, _they, _them, _are, _can
                    the robot's teammates by part and the ones it talks to, named (mhrc.agents.crew);
                    a line using a group the team leaves empty is left out. Filled once, at load.
system
        $teammates  one line per teammate present: name and skill signatures (the default
                    templates give the appendix's background instead; the prompt_hints aid
                    adds this table to its advice)
        $absent     a note naming the teammates left out of this episode, or nothing
        $skills*    one line per skill of this robot: signature and what it does
        $hints      the prompt_hints aid's advice (`<kind>_hints.txt`), or nothing; a system
                    template without it gets the advice at its end when the aid is on
user    $step       the current step (tick); the default templates do not show it (the appendix does not)
        $scene_graph*  furniture (position, yaw, open/closed, stand poses, place pose) and known objects
        $status*    position, orientation, gripper
        $task*      brief and detailed task of the robot's role (the finisher's holds the object list)
        $progress   the latest task progress status as a titled section (the finisher's,
                    required in its template; empty for the others, and under the no_feedback
                    ablation: Table III counts it as feedback)
        $feedback*, $messages*, $actions*
                    each history as a titled section, older entries first and the newest tagged
                    "(latest)"; empty where an ablation removes it

An unknown placeholder, or a required one missing, is an error at load time naming the file and
the placeholder, not a silent "$name" in a prompt or a prompt without its scene graph.
"""

from __future__ import annotations

import asyncio
import re
from importlib import resources
from pathlib import Path
from string import Template
from typing import TypedDict

from mhrc.core.logs import get_logger
from mhrc.core.protocol import LLM_ERROR_PREFIX, Action, ActionResult, Observation, Wait
from mhrc.core.protocol.actions import CALLS
from mhrc.core.protocol.thoughts import ReplyFailure
from mhrc.core.team import TeamSpec

from . import observation as describe
from . import structured as json_mode
from .crew import STATIC, Crew, Role, crew_of
from .llm.completion import (
    DEFAULT_TEMPERATURE,
    LLMClient,
    LLMError,
    LLMFatalError,
    LLMSilent,
    LLMTimeout,
    Messages,
    prompt_text,
)
from .memory import HISTORIES, TITLES, Memory
from .parse import ReplyFormatError, parse_command, signature
from .policy import Decision
from .replay import ReplayClient

log = get_logger("mhrc.llm_policy")

MEANINGS = {
    "navigate": "go to the stand pose with that id of that piece of furniture",
    "move": "move your base dx metres along the x axis and dy metres along the y axis",
    "open": "open that piece of furniture, whose drawer runs on rails or whose door or lid turns on hinges",
    "pick": "pick up that object",
    "place": "put the object in your gripper at that location",
    "communicate": "send content to that robot",
    "wait": "do nothing this step",
}
ROLE_MEANINGS: dict[Role, dict[str, str]] = {  # the appendix words some skills differently for Bob and David
    "finisher": {
        "communicate": "send content to that robot; when objects are missing and you need help, sum up how things stand in it"
    },
    "scout": {
        "navigate": "go to the stand pose with that id of that piece of furniture, both taken from your scene graph",
        "communicate": "send content to that robot; when you discover new objects, send one too, summing up what you did and how things stand",
    },
}
KIND_MEANINGS = {  # and a kind's own, over its part's
    "drone": {
        "navigate": "fly to the stand pose with that id of that piece of furniture, both taken from your scene graph, and look at it from above"
    }
}
PLACEHOLDERS = {
    "system": frozenset({"teammates", "absent", "skills", "hints"}) | STATIC,
    "user": frozenset({"step", "scene_graph", "status", "task", "progress", *HISTORIES}) | STATIC,
    "hints": STATIC,
}
REQUIRED = {
    "system": frozenset({"skills"}),
    "user": frozenset({"scene_graph", "status", "task", *HISTORIES}),
    "hints": frozenset(),
}
REQUIRED_FOR: dict[tuple[Role, str], frozenset[str]] = {
    ("finisher", "user"): frozenset({"progress"})  # the appendix gives Bob his task progress
}
SMALL_CONTEXT_CAP = 12_000  # ~3,000 tokens: a --history-cap that fits a 4k-context local model with room for the reply
UNREADABLE = "Your command could not be read, so you waited."  # the paper's: that it failed, no format advice
# with the feedback_advice aid: the reason and how to answer
FORMAT_ERROR = "Your reply could not be executed ({reason}), so you waited. Give your command on one line: Command: skill(arguments)."
JSON_FORMAT_ERROR = (
    "Your reply could not be executed ({reason}), so you waited. Answer with one JSON object: analysis, then command."
)
CUT_REPLY = "your reply was cut at the token limit before it gave a command; think more briefly"
# The appendix's first feedback of the robot that finishes the task: before any action, talk to the fetchers.
FIRST_STEP: dict[Role, str] = {
    "finisher": "This is the first step of the task: do nothing else now; communicate with $fetchers and share what you know so far."
}
MODEL_DOWN = "Your planner could not reach its model ({reason}), so you waited."
UNREADABLE_TAG, MODEL_DOWN_TAG = (
    "unreadable",
    "model down",
)  # the feedback entries' tags (what a history summary counts)
FEEDBACK_CHARS = 300  # what one error may put into the next prompt


class LLMUnreachable(LLMFatalError):
    """The model never answered during the robot's first step: the run cannot go on."""


def _short(text: str, limit: int = FEEDBACK_CHARS) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


class TemplateError(ValueError):
    """A prompt template that is missing or uses a placeholder mhrc does not fill."""


def template_source(
    robot: str, part: str, prompts_dir: str | Path | None = None, *, team: TeamSpec | None = None
) -> tuple[str, str] | None:
    """The text of `robot`'s `part` template and where it came from: `<robot>_<part>.txt` in
    `prompts_dir`, else `<kind>_<part>.txt` there, else the package's `<kind>_<part>.txt`
    (`team`: the robot's team, the paper's by default); None when there is none."""
    stem = crew_of(robot, team).prompt.template
    if prompts_dir is not None:
        for name in (f"{robot}_{part}.txt", f"{stem}_{part}.txt"):
            path = Path(prompts_dir) / name
            if path.is_file():
                return path.read_text(encoding="utf-8"), str(path)
    res = resources.files("mhrc.prompts").joinpath(f"{stem}_{part}.txt")
    return (res.read_text(encoding="utf-8"), f"mhrc.prompts/{stem}_{part}.txt") if res.is_file() else None


def load_template(
    robot: str, part: str, prompts_dir: str | Path | None = None, *, team: TeamSpec | None = None
) -> Template:
    """`robot`'s `part` template (`template_source`), its placeholders checked (none unknown,
    none required missing), not yet filled. Errors about a file of `prompts_dir` name --prompts."""
    crew = crew_of(robot, team)
    found = template_source(robot, part, prompts_dir, team=team)
    if found is None:
        raise TemplateError(
            f"no prompt template for {robot}'s {part} prompt: neither {robot}_{part}.txt nor "
            f"{crew.prompt.template}_{part}.txt in {prompts_dir or 'mhrc.prompts'}, nor a built-in one for kind {crew.kind}"
        )
    text, where = found
    opt = "--prompts: " if prompts_dir is not None and not where.startswith("mhrc.prompts/") else ""
    template = Template(text)
    if not template.is_valid():
        raise TemplateError(f"{opt}{where}: a '$' that starts no placeholder; write '$$' for a dollar sign")
    used = set(template.get_identifiers())
    unknown = used - PLACEHOLDERS[part]
    if unknown:
        allowed = ", ".join("$" + p for p in sorted(PLACEHOLDERS[part] - STATIC))
        raise TemplateError(
            f"{opt}{where}: unknown placeholder(s) {', '.join(sorted('$' + u for u in unknown))}; "
            f"{part} templates may use {allowed + ', ' if allowed else ''}$robot and the team's words "
            "($finisher, $fetchers, $scouts, $contacts and their forms: see mhrc.agents.crew)"
        )
    required = REQUIRED[part] | REQUIRED_FOR.get((crew.role, part), frozenset())
    missing = required - used
    if missing:
        raise TemplateError(
            f"{opt}{where}: required placeholder(s) {', '.join(sorted('$' + m for m in missing))} missing; "
            f"{robot}'s {part} template (a {crew.kind}, the team's {crew.role}) must use "
            f"{', '.join(sorted('$' + p for p in required))}"
        )
    return template


def load_hints(robot: str, prompts_dir: str | Path | None = None, *, team: TeamSpec | None = None) -> str:
    """The prompt_hints aid's advice for `robot`, filled for its team: `<robot>_hints.txt` or
    `<kind>_hints.txt` from `prompts_dir`, else its kind's from the package (placeholders: the
    team's words only); "" for a robot without any."""
    if template_source(robot, "hints", prompts_dir, team=team) is None:
        return ""
    template = load_template(robot, "hints", prompts_dir, team=team)
    return Template(crew_of(robot, team).fill(template.template)).substitute().strip()


def _tidy(text: str) -> str:
    """No runs of blank lines where an ablation emptied a section."""
    return re.sub(r"\n{3,}", "\n\n", text).strip() + "\n"


class PolicyOptions(TypedDict, total=False):
    """LLMPolicy's settings besides its robot and client (an episode's: mhrc.run.config.EpisodeConfig.policy_options)."""

    prompts_dir: str | Path | None
    temperature: float
    feedback: bool
    history: bool
    prompt_cap_chars: int | None
    teammates_absent: tuple[str, ...]
    reach_labels: bool
    prompt_hints: bool
    feedback_advice: bool
    structured: bool
    step_deadline: float | None
    max_tokens: int | None
    team: TeamSpec | None


class LLMPolicy:
    """One robot's LLM planner.

    Ablations: feedback=False leaves all feedback out; history=False leaves the histories out and
    keeps only the current observation: what arrived with it this step (the last action's
    feedback, the messages delivered now). teammates_absent names robots not in this episode.
    prompt_cap_chars bounds the whole prompt (system + user); None (the default, as the paper)
    keeps every history whole. reach_labels (an aid, not the paper's) says for each object
    whether it lies within the robot's arm reach. prompt_hints (an aid, not the paper's) adds the
    kind's advice (`<kind>_hints.txt`) and the teammates' skills to the system prompt, and
    where objects lie, distances, the step, the stand pose, reach and the arm base to the scene
    graph and status. feedback_advice (an aid, the agent's half of the world's) puts the reason
    an unreadable reply failed, and how to answer, into its feedback. structured asks for a JSON decision that
    follows a schema of this step's valid actions, its analysis short enough that the command
    fits within the client's max_tokens. step_deadline bounds one step's model call,
    every retry included: past it the robot waits that step. team is the robot's team (the
    paper's by default): the robot's kind picks its templates, its teammates' names and kinds
    fill them (mhrc.agents.crew).
    """

    def __init__(
        self,
        robot: str,
        client: LLMClient,
        *,
        prompts_dir: str | Path | None = None,
        temperature: float = DEFAULT_TEMPERATURE,
        feedback: bool = True,
        history: bool = True,
        prompt_cap_chars: int | None = None,
        teammates_absent: tuple[str, ...] = (),
        reach_labels: bool = False,
        prompt_hints: bool = False,
        feedback_advice: bool = False,
        structured: bool = False,
        step_deadline: float | None = None,
        max_tokens: int | None = None,
        team: TeamSpec | None = None,
    ) -> None:
        if step_deadline is not None and step_deadline <= 0:
            raise ValueError(f"step_deadline must be positive (got {step_deadline})")
        self.robot = robot
        self.crew: Crew = crew_of(robot, team)
        self.structured = structured
        self.max_analysis = json_mode.analysis_bound(max_tokens)
        self.step_deadline = step_deadline
        self._answered = False  # any reply yet: a server down before the first one is fatal
        self.reach_labels = reach_labels
        self.prompt_hints = prompt_hints
        self.feedback_advice = feedback_advice
        self.client = client
        self.name = f"llm:{client.model}"
        self.temperature = temperature
        self.feedback = feedback
        self.history = history
        self.cap = prompt_cap_chars
        self.absent = tuple(teammates_absent)
        self.memory = Memory()
        role = self.crew.role
        if feedback and role in FIRST_STEP:  # the appendix's first feedback, before any action
            self.memory.add("feedback", 0, self.crew.fill(FIRST_STEP[role]), tag="first step")
        # the kind's templates (or --prompts' own), the team's words filled in once
        self.system_t, self.user_t = (
            Template(self.crew.fill(load_template(robot, part, prompts_dir, team=team).template))
            for part in ("system", "user")
        )
        self.hints = load_hints(robot, prompts_dir, team=team) if prompt_hints else ""
        if isinstance(
            client, ReplayClient
        ):  # a trace recorded with other prompts is refused now, not at its first step
            where = [
                (template_source(robot, part, prompts_dir, team=team) or ("", part))[1] for part in ("system", "user")
            ]
            client.check_templates({where[0]: self.system_t, where[1]: self.user_t})
        self._pending: tuple[int, str, str] | None = None  # (tick, why this step's reply gave no action, its tag)
        self._log = log.bind(robot=robot, model=client.model)

    # ------------------------------------------------------------------ rendering
    def _histories(self, obs: Observation, budget: int | None) -> dict[str, str]:
        sections = dict.fromkeys(HISTORIES, "")
        if self.history:
            shown = HISTORIES if self.feedback else ("messages", "actions")
            return sections | self.memory.render(shown, budget)
        # only what arrived with the current observation
        if self.feedback:
            sections["feedback"] = self._latest_feedback()
        lines = [f"- (latest) from {m.sender.capitalize()}: {m.content}" for m in obs.new_messages]
        sections["messages"] = f"{TITLES['messages']}:\n" + ("\n".join(lines) or "- (none this step)")
        return sections

    def _latest_feedback(self) -> str:
        latest = self.memory.latest("feedback")
        acted = self.memory.actions[-1].step if self.memory.actions else None
        latest = [e for e in latest if e.step == acted]  # older feedback is history
        return f"{TITLES['feedback']}:\n" + ("\n".join(e.line(latest=True) for e in latest) or "- (none yet)")

    def render(self, obs: Observation) -> Messages:
        """The system and user messages for this observation and the memory so far."""
        meanings = MEANINGS | ROLE_MEANINGS.get(self.crew.role, {}) | KIND_MEANINGS.get(self.crew.kind, {})
        teammates = describe.teammates(obs, self.absent)
        hints = self.hints
        if self.prompt_hints and "teammates" not in self.system_t.get_identifiers():
            hints = f"{hints}\n\n## Your teammates in this episode and their skills\n{teammates}".strip()
        system = self.system_t.substitute(
            robot=self.robot.capitalize(),
            teammates=teammates,
            absent=self._absent_note(),
            skills="\n".join(f"- {signature(s)}: {meanings[s]}" for s in obs.status.skills if s in CALLS),
            hints=hints,
        )
        if hints and "hints" not in self.system_t.get_identifiers():
            system = _tidy(system) + "\n" + hints
        fields = {
            "step": str(obs.tick),
            "scene_graph": describe.scene_graph(obs, reach_labels=self.reach_labels, hints=self.prompt_hints),
            "status": describe.robot_status(obs, hints=self.prompt_hints),
            "task": describe.task_text(obs),
            "progress": describe.progress_text(obs) if self.feedback else "",  # Table III counts it as feedback
        }
        budget = None
        if self.cap is not None and self.history:
            fixed = len(system) + 2 + len(self.user_t.substitute(fields | dict.fromkeys(HISTORIES, "")))
            budget = max(0, self.cap - fixed)
        user = self.user_t.substitute(fields | self._histories(obs, budget))
        if self.structured:
            user = _tidy(user) + "\n" + json_mode.STRUCTURED_INSTRUCTIONS
        return [{"role": "system", "content": _tidy(system)}, {"role": "user", "content": _tidy(user)}]

    def _absent_note(self) -> str:
        if not self.absent:
            return ""
        names = " and ".join(a.capitalize() for a in self.absent)
        verb = "is" if len(self.absent) == 1 else "are"
        note = f"{names} {verb} not part of the team in this episode."
        if self.prompt_hints:  # advice the paper's ablation does not give
            note += (
                f" Nobody else will do {names}'s part: "
                "ignore what this prompt says about working with them and take over their part yourself where you can."
            )
        return note

    # ------------------------------------------------------------------ deciding
    def prepare(self, obs: Observation) -> Messages:
        """What this robot's model is asked on `obs`: the earlier step's pending feedback and the
        messages delivered with `obs` go into the memory, then the prompts are rendered (`decide`'s
        first half; an environment that takes its commands from elsewhere calls it alone)."""
        self._flush_pending()
        for m in obs.new_messages:
            self.memory.add("messages", m.tick, f"from {m.sender.capitalize()}: {m.content}", tag=f"from {m.sender}")
        return self.render(obs)

    def interpret(self, text: str, tick: int, finish_reason: str | None = None) -> tuple[Action, str | None]:
        """The action a reply commands, and None; or `wait` and why the reply could not be read, which
        becomes the robot's feedback for this step (`decide`'s second half)."""
        try:
            action = json_mode.parse_structured(text)[0] if self.structured else parse_command(text)
            return action, None
        except ReplyFormatError as exc:
            reason = CUT_REPLY if finish_reason == "length" else _short(str(exc))
            self._log.info("unparseable reply, waiting", tick=tick, reason=reason)
            advice = JSON_FORMAT_ERROR if self.structured else FORMAT_ERROR
            self._pending = (tick, advice.format(reason=reason) if self.feedback_advice else UNREADABLE, UNREADABLE_TAG)
            return Wait(), reason

    async def decide(self, obs: Observation) -> Decision:
        messages = self.prepare(obs)
        prompt = prompt_text(messages)
        schema = json_mode.decision_schema(obs, max_analysis=self.max_analysis) if self.structured else None
        digest = json_mode.schema_hash(schema) if schema is not None else None
        try:
            async with asyncio.timeout(self.step_deadline):
                c = await self.client.complete(messages, temperature=self.temperature, schema=schema)
        except LLMFatalError:
            raise
        except (LLMError, TimeoutError) as exc:
            silent = (
                isinstance(exc, LLMSilent) or getattr(self.client, "answered", True) is False
            )  # not even a status line, ever
            if isinstance(exc, TimeoutError):
                exc = LLMTimeout(f"no answer within the step deadline of {self.step_deadline:g} s")
            if not self._answered and (silent or not isinstance(exc, LLMTimeout)):
                raise LLMUnreachable(f"{self.robot}'s model never answered during its first step: {exc}") from None
            self._log.warning("model unavailable, waiting", tick=obs.tick, error=str(exc))
            self._pending = (obs.tick, MODEL_DOWN.format(reason=_short(str(exc))), MODEL_DOWN_TAG)
            return Decision(
                action=Wait(),
                prompt=prompt,
                parse_error=_short(f"{LLM_ERROR_PREFIX}{exc}", 2000),
                failure=ReplyFailure.MODEL_UNREACHABLE,
                schema_hash=digest,
            )
        self._answered = True
        action, error = self.interpret(c.text, obs.tick, c.finish_reason)
        return Decision(
            action,
            prompt,
            c.text,
            error,
            c.prompt_tokens,
            c.completion_tokens,
            c.latency,
            reasoning=c.reasoning,
            reasoning_tokens=c.reasoning_tokens,
            finish_reason=c.finish_reason,
            schema_hash=digest,
            ttft=c.ttft,
            failure=None
            if error is None
            else ReplyFailure.CUT_OFF
            if c.finish_reason == "length"
            else ReplyFailure.UNREADABLE,
        )

    def _flush_pending(self) -> None:
        """A format or model error whose result never came back still becomes feedback."""
        if self._pending is not None:
            tick, text, tag = self._pending
            self.memory.add("feedback", tick, text, tag=tag)
            self._pending = None

    def record(self, result: ActionResult) -> None:
        """The result of the action this policy chose last: into the feedback and action histories."""
        call = result.action.call()
        self.memory.add("actions", result.tick, call, tag=result.action.skill)
        if self._pending is not None and self._pending[0] == result.tick:
            self._flush_pending()  # the reason for the wait, not "You waited."
            return
        self._flush_pending()
        ok = result.outcome.succeeded
        if ok and result.action.skill == "wait":
            return  # nothing learned; Bob's task status is in his observation
        verdict = "succeeded" if ok else "FAILED"
        self.memory.add(
            "feedback", result.tick, f"{call} {verdict}: {result.outcome.feedback}", tag="succeeded" if ok else "failed"
        )
