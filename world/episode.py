"""One episode's own rules, apart from any bus: how a batch of actions runs (skills in the simulator,
`communicate` through the mailroom, a crashing skill a failure), what the world counts for the
paper's metrics, and the episode's first and last events.

The world service (service.py) puts this on the bus, from a worker thread under its simulator
lock; the in-process environment (mhrc.env) calls it directly. Both drive the same schedulers
(schedulers/) through it, so an episode runs, answers and scores the same either way.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from mhrc.core.fidelity import label as fidelity_label
from mhrc.core.logs import get_logger
from mhrc.core.protocol import (
    ActionRequest,
    Communicate,
    EpisodeDone,
    EpisodeStarted,
    Message,
    Metrics,
    Observation,
    OutcomeCode,
    SkillOutcome,
    Snapshot,
    TeamRecord,
    Wait,
)
from mhrc.core.protocol.events import DEFAULT_PROTOCOL

from .mail import Mailroom
from .schedulers import Executed, Scheduler, TaskResultLike
from .service_config import SimLike

if TYPE_CHECKING:
    from structlog.typing import FilteringBoundLogger

log = get_logger("mhrc.world")


@dataclass
class Tally:
    """What the world counts for the metrics as actions execute."""

    actions: Counter[str] = field(default_factory=Counter)  # robot -> actions other than wait
    failed: Counter[str] = field(default_factory=Counter)  # skill -> failed actions
    messages: int = 0
    sim_time: float = 0.0


class EpisodeCore:
    """The simulator of one episode with its mailroom, its tally and its latest evaluation."""

    def __init__(self, sim: SimLike, run: str, horizon: int, logger: FilteringBoundLogger | None = None) -> None:
        self.sim = sim
        self.run = run
        self.horizon = horizon
        self.mail = Mailroom(sim.robots, sim.message)  # the robots' messages, held until delivered
        self.tally = Tally()
        self.bound = sim.lower_bound()
        self.evaluation: TaskResultLike = sim.evaluate()
        self.last_results: dict[str, str] = {}  # robot -> goal id of the last result released to it
        self._log = logger or log.bind(run=run)

    # ------------------------------------------------------------------ the simulator's side (its thread)
    def execute_batch(
        self, batch: Sequence[ActionRequest], tick: int, deliver: bool, opens: int | None
    ) -> tuple[Executed, Snapshot, Sequence[Message]]:
        """The actions in order (each by `execute_one`), then the evaluation and
        every acting robot's observation of tick + 1 (with `deliver`, after the batch's messages reached their
        receivers' scene graphs: lockstep delivers them with these observations; with `opens`, after that
        tick's scenario events). Also returns the snapshot after the batch and the scenario events fired."""
        self.mail.learn()
        outcomes = [self.execute_one(req, tick) for req in batch]
        if deliver:
            self.mail.delivered(self.sim.robots)
            self.mail.learn()
        fired = self.sim.fire_events(opens) if opens is not None and not self.sim.evaluate().success else []
        evaluation = self.sim.evaluate()
        observations = {req.robot: self.sim.observe(req.robot, tick + 1) for req in batch}
        return Executed(outcomes, evaluation, observations), self.snapshot(tick, [req.goal_id for req in batch]), fired

    def execute_one(self, req: ActionRequest, tick: int) -> SkillOutcome:
        """One request's outcome: a skill in the simulator, or a message into the mailroom."""
        action = req.action
        if not isinstance(action, Communicate):
            try:
                return self.sim.execute(req.robot, action)
            except Exception as exc:  # a simulator bug must not take the world down
                if getattr(self.sim, "closed", False):  # the world stopped under the skill: no bug to report
                    self._log.debug("skill cut short: the simulator closed", robot=req.robot, action=action.call())
                else:
                    self._log.exception("skill crashed", robot=req.robot, action=action.call())
                return SkillOutcome.fail(
                    OutcomeCode.PLAN_FAILED, f"The {action.skill} skill failed unexpectedly: {exc}."
                )
        if "communicate" not in self.sim.capabilities(req.robot):
            return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, f"{req.robot} cannot communicate.")
        if action.to not in self.sim.robots or action.to == req.robot:
            others = ", ".join(r for r in self.sim.robots if r != req.robot)
            return SkillOutcome.fail(
                OutcomeCode.RECIPIENT_UNKNOWN, f"There is no teammate called {action.to!r}; you can message {others}."
            )
        self.mail.send(req.robot, action.to, action.content, tick)
        self.tally.messages += 1
        return SkillOutcome.ok(f"Your message to {action.to} was sent.")

    def open_tick(self, tick: int) -> tuple[Sequence[Message], TaskResultLike]:
        """Tick `tick` opens: the scenario's events due by then, and the evaluation after them."""
        return self.sim.fire_events(tick), self.sim.evaluate()

    def observe(self, robot: str, tick: int) -> Observation:
        """`robot`'s observation now, once the messages delivered to it are known."""
        self.mail.learn()
        return self.sim.observe(robot, tick)

    def snapshot(self, tick: int, goals: list[str]) -> Snapshot:
        """The ground truth for viewers, taken where the simulator is idle (its thread, or the start)."""
        robots, objects, opened = self.sim.poses()
        return Snapshot(tick=tick, goals=goals, robots=robots, objects=objects, open=opened)

    # ------------------------------------------------------------------ counting (the loop's side)
    def count(self, batch: Sequence[ActionRequest], done: Executed) -> None:
        """A batch executed: its evaluation is the latest; its actions, failures and time count."""
        self.evaluation = done.evaluation
        for req, outcome in zip(batch, done.outcomes):
            self.tally.sim_time += outcome.sim_time
            if not isinstance(req.action, Wait):
                self.tally.actions[req.robot] += 1
            if not outcome.succeeded:
                self.tally.failed[req.action.skill] += 1

    # ------------------------------------------------------------------ the episode's first and last events
    def started(self, scheduler: Scheduler, protocol: str = DEFAULT_PROTOCOL) -> EpisodeStarted:
        """The episode's header; `protocol`: how its team decides, as the assembly said (recorded only)."""
        sim = self.sim
        return EpisodeStarted(
            run=self.run,
            task=sim.task_id,
            scene=sim.scene_id,
            seed=sim.seed,
            n_objects=sim.n_objects,
            robots=list(sim.robots),
            horizon=self.horizon,
            lower_bound=self.bound,
            fidelity=fidelity_label(sim.aids),
            aids=sorted(sim.aids),
            noise=sim.noise,
            team=TeamRecord(name=sim.team.name, digest=sim.team.digest(), kinds=sim.team.kinds),
            scheduler=scheduler.name,  # type: ignore[arg-type]
            protocol=protocol,
            **scheduler.started_fields(),  # type: ignore[arg-type]
        )

    def metrics(self, tick: int, makespan: float, wall_time: float) -> Metrics:
        """The paper's metrics of the episode so far (TS = `tick`)."""
        evaluation, t = self.evaluation, self.tally
        return Metrics(
            success=evaluation.success,
            partial_success=evaluation.partial_success,
            placed=evaluation.placed,
            total=evaluation.total,
            temporal_steps=tick,
            action_steps=sum(t.actions.values()),
            action_steps_per_robot={r: t.actions.get(r, 0) for r in self.sim.robots},
            failed_actions=dict(t.failed),
            messages=t.messages,
            wall_time=wall_time,
            sim_time=t.sim_time,
            lower_bound=self.bound,
            makespan=round(makespan, 6),
        )

    def done(self, reason: str, metrics: Metrics) -> EpisodeDone:
        """The episode's last event, with the answer key (now that no agent can use it: for reports)."""
        targets, goals, ordered = self.sim.answer_key()
        return EpisodeDone(
            run=self.run,
            reason=reason,
            metrics=metrics,
            final_results=dict(self.last_results),  # type: ignore[arg-type]
            targets=targets,
            goals=goals,
            ordered=ordered,
        )
