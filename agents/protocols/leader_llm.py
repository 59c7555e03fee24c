"""The LLM form of `leader`: each robot's agent is a model, and DynaHMRC's loop (self-description
and bid, election, allocation by the leader, execution, reflection on failure, report) is carried
out in the `communicate` actions the models write, in leader_talk.py's sentence shapes.

Each reply is one command line, read by the paper's command parser (agents/parse.py), or with
`--structured` one JSON decision (agents/structured.py). The code decides nothing: `Stages`
follows the messages each robot heard and sent (leader_talk.parse) and tells its model, in the
prompt (prompts/leader_system.txt, leader_user.txt, in the paper's sections), which stage it is
in: whom to describe itself to, the bids the convener holds, who leads, the jobs it was given,
and for the leader what it allocated and what was reported. A message of another shape is still
delivered and shown; it only moves no stage.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from string import Template

from mhrc.core.protocol import Action, ActionResult, Communicate, Coordination, Move, Navigate, Observation, Wait
from mhrc.core.protocol.actions import CALLS
from mhrc.core.protocol.thoughts import ReplyFailure

from .. import structured as json_mode
from ..heuristic_base import role_of
from ..llm.completion import LLMClient, LLMError, LLMFatalError, close_client, prompt_text
from ..llm_policy import MEANINGS
from ..observation import robot_status, scene_graph, task_text
from ..parse import ReplyFormatError, parse_command, signature
from ..policy import Decision, Policy
from . import leader_talk as talk
from .base import Seating
from .leader import ROLE_BID, build_heuristic
from .steps import Job

__all__ = ["LLMLeaderPolicy", "Stages", "build_leader", "read"]

HEARD = 8  # messages the prompt shows (the latest)
FEEDBACK = 4  # results of the robot's own last actions the prompt shows
REPORTS = 8  # reports the leader's prompt shows (the latest)
NAMED = ("robot", "leader", "convener", "asked")  # the robot names a sentence carries, read case-blind


def _template(name: str) -> str:
    return resources.files("mhrc.prompts").joinpath(name).read_text(encoding="utf-8")


def read(text: str) -> talk.Said | None:
    """What a message says in the protocol's shapes, forgiving what models do to a sentence:
    quotes around it, a missing final period, capitalised names."""
    text = text.strip().strip("\"'").strip()
    if text and not text.endswith("."):
        text += "."
    said = talk.parse(text) or talk.parse(text[:1].upper() + text[1:])  # "election held by ..."
    if said is None:
        return None
    names = {f.name: getattr(said, f.name).lower() for f in dataclasses.fields(said) if f.name in NAMED}
    return dataclasses.replace(said, **names)


@dataclass
class Stages:
    """One robot's view of the loop, followed from the messages it heard and sent."""

    robot: str
    team: tuple[str, ...]
    skills: dict[str, tuple[str, ...]] = field(default_factory=dict)
    attached: set[str] = field(default_factory=set)
    bids: dict[str, float] = field(default_factory=dict)  # the convener: the bids it heard
    described_to: str | None = None  # the convener I sent my self-description and bid
    leader: str | None = None
    told: set[str] = field(default_factory=set)  # the convener: robots told the election's result
    jobs: list[Job] = field(default_factory=list)  # given to me and not reported yet, in order
    book: dict[str, list[Job]] = field(default_factory=dict)  # the leader: robot -> its jobs not reported yet
    reports: list[str] = field(default_factory=list)  # the leader: the reports it heard
    task: talk.TaskList | None = None  # the leader: what the finisher said the task is
    told_task: str | None = None  # the finisher: the leader it told the task
    tell_status: bool = False  # after a new election: tell the new leader what I work on
    make_way: str | None = None  # a teammate asked me to leave this furniture
    elections: int = 0

    def convener(self) -> str:
        """Who collects the bids: the lowest bid by role among those attached (every robot can
        work it out from its teammates' skills), first in the team's order."""
        order = {r: i for i, r in enumerate(self.team)}
        return min(self.attached, key=lambda r: (ROLE_BID[role_of(self.skills.get(r, ()))], order.get(r, len(order))))

    def observe(self, obs: Observation) -> None:
        """A new observation: who is attached, and the messages it brought."""
        self.skills[self.robot] = tuple(obs.status.skills)
        self.skills.update({r: tuple(s) for r, s in obs.teammates.items()})
        self.attached = {self.robot, *obs.teammates}
        for m in obs.new_messages:
            said = read(m.content)
            if said is not None:
                self.hear(said)
        if self.leader is not None and self.leader not in self.attached:
            self.lost_leader()

    def lost_leader(self) -> None:
        """The leader detached: the election is held again; jobs are kept and told to the new leader."""
        self.leader, self.described_to, self.told_task = None, None, None
        self.bids, self.told, self.book, self.reports = {}, set(), {}, []
        self.tell_status = "navigate" in self.skills.get(self.robot, ())

    def hear(self, said: talk.Said) -> None:
        if isinstance(said, talk.Describe):
            self.bids[said.robot] = said.bid
        elif isinstance(said, talk.Elected):
            self._leads(said.leader)
        elif isinstance(said, talk.Assign):
            if self.leader is None:
                self._leads(said.leader)
            if said.robot == self.robot and Job(said.kind, said.target) not in self.jobs:
                self.jobs.append(Job(said.kind, said.target))
        elif isinstance(said, talk.TaskList):
            self.task = said
        elif isinstance(said, talk.Done | talk.Failed):
            self._book(said.robot, Job(said.kind, said.target), None)
            self.reports = [*self.reports, _report(said)][-REPORTS:]
        elif isinstance(said, talk.MakeWay) and said.asked == self.robot:
            self.make_way = said.furniture
        elif isinstance(said, talk.Status):
            self._book(said.robot, None, Job(said.kind, said.target) if said.kind and said.target else None)
            self.reports = [*self.reports, _report(said)][-REPORTS:]

    def sent(self, msg: Communicate) -> None:
        """A message I sent (and the world delivered): the stage it moves."""
        said = read(msg.content)
        if isinstance(said, talk.Describe):
            self.described_to = msg.to
        elif isinstance(said, talk.Elected):
            self._leads(said.leader)
            self.told.add(msg.to)
        elif isinstance(said, talk.Assign):
            self._book(said.robot, None, Job(said.kind, said.target))
        elif isinstance(said, talk.TaskList):
            self.told_task = msg.to
        elif isinstance(said, talk.Done | talk.Failed):
            job = Job(said.kind, said.target)
            self.jobs = [j for j in self.jobs if j != job]
        elif isinstance(said, talk.Status):
            self.tell_status = False

    def _leads(self, leader: str) -> None:
        if leader != self.leader:
            self.elections += 1
        self.leader = leader

    def _book(self, robot: str, done: Job | None, given: Job | None) -> None:
        jobs = [j for j in self.book.get(robot, []) if j != done]
        if given is not None and given not in jobs:
            jobs.append(given)
        self.book[robot] = jobs

    # ---------------------------------------------------------------- for the prompt
    def stage(self, obs: Observation) -> str:
        """What this robot's stage asks of it, in words, with the sentence to send where there is one."""
        me, lines = self.robot, []
        conv = self.convener()
        if self.leader is None and conv != me:
            if self.described_to != conv:
                can = ", ".join(s for s in obs.status.skills if s not in ("communicate", "wait"))
                text = f"{me} here: {obs.status.kind}; I can {can}. My bid to lead: NUMBER."
                return (
                    f"Stage 1, self-description and bid. {conv} is the convener: tell it what you are and your bid "
                    f"to lead, with NUMBER the steps of your own work you would give up to lead:\n"
                    f'communicate("{text}", {conv})'
                )
            return f"Stage 2, election: you sent {conv} your bid. Wait for the result (wait())."
        if self.leader is None:
            heard = ", ".join(f"{r} {b:.1f}" for r, b in sorted(self.bids.items())) or "none yet"
            missing = [r for r in self.team if r in self.attached and r != me and r not in self.bids]
            return (
                f"Stage 2, election: you are the convener. Bids heard: {heard}. "
                f"Still to bid: {', '.join(missing) or 'nobody'}. Your own bid is the steps of your own work you "
                f"would give up to lead. Once every robot has bid, choose the lowest bid (yours too) and tell each "
                f"other robot, one message each:\n"
                f'communicate("Election held by {me}: LEADER leads.", ROBOT)'
            )
        if self.told:  # the convener that elected: the others still to be told
            untold = [r for r in self.team if r in self.attached and r != me and r not in self.told]
            if untold:
                lines.append(
                    f"Election: tell {', '.join(untold)} the result, one message each:\n"
                    f'communicate("Election held by {me}: {self.leader} leads.", ROBOT)'
                )
        lead = self.leader
        if self.tell_status and lead != me:
            now = f"working on {self.jobs[0].call()}" if self.jobs else "free"
            lines.append(f'A new leader, {lead}: tell it what you do:\ncommunicate("{me} reports: {now}.", {lead})')
        if "navigate" not in obs.status.skills and obs.targets and self.told_task != lead and lead != me:
            lines.append(
                f"Tell the leader, {lead}, the task's targets and those within your own reach:\n"
                f'communicate("{me} reports: the targets are {", ".join(obs.targets)}; I take OBJECT, OBJECT myself.", {lead})'
            )
        if lead == me:
            lines.append(
                "Stage 3, allocation: you lead. Give each robot without work a job, one message each "
                "(a fetch for an object whose place is known, else an explore of a furniture not looked at yet):\n"
                f'communicate("Leader {me} assigns ROBOT: fetch(OBJECT).", ROBOT) or '
                f'communicate("Leader {me} assigns ROBOT: explore(FURNITURE).", ROBOT)\n'
                "You may give yourself a job too (no message needed) and carry it out."
            )
        if self.jobs:
            job = self.jobs[0]
            rest = f" (then {', '.join(j.call() for j in self.jobs[1:])})" if len(self.jobs) > 1 else ""
            work = (
                f"Stage 4, execution: your job is {job.call()}{rest}. Carry it out with your skills "
                "(a fetch ends with the object placed on the finisher's table)."
            )
            if lead != me:
                work += (
                    f" Then report it to {lead}:\n"
                    f'communicate("{me} reports: done {job.call()}.", {lead}) or, if it failed and you reflected on why,\n'
                    f'communicate("{me} reports: failed {job.call()} (CODE); reflection: WHAT SHOULD HAPPEN NEXT.", {lead})'
                )
            lines.append(work)
        elif "navigate" not in obs.status.skills:
            lines.append("Stage 4, execution: put the targets within your reach on the goal, one at a time.")
        elif lead != me:
            lines.append(f"Stage 4, execution: no job from {lead} yet. Wait, and keep out of the others' way.")
        if self.make_way is not None and not self.jobs:
            lines.append(f"You were asked to make way at {self.make_way}: go to another furniture.")
        return "\n\n".join(lines)

    def book_text(self) -> str:
        """Who leads and, for the leader, the jobs out and the reports heard."""
        who = f"Leader: {self.leader}." if self.leader else "Leader: none yet."
        lines = [f"Convener: {self.convener()}. {who}"]
        if self.leader == self.robot:
            if self.task is not None:
                order = " (in this order)" if self.task.ordered else ""
                lines.append(
                    f"Targets{order}: {', '.join(self.task.targets)}; the finisher takes "
                    f"{', '.join(self.task.mine) or 'none'} itself."
                )
            out = [f"- {r}: {', '.join(j.call() for j in jobs)}" for r, jobs in self.book.items() if jobs]
            lines.append("Jobs given and not reported yet:\n" + ("\n".join(out) or "- none"))
            lines.append("Reports heard:\n" + ("\n".join(f"- {r}" for r in self.reports) or "- none"))
        return "\n".join(lines)


def _report(said: talk.Done | talk.Failed | talk.Status) -> str:
    if isinstance(said, talk.Done):
        found = f"; found {', '.join(said.found)}" if said.found else ""
        return f"{said.robot}: done {said.kind}({said.target}){found}"
    if isinstance(said, talk.Failed):
        return f"{said.robot}: failed {said.kind}({said.target}) ({said.code}): {said.reflection}"
    return f"{said.robot}: " + (f"working on {said.kind}({said.target})" if said.kind else "free")


@dataclass
class LLMLeaderPolicy:
    """One robot under the leader protocol, its every step one model call (see the module docstring)."""

    robot: str
    team: tuple[str, ...]
    client: LLMClient
    kinds: Mapping[str, str] = field(default_factory=dict)  # robot -> its kind, for the prompt
    structured: bool = False
    max_analysis: int = json_mode.MAX_ANALYSIS
    name: str = "leader-llm"
    stages: Stages = field(init=False)
    feedback: list[str] = field(default_factory=list)
    heard: list[str] = field(default_factory=list)
    unread: str | None = None  # why the last reply gave no command

    def __post_init__(self) -> None:
        self.stages = Stages(self.robot, self.team)
        self.name = f"leader-llm:{self.client.model}"

    async def aclose(self) -> None:
        """The episode is over: this robot's model client is closed, its connections with it."""
        await close_client(self.client)

    def prompt(self, obs: Observation) -> list[dict[str, str]]:
        """The chat of this step: the system text (who it is, the loop, the shapes), and its stage,
        what the team said, its status, scene graph, feedback and messages."""
        s = self.stages
        mates = [
            f"- {r}: {', '.join(signature(k) if k in CALLS else k for k in sk)}" for r, sk in obs.teammates.items()
        ]
        system = Template(_template("leader_system.txt")).safe_substitute(
            Robot=self.robot.capitalize(),
            kind=obs.status.kind,
            team=", ".join(f"{r} ({self.kinds[r].replace('_', ' ')})" if r in self.kinds else r for r in self.team),
            convener=s.convener(),
            skills="\n".join(f"- {signature(k)}: {MEANINGS[k]}" for k in obs.status.skills if k in MEANINGS),
            teammates="\n".join(mates) or "- nobody: you are on your own",
        )
        feedback = list(self.feedback)
        if self.unread is not None:
            feedback.append(f"- your last reply gave no command ({self.unread}); you waited")
        user = Template(_template("leader_user.txt")).safe_substitute(
            task=task_text(obs),
            step=str(obs.tick),
            stage=s.stage(obs),
            book=s.book_text(),
            status=robot_status(obs),
            scene_graph=scene_graph(obs),
            feedback="\n".join(feedback) or "- none yet",
            messages="\n".join(self.heard) or "- none yet",
        )
        if self.structured:
            user = user.rstrip("\n") + "\n" + json_mode.STRUCTURED_INSTRUCTIONS
        return [{"role": "system", "content": system}, {"role": "user", "content": user}]

    def _coordination(self) -> Coordination:
        """Whom this robot follows and its first job not reported yet, as it read them from the messages."""
        s = self.stages
        job = s.jobs[0].call() if s.jobs else None
        return Coordination(leader=s.leader, job=job, by=s.leader if job else None)

    async def decide(self, obs: Observation) -> Decision:
        self.stages.observe(obs)
        said = [f"- step {m.tick}, from {m.sender}: {m.content}" for m in obs.new_messages]
        self.heard = [*self.heard, *said][-HEARD:]
        messages = self.prompt(obs)
        prompt = prompt_text(messages)
        schema = json_mode.decision_schema(obs, max_analysis=self.max_analysis) if self.structured else None
        digest = json_mode.schema_hash(schema) if schema is not None else None
        try:
            done = await self.client.complete(messages, schema=schema)
        except LLMFatalError:
            raise
        except LLMError as exc:
            self.unread = f"the model did not answer: {exc}"[:300]
            return Decision(
                Wait(),
                prompt,
                parse_error=self.unread,
                failure=ReplyFailure.MODEL_UNREACHABLE,
                schema_hash=digest,
                coordination=self._coordination(),
            )
        error: str | None = None
        try:
            action: Action = json_mode.parse_structured(done.text)[0] if self.structured else parse_command(done.text)
            self.unread = None
        except ReplyFormatError as exc:
            action, error = Wait(), str(exc)[:300]
            self.unread = error
        return Decision(
            action,
            prompt,
            done.text,
            error,
            done.prompt_tokens,
            done.completion_tokens,
            done.latency,
            reasoning=done.reasoning,
            finish_reason=done.finish_reason,
            schema_hash=digest,
            failure=None if error is None else ReplyFailure.UNREADABLE,
            coordination=self._coordination(),
        )

    def record(self, result: ActionResult) -> None:
        if isinstance(result.action, Communicate) and result.outcome.succeeded:
            self.stages.sent(result.action)
        if isinstance(result.action, Navigate | Move) and result.outcome.succeeded:
            self.stages.make_way = None  # it went
        if result.action.skill == "wait" and result.outcome.succeeded:
            return
        verdict = "succeeded" if result.outcome.succeeded else f"FAILED ({result.outcome.code.value})"
        line = f"- step {result.tick}: {result.action.call()} {verdict}: {result.outcome.feedback}"
        self.feedback = [*self.feedback, line][-FEEDBACK:]


def build_leader(seating: Seating) -> Mapping[str, Policy]:
    """Each robot its own policy (they share nothing but messages): the LLM form's, each robot with
    its own client, when the seating names a model, else the heuristic form (leader.py)."""
    if seating.model is None:
        return build_heuristic(seating)
    from ..llm.model_spec import make_client  # here: the heuristic form needs no HTTP client

    options = dict(seating.client_options)
    return {
        r: LLMLeaderPolicy(
            r,
            seating.team.names,
            make_client(seating.model, seating.base_url, **options),
            kinds=seating.team.kinds,
            structured=seating.structured,
            max_analysis=json_mode.analysis_bound(options.get("max_tokens")),
        )
        for r in seating.robots
    }
