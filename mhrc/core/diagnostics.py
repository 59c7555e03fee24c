"""Failure diagnostics: why an episode went the way it did, counted from its trace alone.

`mhrc.core.metrics` says how well an episode went; this module says what went wrong, per episode
(`diagnose`) and over episodes (`summarize_diagnostics`). Every count comes from the bus
messages of one trace (`mhrc.core.trace.read_trace`); nothing is re-simulated. Definitions:

- parse_failures: replies that did not parse into one command (a `thought` whose parse_error
  is set and does not start with LLM_ERROR_PREFIX); llm_unreachable: steps lost to a model
  that stayed down (parse_error starting with LLM_ERROR_PREFIX). Both make the robot wait.
- hallucinations: executed commands (`action_result`) naming an object or furniture the robot
  had no source for. The names checked are navigate/open's target, pick's obj, place's obj
  and location. The observation the robot planned on is the one delivered to it (in an
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
- messages_sent: communicate actions that succeeded (as `mhrc.core.metrics`'s messages);
  messages_read: distinct messages delivered into their receiver's observation new_messages
  (a message sent in the last tick may never be).
- steps_above_bound: TS (`mhrc.core.metrics.from_trace`'s temporal_steps, as the row's TS) minus the
  episode's lower bound (`episode_started`); None when either is unknown. Negative only when the
  horizon is below the bound (the episode was cut off before it could finish).

Episode rows (`episodes.jsonl`) carry these as flat columns prefixed `diag_` (`columns()`);
rows written before diagnostics existed lack them, and summaries treat them as unknown.
"""

from __future__ import annotations

import statistics
from collections import Counter, defaultdict
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from mhrc.core.metrics import TraceError, from_trace
from mhrc.core.protocol import EPISODE_OVER, LLM_ERROR_PREFIX, OutcomeCode

PREFIX = "diag_"
REJECT_KINDS = ("stale_tick", "busy", "out_of_turn", "episode_over", "malformed", "not_attached", "other")
# The world's codes for a name it does not know (the fallback when the planning observation is not in the trace)
UNKNOWN_NAME_CODES = (OutcomeCode.TARGET_UNKNOWN.value, OutcomeCode.OBJECT_UNKNOWN.value, OutcomeCode.LOCATION_UNKNOWN.value)
UNKNOWN_NAME_FEEDBACK = "There is no "  # world/feedback.py: unknown_furniture, object_unknown, location_unknown
NAMED_ARGS = {"navigate": ("target",), "open": ("target",), "pick": ("obj",), "place": ("obj", "location")}


@dataclass
class Diagnostics:
    """One episode's failure diagnostics (definitions: the module docstring)."""

    llm_steps: int = 0
    parse_failures: int = 0
    llm_unreachable: int = 0
    hallucinations: int = 0
    hallucinated_names: dict[str, int] = field(default_factory=dict)
    not_capable: int = 0
    rejected: int = 0
    rejected_by_reason: dict[str, int] = field(default_factory=dict)
    failed: int = 0
    failed_by_code: dict[str, int] = field(default_factory=dict)
    failed_by_skill: dict[str, dict[str, int]] = field(default_factory=dict)
    repeated_failures: int = 0
    waits: int = 0
    waits_with_pending: int = 0
    messages_sent: int = 0
    messages_read: int = 0
    steps_above_bound: int | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def columns(self) -> dict[str, Any]:
        """The flat, prefixed columns of an episodes.jsonl row."""
        return {PREFIX + k: v for k, v in self.as_dict().items()}


COUNTS = tuple(f.name for f in fields(Diagnostics) if f.type in ("int", "int | None"))
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
    "stale_tick": "stale_tick", "tick_taken": "busy", "busy": "busy", "duplicate_goal": "busy", "not_your_turn": "out_of_turn",
    "episode_over": "episode_over", "malformed": "malformed", "not_attached": "not_attached", "other_agent": "not_attached",
    "wrong_key": "not_attached", "no_such_robot": "not_attached",
}  # fmt: skip


def reject_kind(reason: str, code: object = None) -> str:
    """The kind of a rejection: from the `action_ack`'s `code` (mhrc.core.protocol.RejectCode); a
    trace recorded before acks had one is read from the reason's text."""
    if isinstance(code, str) and code in KIND_OF_CODE:
        return KIND_OF_CODE[code]
    r = reason.lower()
    if reason == EPISODE_OVER:
        return "episode_over"
    if r.startswith("malformed"):
        return "malformed"
    if "the request is for tick" in r:
        return "stale_tick"
    if "already submitted" in r or "still busy" in r:
        return "busy"
    if "'s turn" in r:
        return "out_of_turn"
    if "not attached" in r or "attached to another agent" in r or "sent on the key of" in r or "there is no robot" in r:
        return "not_attached"
    return "other"


def _msgs(rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r["msg"] for r in rows if r.get("kind") == "put" and isinstance(r.get("msg"), dict)]


def _known_names(obs: dict[str, Any]) -> set[str]:
    names = {f["name"] for f in obs.get("furniture", [])} | {o["name"] for o in obs.get("objects", [])}
    holding = (obs.get("status") or {}).get("holding")
    goals = obs.get("goals") or {}
    return names | ({holding} if holding else set()) | set(obs.get("targets") or []) | set(goals) | set(goals.values())


def _world_says_unknown(outcome: dict[str, Any]) -> bool:
    return outcome.get("code") in UNKNOWN_NAME_CODES and str(outcome.get("feedback", "")).startswith(UNKNOWN_NAME_FEEDBACK)


def diagnose(rows: list[dict[str, Any]]) -> Diagnostics:
    """The failure diagnostics of one episode from its trace rows (`mhrc.core.trace.read_trace`)."""
    msgs = _msgs(rows)
    d = Diagnostics()
    # what each robot planned on: (robot, tick) -> the last observation of that tick, and every message it delivered
    planned: dict[tuple[str, int], dict[str, Any]] = {}
    delivered: dict[tuple[str, int], list[dict[str, Any]]] = defaultdict(list)
    read: set[tuple[str, str, int, str]] = set()
    for m in msgs:
        if m.get("kind") in ("action_result", "turn") and isinstance(m.get("observation"), dict):
            obs = m["observation"]
            key = (str(obs.get("robot", m.get("robot"))), int(obs.get("tick", 0)))
            planned[key] = obs
            for note in obs.get("new_messages") or []:
                delivered[key].append(note)
                read.add((note.get("sender", ""), note.get("to", ""), int(note.get("tick", 0)), note.get("content", "")))
    errors: dict[tuple[str, int], str] = {}
    for m in msgs:
        if m.get("kind") != "thought":
            continue
        if m.get("prompt") is not None:
            d.llm_steps += 1
        if m.get("parse_error"):
            errors[(m["robot"], int(m["tick"]))] = str(m["parse_error"])
            if str(m["parse_error"]).startswith(LLM_ERROR_PREFIX):
                d.llm_unreachable += 1
            else:
                d.parse_failures += 1

    reasons: Counter[str] = Counter()
    for m in msgs:
        if m.get("kind") == "action_ack" and m.get("accepted") is False:
            reasons[reject_kind(str(m.get("reason", "")), m.get("code"))] += 1
    for row in rows:  # a flood of junk or of rejections, counted by the recorder (mhrc.core.trace)
        if row.get("kind") == "junk" and str(row.get("key", "")).endswith("/action/ack") and isinstance(row.get("msg"), dict):
            junk = row["msg"]
            reasons[reject_kind(str(junk.get("reason", "")).removeprefix("rejected: "), junk.get("code"))] += int(junk.get("count", 0))
    d.rejected, d.rejected_by_reason = sum(reasons.values()), dict(sorted(reasons.items()))

    names: Counter[str] = Counter()
    by_code: Counter[str] = Counter()
    by_skill: dict[str, Counter[str]] = defaultdict(Counter)
    last: dict[str, tuple[dict[str, Any], bool]] = {}  # robot -> (its previous action, whether it failed)
    pending: dict[str, set[str]] = defaultdict(set)  # robot -> teammates whose messages it has not acted on
    for m in msgs:
        if m.get("kind") != "action_result":
            continue
        robot, tick, action, outcome = str(m["robot"]), int(m["tick"]), m["action"], m["outcome"]
        skill, ok = str(action.get("skill")), bool(outcome.get("succeeded"))
        obs = planned.get((robot, tick))
        pending[robot] |= {n.get("sender", "") for n in delivered.get((robot, tick), []) if n.get("sender") != robot}
        # hallucinations: names against the scene graph planned on, else the world's verdict
        args = [str(action[a]) for a in NAMED_ARGS.get(skill, ()) if action.get(a) is not None]
        if obs is not None:
            unknown = [n for n in args if n not in _known_names(obs)]
        else:
            unknown = args[:1] if _world_says_unknown(outcome) and args else []
            if unknown and skill == "place":  # which of the two names the world did not know
                unknown = [str(action["location" if outcome["code"] == OutcomeCode.LOCATION_UNKNOWN.value else "obj"])]
        if unknown:
            d.hallucinations += 1
            names.update(unknown)
        if outcome.get("code") == OutcomeCode.NOT_CAPABLE.value:
            d.not_capable += 1
        if not ok:
            code = str(outcome.get("code"))
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
    started = [m for m in msgs if m.get("kind") == "episode_started"]
    bound = started[0].get("lower_bound") if started else None
    if bound is not None:
        try:
            d.steps_above_bound = from_trace(rows).temporal_steps - int(bound)
        except TraceError:
            d.steps_above_bound = None
    return d


def row_diagnostics(row: dict[str, Any]) -> dict[str, Any] | None:
    """The diagnostics of an episodes.jsonl row (unprefixed), or None for a row written before they existed."""
    if PREFIX + "hallucinations" not in row:
        return None
    return {k[len(PREFIX):]: v for k, v in row.items() if k.startswith(PREFIX)}


def summarize_diagnostics(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Means and totals over episode rows. Rows without diagnostics (written before they
    existed) are unknown, not zero: they are left out and counted in `unknown`; with none
    known, every mean and total is None."""
    known = [d for r in rows if (d := row_diagnostics(r)) is not None]
    out: dict[str, Any] = {"episodes": len(rows), "known": len(known), "unknown": len(rows) - len(known)}
    means: dict[str, float | None] = {}
    totals: dict[str, int | None] = {}
    for name in COUNTS:
        values = [d[name] for d in known if d.get(name) is not None]
        means[name] = round(statistics.fmean(values), 3) if values else None
        totals[name] = int(sum(values)) if values else None
    out["mean"], out["total"] = means, totals
    for name in BREAKDOWNS:
        c: Counter[str] = Counter()
        for d in known:
            c.update(d.get(name) or {})
        out[name] = dict(sorted(c.items())) if known else None
    return out
