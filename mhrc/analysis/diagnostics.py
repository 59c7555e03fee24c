"""Failure diagnostics: why an episode went the way it did, counted from its trace alone.

`mhrc.analysis.metrics` says how well an episode went; this module says what went wrong in one
episode (`diagnose`; the means over episodes are an evaluation's, mhrc.eval.means). Every count comes from the bus
messages of one trace (`mhrc.core.records.read_records`); nothing is re-simulated. Definitions:

- parse_failures: replies that did not parse into one command (a `thought` whose failure,
  mhrc.core.records.ReplyFailure, is unreadable or cut_off); llm_unreachable: steps lost to a
  model that stayed down (failure model_unreachable). Both make the robot wait.
- hallucinations: executed commands (`action_result`) naming an object or furniture the robot
  had no source for. The names checked are the arguments its call form declares as naming
  furniture or an object (mhrc.core.protocol.actions, ArgKind.names_a_thing): navigate/open's
  target, pick's obj, place's obj and location. The observation the robot planned on is the one delivered to it (in an
  `action_result` or a sequential `turn`) whose tick is the action's tick; a name is known if
  that scene graph holds it (furniture, objects, what the robot holds) or the task names it to
  that robot (Bob's targets and goals). When that observation is not in the trace (a robot's
  first step plans on its attach reply, which is not a bus message the recorder sees), the
  world's verdict decides instead: outcome target_unknown, object_unknown or location_unknown
  with the world's "There is no ..." feedback (not "held by another robot", not "not a
  surface"). A command counts once however many of its names are unknown; hallucinated_names
  counts each unknown name. Rejected requests never executed and are not checked.
- not_capable: executed commands outside the robot's capabilities (outcome not_capable: a
  skill it lacks, or a non-finisher placing on the task's fixtures).
- rejected: `action_ack` with accepted false, by kind of reason (REJECT_KINDS): stale_tick
  (planned on an old tick), busy (an action already submitted or still running, or a goal id
  sent before), out_of_turn (sequential: another robot's turn), episode_over, malformed,
  not_attached, other.
- failed: executed actions whose outcome did not succeed, by outcome code and by skill/code.
- repeated_failures: a failed action whose robot's previous executed action was the same call
  (same skill and arguments) and failed too; a third identical failure in a row counts again.
- waits, waits_with_pending: waits the robot chose (not forced by an unparsed or lost reply),
  and those among them made while a teammate's message was pending. A message is pending from
  the observation that delivered it (new_messages of an observation the robot planned on)
  until the robot does anything but wait (acting on it or replying). The trace cannot tell a
  request from a report, so every teammate message counts.
- messages_sent: communicate actions that succeeded (as `mhrc.analysis.metrics`'s messages);
  messages_read: distinct messages delivered into their receiver's observation new_messages
  (a message sent in the last tick may never be).
- steps_above_bound: TS (`mhrc.analysis.metrics.from_trace`'s temporal_steps, as the row's TS) minus the
  episode's lower bound (`episode_started`); None when either is unknown, and when the horizon
  is below the bound (the episode was cut off before it could finish: there is no excess to tell).

An evaluation row holds them as its `diagnostics` (episodes.jsonl: flat columns prefixed `diag_`,
mhrc.eval.records); rows written before diagnostics existed lack them, and summaries treat them as unknown.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Sequence
from typing import Any, get_origin

from pydantic import BaseModel

from mhrc.analysis.metrics import EpisodeMetrics, TraceError, from_trace
from mhrc.analysis.values import Count
from mhrc.core.protocol import (
    Action,
    ActionAck,
    ActionResult,
    EpisodeStarted,
    Observation,
    OutcomeCode,
    Place,
    RejectCode,
    RobotMessage,
    SkillOutcome,
    Thought,
    Turn,
)
from mhrc.core.records import LineKind, TraceLine, messages
from mhrc.core.upgrade import legacy_reject_code

REJECT_KINDS = ("stale_tick", "busy", "out_of_turn", "episode_over", "malformed", "not_attached", "other")
# The world's codes for a name it does not know (the fallback when the planning observation is not in the trace)
UNKNOWN_NAME_CODES = (
    OutcomeCode.TARGET_UNKNOWN.value,
    OutcomeCode.OBJECT_UNKNOWN.value,
    OutcomeCode.LOCATION_UNKNOWN.value,
)
UNKNOWN_NAME_FEEDBACK = "There is no "  # world/feedback.py: unknown_furniture, object_unknown, location_unknown


def named_args(action: Action) -> list[str]:
    """The names of furniture or objects `action` gives, in its call's order (its declared call form)."""
    return [str(getattr(action, a.field)) for a in action.ARGS if a.kind.names_a_thing]


class Diagnostics(BaseModel):
    """One episode's failure diagnostics (definitions: the module docstring), with their ranges
    (mhrc.analysis.values); an evaluation row holds it as it is (mhrc.eval.records.EvalRow.diagnostics)."""

    llm_steps: Count = 0
    parse_failures: Count = 0
    llm_unreachable: Count = 0
    hallucinations: Count = 0
    hallucinated_names: dict[str, Count] = {}
    not_capable: Count = 0
    rejected: Count = 0
    rejected_by_reason: dict[str, Count] = {}
    failed: Count = 0
    failed_by_code: dict[str, Count] = {}
    failed_by_skill: dict[str, dict[str, Count]] = {}
    repeated_failures: Count = 0
    waits: Count = 0
    waits_with_pending: Count = 0
    messages_sent: Count = 0
    messages_read: Count = 0
    steps_above_bound: Count | None = None

    def as_dict(self) -> dict[str, Any]:
        return self.model_dump()


COUNTS = tuple(name for name, f in Diagnostics.model_fields.items() if get_origin(f.annotation) is not dict)
BREAKDOWNS = ("hallucinated_names", "rejected_by_reason", "failed_by_code")

# What people read for each key, in every report (the episode report's failure panel, the
# evaluation page's plots): the Diagnostics fields, then the REJECT_KINDS. Outcome codes and
# anything else unlisted read as the key with spaces (`label`).
LABELS: dict[str, str] = {
    "llm_steps": "LLM steps",
    "parse_failures": "unparsed replies",
    "llm_unreachable": "steps lost to an unreachable model",
    "hallucinations": "hallucinations",
    "hallucinated_names": "hallucinated names",
    "not_capable": "not capable",
    "rejected": "rejected requests",
    "rejected_by_reason": "rejected requests, by reason",
    "failed": "failed actions",
    "failed_by_code": "failed actions, by outcome",
    "failed_by_skill": "failed actions, by skill and outcome",
    "repeated_failures": "repeated failures",
    "waits": "waits chosen",
    "waits_with_pending": "waits with a message pending",
    "messages_sent": "messages sent",
    "messages_read": "messages read",
    "steps_above_bound": "steps above the TS lower bound",
    "stale_tick": "planned on an old tick",
    "busy": "robot still busy",
    "out_of_turn": "out of turn",
    "episode_over": "episode over",
    "malformed": "malformed",
    "not_attached": "not attached",
    "other": "other",
}


def label(key: str) -> str:
    """The human label of a diagnostics key, a rejection kind or an outcome code."""
    return LABELS.get(key, key.replace("_", " "))


KIND_OF_CODE = {  # RejectCode -> the kind diagnostics count it under
    "stale_tick": "stale_tick",
    "tick_taken": "busy",
    "busy": "busy",
    "duplicate_goal": "busy",
    "not_your_turn": "out_of_turn",
    "episode_over": "episode_over",
    "malformed": "malformed",
    "not_attached": "not_attached",
    "other_agent": "not_attached",
    "wrong_key": "not_attached",
    "no_such_robot": "not_attached",
}


def kind_of(code: RejectCode | None) -> str:
    """The kind diagnostics count a rejection under, from its code (None: a reason no code covers)."""
    return KIND_OF_CODE[code.value] if code is not None else "other"


def reject_kind(reason: str, code: object = None) -> str:
    """The kind of a rejection: from its code (mhrc.core.protocol.RejectCode); a rejection recorded
    before acks had one, from the reason's text (mhrc.core.upgrade.legacy_reject_code)."""
    if isinstance(code, str) and code in KIND_OF_CODE:
        return KIND_OF_CODE[code]
    return kind_of(legacy_reject_code(reason))


def _known_names(obs: Observation) -> set[str]:
    names = {f.name for f in obs.furniture} | {o.name for o in obs.objects}
    holding = obs.status.holding
    return names | ({holding} if holding else set()) | set(obs.targets) | set(obs.goals) | set(obs.goals.values())


def _world_says_unknown(outcome: SkillOutcome) -> bool:
    return outcome.code.value in UNKNOWN_NAME_CODES and outcome.feedback.startswith(UNKNOWN_NAME_FEEDBACK)


def diagnose(lines: Sequence[TraceLine], metrics: EpisodeMetrics | None = None) -> Diagnostics:
    """The failure diagnostics of one episode from its trace (`mhrc.core.records.read_records`); `metrics`: the
    trace's metrics when the caller has them already (computed from it otherwise)."""
    d = Diagnostics()
    # what each robot planned on: (robot, tick) -> the last observation of that tick, and every message it delivered
    planned: dict[tuple[str, int], Observation] = {}
    delivered: dict[tuple[str, int], list[RobotMessage]] = defaultdict(list)
    read: set[tuple[str, str, int, str]] = set()
    for m in messages(lines, BaseModel):
        if isinstance(m, (ActionResult, Turn)):
            obs = m.observation
            key = (obs.robot, obs.tick)
            planned[key] = obs
            for note in obs.new_messages:
                delivered[key].append(note)
                read.add((note.sender, note.to, note.tick, note.content))
    errors: set[tuple[str, int]] = set()  # the steps whose reply gave no action
    for line in lines:
        if line.kind is not LineKind.PUT or not isinstance(line.msg, Thought):
            continue
        if line.msg.prompt is not None:
            d.llm_steps += 1
        if line.failure is not None:
            errors.add((line.msg.robot, line.msg.tick))
            if line.failure.unparsed:
                d.parse_failures += 1
            else:
                d.llm_unreachable += 1

    reasons: Counter[str] = Counter()
    for ack in messages(lines, ActionAck):
        if ack.accepted is False:
            reasons[kind_of(ack.code)] += 1
    for line in lines:  # a flood of junk or of rejections, counted by the recorder (mhrc.core.trace)
        if line.junk is not None and line.key.endswith("/action/ack"):  # the world's codes (never NotCopied)
            reasons[kind_of(line.junk.code if isinstance(line.junk.code, RejectCode) else None)] += line.junk.count
    d.rejected, d.rejected_by_reason = sum(reasons.values()), dict(sorted(reasons.items()))

    names: Counter[str] = Counter()
    by_code: Counter[str] = Counter()
    by_skill: dict[str, Counter[str]] = defaultdict(Counter)
    last: dict[str, tuple[Action, bool]] = {}  # robot -> (its previous action, whether it failed)
    pending: dict[str, set[str]] = defaultdict(set)  # robot -> teammates whose messages it has not acted on
    for m in messages(lines, ActionResult):
        robot, tick, action, outcome = m.robot, m.tick, m.action, m.outcome
        skill, ok = action.skill, outcome.succeeded
        seen = planned.get((robot, tick))
        pending[robot] |= {n.sender for n in delivered.get((robot, tick), []) if n.sender != robot}
        # hallucinations: names against the scene graph planned on, else the world's verdict
        args = named_args(action)
        if seen is not None:
            unknown = [n for n in args if n not in _known_names(seen)]
        else:
            unknown = args[:1] if _world_says_unknown(outcome) and args else []
            if unknown and isinstance(action, Place):  # which of the two names the world did not know
                unknown = [action.location if outcome.code is OutcomeCode.LOCATION_UNKNOWN else action.obj]
        if unknown:
            d.hallucinations += 1
            names.update(unknown)
        if outcome.code is OutcomeCode.NOT_CAPABLE:
            d.not_capable += 1
        if not ok:
            code = outcome.code.value
            by_code[code] += 1
            by_skill[skill][code] += 1
            prev = last.get(robot)
            if prev is not None and prev[1] and prev[0] == action:
                d.repeated_failures += 1
        last[robot] = (action, not ok)
        if skill == "wait":
            if (robot, tick) not in errors:  # a wait forced by an unparsed or lost reply is no choice
                d.waits += 1
                d.waits_with_pending += bool(pending[robot])
        else:
            pending[robot].clear()
        if skill == "communicate" and ok:
            d.messages_sent += 1

    d.hallucinated_names = dict(sorted(names.items()))
    d.failed, d.failed_by_code = sum(by_code.values()), dict(sorted(by_code.items()))
    d.failed_by_skill = {s: dict(sorted(c.items())) for s, c in sorted(by_skill.items())}
    d.messages_read = len(read)
    started = messages(lines, EpisodeStarted)
    bound = started[0].lower_bound if started else None
    if bound is not None:
        try:
            excess = (metrics or from_trace(lines)).temporal_steps - bound
        except TraceError:
            excess = None
        d.steps_above_bound = excess if excess is not None and excess >= 0 else None  # below: cut off, not fast
    return Diagnostics.model_validate(d.model_dump())  # every field set: a row writes each of them
