"""Async (docs/architecture.md, "Time"): no step barrier. Each robot acts at its own pace and waits only
for the world's answer to its own action.

- A request is executed as soon as the world gets to it (one action at a time on the one
  simulator, in arrival order), on the world as it is then: an action whose preconditions no
  longer hold (a teammate took the object) fails with the feedback any robot would get.
- Each action takes simulated time (`base.duration`: skills measure theirs; `wait` 1 s; a message
  or an action that failed before moving 0.5 s). It starts at the world's clock when executed,
  never before the robot's previous action ended nor before an action executed earlier started
  (so the clock never runs backwards), and its effects are in the world from its start.
- Its result, with the robot's observation, is released when the world's clock reaches the
  action's end. The clock runs at `time_scale` simulated seconds per wall second; with 0 (as
  fast as possible) it is driven by the actions alone: a result goes out as soon as its action
  executed, and thinking costs a robot no simulated time of its own, only the time its
  teammates' actions took meanwhile.
- A robot's tick is its own step count: the number of its actions executed so far. Its request
  names the tick of the observation it planned on; a request while its previous one is queued,
  executing or running (its result not yet out) is rejected.
- Messages arrive when sent: a message goes out on its inbox key when its `communicate`
  executes and reaches the receiver with its next observation.
- The horizon is a budget of `horizon x step_seconds` simulated seconds (STEP_SECONDS: the mean
  duration of a lockstep step of the heuristic team, measured). The episode ends with success
  when the clock reaches the end of the action that completed the task, or at the budget.
- TS (`tick` at the end) is the makespan in steps: makespan / step_seconds, rounded up, so a
  TS here stands beside the paper's step counts; `makespan` is in simulated seconds.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass

from mhrc.core.logs import get_logger
from mhrc.core.protocol import (
    ActionRequest,
    ActionResult,
    Observation,
    RejectCode,
    Rejection,
    RobotMessage,
    SkillOutcome,
)

from .base import Scheduler, SchedulerOptionError, World, duration

log = get_logger("mhrc.world")

# The mean simulated duration of one lockstep step (its longest action) of the heuristic team,
# measured over pack_objects, sort_solids and make_sandwich in the kitchen, 4 objects: 7.7 s.
STEP_SECONDS = 8.0


@dataclass(frozen=True)
class _Running:
    """An executed action whose result waits for the clock to reach its end."""

    req: ActionRequest
    outcome: SkillOutcome
    tick: int
    started: float
    ended: float
    observation: Observation  # the robot's view right after the action executed


class AsyncScheduler(Scheduler):
    """Every robot at its own pace; results released when their simulated duration has passed."""

    name = "async"

    def __init__(self, world: World, *, time_scale: float = 0.0, step_seconds: float = STEP_SECONDS) -> None:
        super().__init__(world)
        if not math.isfinite(time_scale) or time_scale < 0:
            raise SchedulerOptionError(
                f"--time-scale must be 0 (as fast as possible) or a positive number, not {time_scale}"
            )
        if step_seconds <= 0:
            raise SchedulerOptionError(f"step_seconds must be positive, not {step_seconds}")
        self.time_scale = time_scale
        self.step_seconds = step_seconds
        self.budget = world.horizon * step_seconds
        self.tick = 0
        self.steps: dict[str, int] = {r: 0 for r in world.robots}  # robot -> actions executed
        self.queue: list[ActionRequest] = []  # admitted, not yet executed, in arrival order
        self.executing: ActionRequest | None = None  # off the queue, in the simulator now
        self.running: dict[str, _Running] = {}  # executed, result not yet released
        self.mail: dict[str, list[RobotMessage]] = {}
        self.free_at: dict[str, float] = {}  # robot -> the end of its last action
        self.watermark = 0.0  # the start of the action executed last
        self.success_at: float | None = None  # the end of the action that completed the task
        self._t0: float | None = None  # loop time at the episode's start
        self._log = log.bind(run=world.run_id)

    # ------------------------------------------------------------------ the clock
    def start(self) -> None:
        self._t0 = asyncio.get_running_loop().time()

    def now(self) -> float:
        """The world's clock in simulated seconds."""
        if self.time_scale == 0 or self._t0 is None:
            return self.watermark
        return max(self.watermark, (asyncio.get_running_loop().time() - self._t0) * self.time_scale)

    def _due(self, t: float) -> bool:
        return self.time_scale == 0 or self.now() >= t

    def wake_at(self) -> float | None:
        if self.time_scale == 0 or self._t0 is None:
            return None
        times = [r.ended for r in self.running.values()] + [self.budget]
        if self.success_at is not None:
            times.append(self.success_at)
        return self._t0 + min(times) / self.time_scale

    def started_fields(self) -> dict[str, float]:
        return {"time_scale": self.time_scale, "step_seconds": self.step_seconds}

    # ------------------------------------------------------------------ requests
    def tick_of(self, robot: str) -> int:
        return self.steps.get(robot, 0)

    def admit(self, req: ActionRequest) -> Rejection | None:
        robot = req.robot
        busy = next((q for q in self._unanswered() if q.robot == robot), None)
        if busy is not None:
            return Rejection(
                RejectCode.BUSY,
                f"{robot} is still busy with {busy.action.call()}: send the next action after its result",
            )
        if req.tick != self.steps[robot]:
            return Rejection(
                RejectCode.STALE_TICK, f"the request is for tick {req.tick} but {robot} is at tick {self.steps[robot]}"
            )
        self.queue.append(req)
        return None

    def _unanswered(self) -> list[ActionRequest]:
        """The admitted requests whose result has not gone out: queued, executing, running."""
        executing = [] if self.executing is None else [self.executing]
        return [*self.queue, *executing, *(run.req for run in self.running.values())]

    def on_attach(self, robot: str) -> bool:
        self.world.hold_messages(robot, self.mail.pop(robot, []))  # into the attach reply's observation
        return False

    def forget(self, robot: str) -> None:
        self.queue = [q for q in self.queue if q.robot != robot]
        self.running.pop(robot, None)

    def ready(self) -> bool:
        if not self.world.attached:
            return False
        if self.success_at is None and (self.queue or (self.time_scale > 0 and self.now() >= self.budget)):
            return True
        if self.success_at is not None and self._due(self.success_at):
            return True
        return any(self._due(r.ended) for r in self.running.values())

    # ------------------------------------------------------------------ stepping
    async def step(self) -> None:
        """Release what is due, then execute the queued requests in arrival order; end the
        episode at the end of the action that completed the task, or at the budget."""
        if self.success_at is not None:  # nothing more executes; results due before the end go out
            if self._due(self.success_at):
                await self._finish("success", self.success_at)
            else:
                await self._release_due()
            return
        if self.time_scale > 0 and self.now() >= self.budget:
            await self._finish("horizon", self.budget)
            return
        await self._release_due()
        while self.queue and self.success_at is None:
            req = self.queue.pop(0)
            if req.robot not in self.world.attached:
                continue
            start = max(self.now(), self.free_at.get(req.robot, 0.0), self.watermark)
            if start >= self.budget:
                await self._finish("horizon", self.budget)
                return
            self.executing = req
            try:
                await self._execute(req, start)
            finally:
                self.executing = None  # now in `running` (or its robot left)
            if self.success_at is None:
                await self._release_due()
        if self.success_at is not None and self._due(self.success_at):
            await self._finish("success", self.success_at)

    async def _execute(self, req: ActionRequest, start: float) -> None:
        world, robot = self.world, req.robot
        tick = self.steps[robot]
        await world.open_tick(math.floor(start / self.step_seconds))  # the scenario's events due by the action's start
        done = await world.execute([req], tick)
        outcome = done.outcomes[0]
        end = start + duration(req, outcome)
        self.watermark = start
        self.steps[robot] = tick + 1
        self.free_at[robot] = end
        for receiver, msgs in world.deliver_messages().items():
            self.mail.setdefault(receiver, []).extend(msgs)
        if robot in world.attached:  # still there after the simulator's thread returned
            self.running[robot] = _Running(req, outcome, tick, start, end, done.observations[robot])
        self._advance(end if self.time_scale == 0 else start)
        if done.evaluation.success:
            self.success_at = end
        self._log.debug(
            "action executed",
            robot=robot,
            tick=tick,
            action=req.action.call(),
            start=round(start, 2),
            end=round(end, 2),
        )

    async def _release_due(self) -> None:
        for run in sorted(self.running.values(), key=lambda r: r.ended):
            if self._due(run.ended):
                await self._release(run, done=False)

    async def _release(self, run: _Running, *, done: bool) -> None:
        """Publish `run`'s result; the robot counts as busy until it is out (its observation may be awaited)."""
        robot = run.req.robot
        if self.time_scale == 0:
            obs = run.observation
        else:  # the world as it is at the action's end (with the scenario's events due by then)
            await self.world.open_tick(math.floor(run.ended / self.step_seconds))
            obs = await self.world.observe(robot, run.tick + 1)
        obs = obs.model_copy(update={"new_messages": self.mail.pop(robot, [])})
        self.world.release(
            [
                ActionResult(
                    goal_id=run.req.goal_id,
                    robot=robot,
                    tick=run.tick,
                    action=run.req.action,
                    outcome=run.outcome,
                    observation=obs,
                    done=done,
                    started=round(run.started, 6),
                    ended=round(run.ended, 6),
                )
            ]
        )
        if self.running.get(robot) is run:  # not forgotten meanwhile (nor, after a re-attach, another run)
            del self.running[robot]

    def _advance(self, t: float) -> None:
        self.makespan = max(self.makespan, t)
        self.tick = math.ceil(round(self.makespan / self.step_seconds, 9))

    async def _finish(self, reason: str, at: float) -> None:
        """End the episode at simulated time `at`: the actions still running go out with `done`."""
        self.makespan = at
        self.tick = math.ceil(round(at / self.step_seconds, 9))
        for run in sorted(self.running.values(), key=lambda r: r.ended):
            await self._release(run, done=True)
        self.world.finish(reason)
