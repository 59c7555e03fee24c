"""The world's time policy without a bus: the world service's schedulers (world/schedulers/), its
roster and its admission of requests, driven in this thread by a caller that hands over the
robots' actions itself.

`DirectWorld` is the `World` a scheduler sees (world/schedulers/base.py), as the world service is,
with the episode's own rules shared with it (world/episode.py: how a batch runs, what counts
for the metrics, the first and last events). What the service would publish (results, turns,
events) is kept here for the caller to read. The schedulers' coroutines never wait on anything
outside the scheduler here (no bus, no worker thread), so each runs to its end at once
(`run_now`).
"""

from __future__ import annotations

import itertools
from collections.abc import Coroutine, Mapping, Sequence
from typing import Any, TypeVar

from mhrc.core.logs import get_logger
from mhrc.core.protocol import (
    Action,
    ActionRequest,
    ActionResult,
    EpisodeDone,
    Message,
    Observation,
    Rejection,
    RobotMessage,
    Turn,
    encode,
)
from mhrc.world.admission import Admission
from mhrc.world.episode import EpisodeCore
from mhrc.world.roster import Roster
from mhrc.world.schedulers import Executed, make_scheduler
from mhrc.world.sim import Sim

log = get_logger("mhrc.env")

T = TypeVar("T")
SESSION = "env"  # the one session every robot of an environment is attached from


def run_now(coro: Coroutine[Any, Any, T]) -> T:
    """Run a coroutine that never suspends to its end, here and now."""
    try:
        coro.send(None)
    except StopIteration as stop:
        return stop.value  # type: ignore[no-any-return]
    coro.close()
    raise RuntimeError("a scheduler awaited something outside the environment's world")  # pragma: no cover


def agent_id(robot: str) -> str:
    return f"env-{robot}"


class DirectWorld:
    """One episode of `sim` under the schedule `schedule` (lockstep or sequential), every robot
    attached from the start; `submit` hands a robot's action to the world's door."""

    def __init__(self, sim: Sim, *, schedule: str, horizon: int, run: str = "env") -> None:
        self.sim = sim
        self._run = run
        self._horizon = horizon
        self._log = log.bind(run=run)
        self.core = EpisodeCore(sim, run, horizon, self._log)
        self.roster = Roster(sim.robots, self._log)
        self.scheduler = make_scheduler(schedule, self)
        self.admission = Admission(self.roster, self.scheduler, self._log)
        self.done: EpisodeDone | None = None
        self.results: list[ActionResult] = []  # released, not yet read by the caller
        self.turns: list[Turn] = []  # given, not yet read by the caller
        self.events: list[Message] = []  # every world event, in order (the bus's world/event)
        self._goals = itertools.count()

    # ------------------------------------------------------------------ the caller's side
    def start(self) -> dict[str, Observation]:
        """Attach every robot, as the service does when an agent attaches, and start the episode:
        the observations the attach replies carry (in the sequential schedule, only the first
        robot's: the others wait for their turn)."""
        first: dict[str, Observation] = {}
        for robot in self.sim.robots:
            self.roster.attach(robot, agent_id(robot), SESSION)
            if not self.scheduler.on_attach(robot):
                messages = self.core.mail.deliver(robot)
                obs = self.core.observe(robot, self.scheduler.tick_of(robot))
                first[robot] = obs.model_copy(update={"new_messages": messages})
        self.scheduler.start()
        self.events += [self.core.started(self.scheduler), self.core.snapshot(0, [])]
        return first

    def submit(self, robot: str, action: Action) -> Rejection | None:
        """`robot`'s action for its current tick through the world's admission (the roster, each goal
        once, the scheduler's verdict); then whatever is due runs. None when it was accepted."""
        req = ActionRequest(
            goal_id=f"{robot}-{next(self._goals)}",
            robot=robot,
            agent_id=agent_id(robot),
            tick=self.scheduler.tick_of(robot),
            action=action,
        )
        _, rejection = self.admission.request(robot, encode(req), over=self.done is not None)
        if rejection is None:
            while self.done is None and self.scheduler.ready():
                run_now(self.scheduler.step())
        return rejection

    @property
    def tick(self) -> int:
        return self.scheduler.tick

    @property
    def turn(self) -> str | None:
        """The robot whose turn it is (sequential schedule); None in lockstep."""
        return getattr(self.scheduler, "turn", None)

    # ------------------------------------------------------------------ the scheduler's side (schedulers.World)
    @property
    def run_id(self) -> str:
        return self._run

    @property
    def robots(self) -> tuple[str, ...]:
        return self.sim.robots

    @property
    def attached(self) -> Mapping[str, str]:
        return self.roster.attached

    @property
    def horizon(self) -> int:
        return self._horizon

    async def execute(
        self, batch: Sequence[ActionRequest], tick: int, *, deliver: bool = False, opens: int | None = None
    ) -> Executed:
        done, snapshot, fired = self.core.execute_batch(batch, tick, deliver, opens)
        self.events += [*fired, snapshot]
        self.core.count(batch, done)
        return done

    async def open_tick(self, tick: int) -> None:
        fired, self.core.evaluation = self.core.open_tick(tick)
        self.events += fired

    async def observe(self, robot: str, tick: int) -> Observation:
        return self.core.observe(robot, tick)

    def deliver_messages(self) -> dict[str, list[RobotMessage]]:
        delivered = self.core.mail.take_all()
        self.events += [m for msgs in delivered.values() for m in msgs]
        return delivered

    def hold_messages(self, robot: str, messages: Sequence[RobotMessage]) -> None:
        self.core.mail.hold(robot, messages)

    def release(self, results: Sequence[ActionResult]) -> None:
        self.core.last_results.update((r.robot, r.goal_id) for r in results)
        self.results += results

    def give_turn(self, turn: Turn) -> None:
        self.turns.append(turn)

    def publish_event(self, event: Message) -> None:
        self.events.append(event)

    def finish(self, reason: str) -> None:
        """End the episode. Its wall time is 0: the environment's clock is its caller's, and the
        same seed and actions must give the same metrics (PettingZoo's seed tests compare them)."""
        if self.done is not None:
            return
        metrics = self.core.metrics(self.scheduler.tick, self.scheduler.makespan, wall_time=0.0)
        self.done = self.core.done(reason, metrics)
        self.events.append(self.done)
