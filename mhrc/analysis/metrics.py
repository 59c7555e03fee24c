"""The one place that defines the metrics, computed from an episode's trace.

The paper's four (Succ, PS, TS, AS) and the extras a comparison needs. Per episode:

- success, placed / total, partial_success: the world's goal check at the end, as the
  `episode_done` event carries it (the trace holds no other ground truth of object poses).
- temporal_steps (TS): lockstep and sequential ticks executed, i.e. the number of `tick`
  events; an episode that fails runs to the horizon. The async schedule has no ticks: its TS is
  the makespan in steps, makespan / step_seconds rounded up (`episode_started` records
  step_seconds; its horizon is the same number of steps as a budget of simulated seconds).
- makespan: simulated seconds from the start to the end of the episode on the world's clock
  (`episode_done`); busy / idle per robot: the simulated seconds its actions took (their
  `started`..`ended`, clipped to the makespan) and the rest of the makespan; actions_per_robot:
  every action a robot completed, `wait` included.
- action_steps (AS): actions executed by all robots, `wait` excluded, failed ones included;
  also per robot. The paper does not define its AS beyond "action steps, wait excluded", so
  three readings are kept: `as` (summed over the robots), `as_per_robot` (that sum over the
  number of robots) and `active_ticks` (the steps in which any robot did a non-wait action; in
  the async schedule, the distinct `step_seconds` steps in which one began). The paper's AS is
  below its TS in all 21 rows of Tables I-II, often close to it (48.56 of 50 where episodes
  fail), which a sum over three robots cannot be and which the per-robot mean reaches only if
  every robot acts in nearly every step: `active_ticks` is the reading set beside the paper's
  AS (mhrc.eval.report), the other two are columns beside it.
- failed_actions by skill; messages (communicate actions that were delivered);
- llm_calls, prompt_tokens, completion_tokens: from the agents' `thought` events (an LLM step
  is a thought with a prompt, whether or not the model answered);
- the LLM failures that shaped the episode: parse_failures (replies that did not parse: a
  thought whose failure is unreadable or cut_off), llm_unreachable (steps lost to a
  model that stayed down after its retries: failure model_unreachable),
  rejected_actions (`action_ack` events with accepted false, and the rejections of malformed
  requests the recorder counted as `junk` lines);
- valid / invalid_code / invalid_reason: an episode that measured the machine, not the method,
  is invalid and left out of summaries; `invalid_code` (an `Invalid`) says why for programs,
  `invalid_reason` for people. `not_played`: it ended before any robot acted (no action
  executed, `wait` included; at tick 0, or because every agent left: reason `no_agents`), e.g. a
  loaded machine's agents let go before their first action; `model_unreachable`: every LLM
  step (at least one) found the model unreachable, so it measured the network;
- fidelity (`paper` or `aids:...`, from `episode_started`; `unrecorded` for traces older than
  the field) and horizon;
- noise (`on` or `off`) and noise_rates (the motion noise's chances and error scales), from
  `episode_started` (mhrc.core.fidelity.recorded_noise: a trace older than the field ran with
  the calibration, or with none under the exact_motion aid);
- wall_time (world's measure), lower_bound (world/bound.py, from `episode_started`).
- recovery (a scenario's events, `--events`; world/scenario.py): per `scenario_event` in the
  trace, in firing order, {index, kind, tick, applied, ticks_to_recover}. ticks_to_recover is the
  number of steps from the event to the first moment the team has one more target in place than
  it had when the event fired, i.e. until its progress resumes:
    - lockstep and sequential: an event of tick T fires when tick T opens, so the team had then
      the `placed` of tick T-1's `tick` event (0 before any); if tick t (t >= T) is the first
      whose `tick` event has more, ticks_to_recover = t + 1 - T (the ticks executed from the
      event through the one that placed it: 1 when the first tick after the event places one).
    - async: the event fires at T x step_seconds of simulated time; the targets in place are
      counted on the world's `snapshot` events (a target on its goal and not held, as `mhrc
      show` counts them; the targets and goals are `episode_done`'s, new ones included, so a
      target counts from the moment it joined). At the event the count is the last snapshot's
      before it; the first later snapshot with more gives the end of its action (`ended` of
      the action_result), and ticks_to_recover = ceil((ended - T x step_seconds) / step_seconds),
      steps as TS counts them. In an ordered task (make_sandwich) this counts every layer on
      the board, where the world counts only the correct prefix.
  None when progress never resumes before the episode ends, and for a skipped event (`applied`
  false: it changed nothing to recover from). recovery_ticks: the mean ticks_to_recover over
  the applied events that have one (None when none has); unrecovered: the applied events after
  which progress never resumed (both None in an episode without scenario events).

- team, team_digest, team_kinds: the team the episode ran (`episode_started`'s `team`: its name,
  mhrc.core.team.TeamSpec.digest() and each robot's kind in execution order; a trace older than the
  field ran the paper's team, mhrc.core.upgrade.paper_team);
- the team's work (mhrc.analysis.teamwork defines each): messages_per_robot, moves_per_robot (successful
  picks and places), communication_steps (communicate actions, beside the other action steps),
  redundant_navigations, redundant_picks and redundant_per_robot.

The means over episodes are an evaluation's (mhrc.eval.means).
"""

from __future__ import annotations

import math
import statistics
from collections import Counter
from collections.abc import Sequence
from enum import StrEnum
from typing import Any

from pydantic import BaseModel, StrictBool

from mhrc.analysis.teamwork import teamwork
from mhrc.analysis.values import Amount, Count, Name, Rate
from mhrc.core.protocol import (
    ActionAck,
    ActionResult,
    EpisodeDone,
    EpisodeStarted,
    RobotDetached,
    ScenarioEvent,
    Snapshot,
    Thought,
    TickClosed,
)
from mhrc.core.records import LineKind, TraceLine, messages
from mhrc.core.upgrade import UNRECORDED

__all__ = [
    "UNRECORDED",
    "EpisodeMetrics",
    "Invalid",
    "TraceError",
    "from_trace",
    "junk_rejections",
    "recovery_of",
]


class TraceError(ValueError):
    """A trace that lacks what the metrics need (an episode that never finished)."""


class Invalid(StrEnum):
    """Why an episode is left out of every score (a row's `invalid_code`; the module docstring)."""

    NOT_PLAYED = "not_played"  # it ended before any robot acted
    MODEL_UNREACHABLE = "model_unreachable"  # every LLM step found the model unreachable


class EpisodeMetrics(BaseModel):
    """One episode's metrics (the module docstring defines each), with their ranges
    (mhrc.analysis.values): the one model of them, which an evaluation row holds as it is
    (mhrc.eval.records.EvalRow.metrics). A field a row was written without is not set
    (`model_fields_set`): what it meant then is its default, or, for the team's work, unknown."""

    task: Name
    scene: Name
    seed: Count
    n_objects: Count
    robots: list[str]
    reason: str
    success: StrictBool
    placed: Count
    total: Count
    partial_success: Rate
    temporal_steps: Count
    action_steps: Count
    action_steps_per_robot: dict[str, Count]
    failed_actions: dict[str, Count] = {}
    messages: Count = 0
    llm_calls: Count = 0
    prompt_tokens: Count = 0
    completion_tokens: Count = 0
    wall_time: Amount = 0.0
    lower_bound: Count | None = None
    parse_failures: Count = 0
    llm_unreachable: Count = 0
    rejected_actions: Count = 0
    valid: StrictBool = True
    invalid_reason: str | None = None
    invalid_code: Invalid | None = None
    fidelity: str = UNRECORDED
    noise: str = "on"  # the motion noise: on (the calibration) or off (--noise off, or the exact_motion aid)
    noise_rates: dict[str, Amount] = {}  # its chances and error scales (mhrc.core.protocol.MotionNoise)
    horizon: Count | None = None
    scheduler: str = "lockstep"
    makespan: Amount = 0.0
    busy: dict[str, Amount] = {}
    idle: dict[str, Amount] = {}
    actions_per_robot: dict[str, Count] = {}
    active_ticks: Count | None = None  # steps with a non-wait action of any robot (None: rows written before the field)
    recovery: list[dict[str, Any]] = []  # per scenario event (module docstring)
    recovery_ticks: Amount | None = None  # mean ticks_to_recover of the applied events that recovered
    unrecovered: Count | None = None  # applied events after which progress never resumed (None: no scenario events)
    team: Name = "paper"  # the team's name, digest and robots' kinds (module docstring)
    team_digest: str = ""
    team_kinds: dict[str, str] = {}
    messages_per_robot: dict[str, Count] = {}  # mhrc.analysis.teamwork defines these; not set: unknown
    moves_per_robot: dict[str, Count] = {}
    communication_steps: Count = 0
    redundant_navigations: Count = 0
    redundant_picks: Count = 0
    redundant_per_robot: dict[str, Count] = {}

    def as_dict(self) -> dict[str, Any]:
        return self.model_dump()


def junk_rejections(lines: Sequence[TraceLine]) -> int:
    """Rejections of malformed requests, which the recorder counts instead of copying (`junk` lines)."""
    return sum(line.junk.count for line in lines if line.junk is not None and line.key.endswith("/action/ack"))


def from_trace(lines: Sequence[TraceLine]) -> EpisodeMetrics:
    """The metrics of one episode from its trace (`mhrc.core.records.read_records`)."""
    started, done = messages(lines, EpisodeStarted), messages(lines, EpisodeDone)
    if not started or not done:
        raise TraceError("the trace has no episode_started or no episode_done event: the episode did not finish")
    s, d = started[0], done[-1]
    world = d.metrics
    results = messages(lines, ActionResult)
    acting = [r for r in results if r.action.skill != "wait"]
    per_robot = Counter(r.robot for r in acting)
    failed = Counter(r.action.skill for r in results if not r.outcome.succeeded)
    every_thought = [line for line in lines if isinstance(line.msg, Thought) and line.kind is LineKind.PUT]
    thoughts = [line.msg for line in every_thought if isinstance(line.msg, Thought) and line.msg.prompt is not None]
    failures = [line.failure for line in every_thought if line.failure is not None]
    unreachable = sum(1 for f in failures if not f.unparsed)
    scheduler = s.scheduler
    makespan = world.makespan
    if scheduler == "async":
        temporal_steps = math.ceil(round(makespan / float(s.step_seconds or 0.0), 9))
    else:
        temporal_steps = len(messages(lines, TickClosed))
    busy: dict[str, float] = {}
    for r in results:
        if r.started is not None and r.ended is not None:
            busy[r.robot] = busy.get(r.robot, 0.0) + max(0.0, min(r.ended, makespan) - r.started)
    everything = Counter(r.robot for r in results)
    if scheduler == "async":
        step = float(s.step_seconds or 0.0)
        active = {math.floor(round((r.started or 0.0) / step, 9)) for r in acting}
    else:
        active = {r.tick for r in acting}
    recovery = recovery_of(lines, scheduler, s.step_seconds or 0.0, d)
    invalid, why = _invalidity(lines, d, temporal_steps, results, len(thoughts), unreachable)
    recovered = [int(e["ticks_to_recover"]) for e in recovery if e["applied"] and e["ticks_to_recover"] is not None]
    team = s.team
    if team is None:  # read_records gives every episode_started one (mhrc.core.upgrade): this line was not read so
        raise TraceError("the trace's episode_started names no team: read traces with mhrc.core.records")
    work = teamwork(results, s.robots)
    return EpisodeMetrics(
        task=s.task,
        scene=s.scene,
        seed=s.seed,
        n_objects=s.n_objects,
        robots=list(s.robots),
        reason=d.reason,
        success=world.success,
        placed=world.placed,
        total=world.total,
        partial_success=world.partial_success,
        temporal_steps=temporal_steps,
        action_steps=len(acting),
        action_steps_per_robot={r: per_robot.get(r, 0) for r in s.robots},
        failed_actions=dict(sorted(failed.items())),
        messages=sum(1 for r in results if r.action.skill == "communicate" and r.outcome.succeeded),
        llm_calls=len(thoughts),
        prompt_tokens=sum(t.prompt_tokens for t in thoughts),
        completion_tokens=sum(t.completion_tokens for t in thoughts),
        wall_time=world.wall_time,
        lower_bound=s.lower_bound,
        parse_failures=len(failures) - unreachable,
        llm_unreachable=unreachable,
        rejected_actions=sum(1 for a in messages(lines, ActionAck) if a.accepted is False) + junk_rejections(lines),
        valid=invalid is None,
        invalid_reason=why,
        invalid_code=invalid,
        fidelity=s.fidelity or UNRECORDED,
        noise=s.noise.setting,
        noise_rates=s.noise.model_dump(exclude={"setting"}),
        horizon=s.horizon,
        scheduler=scheduler,
        makespan=round(makespan, 3),
        busy={r: round(busy.get(r, 0.0), 3) for r in s.robots},
        idle={r: round(max(0.0, makespan - busy.get(r, 0.0)), 3) for r in s.robots},
        actions_per_robot={r: everything.get(r, 0) for r in s.robots},
        active_ticks=len(active),
        recovery=recovery,
        recovery_ticks=round(statistics.fmean(recovered), 3) if recovered else None,
        unrecovered=sum(1 for e in recovery if e["applied"] and e["ticks_to_recover"] is None) if recovery else None,
        team=team.name,
        team_digest=team.digest,
        team_kinds=dict(team.kinds),
        messages_per_robot=work.messages_per_robot,
        moves_per_robot=work.moves_per_robot,
        communication_steps=work.communication_steps,
        redundant_navigations=work.redundant_navigations,
        redundant_picks=work.redundant_picks,
        redundant_per_robot=work.redundant_per_robot,
    )


def _invalidity(
    lines: Sequence[TraceLine],
    done: EpisodeDone,
    temporal_steps: int,
    results: list[ActionResult],
    llm_steps: int,
    unreachable: int,
) -> tuple[Invalid | None, str | None]:
    """Why the episode measured the machine rather than the method (the code and a sentence), or (None, None)."""
    reason = done.reason
    if not results and not done.metrics.success and (temporal_steps == 0 or reason == "no_agents"):
        left = sorted({e.robot for e in messages(lines, RobotDetached)})
        why = f"it ended ({reason}) at step {temporal_steps} before any robot acted" + (
            f"; detached: {', '.join(left)} (the trace says why)" if left else ""
        )
        return Invalid.NOT_PLAYED, why
    if llm_steps and unreachable >= llm_steps:
        return Invalid.MODEL_UNREACHABLE, f"the model was unreachable for all {llm_steps} LLM steps"
    return None, None


def recovery_of(
    lines: Sequence[TraceLine], scheduler: str, step_seconds: float, done: EpisodeDone
) -> list[dict[str, Any]]:
    """Per scenario event of the trace, the steps until the team's progress resumes (module docstring)."""
    events = messages(lines, ScenarioEvent)
    if not events:
        return []
    if scheduler == "async":
        since = _async_progress(lines, step_seconds, done)
    else:
        placed = {t.tick: t.placed for t in messages(lines, TickClosed)}
        since = {}
        for ev in events:
            tick = ev.tick
            before = max((t for t in placed if t < tick), default=None)
            at_event = placed[before] if before is not None else 0
            later = [t for t in sorted(placed) if t >= tick and placed[t] > at_event]
            since[ev.index] = later[0] + 1 - tick if later else None
    return [
        {
            "index": ev.index,
            "kind": ev.event,
            "tick": ev.tick,
            "applied": ev.applied,
            "ticks_to_recover": since.get(ev.index) if ev.applied else None,
        }
        for ev in events
    ]


def _async_progress(lines: Sequence[TraceLine], step_seconds: float, done: EpisodeDone) -> dict[int, int | None]:
    """Async: scenario event index -> ceil((end of the first action after it that put one more target
    in place - its firing time) / step_seconds), None if none did; counted on the snapshots."""
    goals = dict(done.goals)
    targets = list(done.targets or goals)
    ended = {r.goal_id: r.ended for r in messages(lines, ActionResult) if r.ended is not None}
    end_of_episode = done.metrics.makespan
    count = 0
    waiting: dict[int, tuple[float, int]] = {}  # event index -> (its firing time, the count then)
    out: dict[int, int | None] = {}
    for msg in messages(lines, BaseModel):
        if isinstance(msg, ScenarioEvent):
            waiting[msg.index] = (msg.tick * step_seconds, count)
            out[msg.index] = None
        elif isinstance(msg, Snapshot):
            objects = msg.objects
            count = sum(1 for t in targets if t in objects and objects[t].on == goals.get(t) and not objects[t].held_by)
            at = max((ended.get(g, end_of_episode) for g in msg.goals), default=end_of_episode)
            for index, (fired, then) in list(waiting.items()):
                if count > then:
                    out[index] = max(0, math.ceil(round((at - fired) / step_seconds, 9)))
                    del waiting[index]
    return out
