"""Sequential (docs/architecture.md, "Time"; the paper's Algorithm 1): within tick t the world asks the
attached robots one at a time, in the fixed robot order, and executes each one's action before
the next robot observes: robot k plans on the world that robots 0..k-1 left in this tick.

The turn: a robot gets an observation only when it is its turn. The result of its action in
tick t-1 is held by the world and released at its turn in tick t, with an observation computed
at that moment; a robot with no result pending (tick 0, or after attaching) gets a `Turn` on
its turn key instead (its attach reply said `wait_turn`), except the robot on turn, whose
attach reply carries its observation. Only the robot on turn may submit, for the current tick.
After the last robot of the tick the tick closes: `TickClosed`, then success or the horizon end
the episode, and every held result goes out at once with `done`.

Messages: a message sent in tick t reaches its receiver with the receiver's observation of
tick t+1, whether the sender comes before or after the receiver in the order (the paper's
m_i^t comes back with the feedback of the receiver's own action, so what robot j < i sent in
step t is in the observation robot i plans step t+1 on; what j > i sent in step t is too). A
message sent in tick t+1 before the receiver's turn waits for tick t+2, so that what a robot
hears never depends on how the order interleaves with its own step. This is lockstep's rule.

On the world's clock the robots act one after another: each action starts when the one before
it (any robot's) ended.
"""

from __future__ import annotations

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
    TickClosed,
    Turn,
)

from .base import Scheduler, TaskResultLike, World, duration

log = get_logger("mhrc.world")


@dataclass(frozen=True)
class _Held:
    """An executed action whose result waits for its robot's next turn."""

    req: ActionRequest
    outcome: SkillOutcome
    tick: int
    started: float
    ended: float


class SequentialScheduler(Scheduler):
    """One robot at a time, in the fixed robot order; each acts on the world the earlier ones left."""

    name = "sequential"

    def __init__(self, world: World, *, time_scale: float = 0.0) -> None:
        super().__init__(world)
        self.tick = 0
        self.turn: str | None = world.robots[0] if world.robots else None  # the robot asked now
        self.given = False  # whether the robot on turn has its observation
        self.pending: ActionRequest | None = None  # the admitted request of the robot on turn
        self.executing: ActionRequest | None = (
            None  # that request while the simulator runs it (off `pending`, turn not yet passed)
        )
        self.held: dict[str, _Held] = {}
        self.mail: dict[str, list[RobotMessage]] = {}  # messages of closed ticks, for the receiver's next turn
        self._executed: list[tuple[ActionRequest, SkillOutcome]] = []  # this tick's, in order
        self._evaluation: TaskResultLike | None = None
        self._log = log.bind(run=world.run_id)

    def on_attach(self, robot: str) -> bool:
        if robot != self.turn:
            return True
        self.given = True  # the attach reply carries its observation
        self.world.hold_messages(robot, self.mail.pop(robot, []))  # into that observation
        return False

    def admit(self, req: ActionRequest) -> Rejection | None:
        if req.tick != self.tick:
            return Rejection(
                RejectCode.STALE_TICK, f"the request is for tick {req.tick} but the world is at tick {self.tick}"
            )
        if req.robot != self.turn or not self.given:
            return Rejection(
                RejectCode.NOT_YOUR_TURN, f"it is {self.turn}'s turn in tick {self.tick}: {req.robot} waits for its own"
            )
        if self.pending is not None or self.executing is not None:  # one action per turn, the executing one included
            return Rejection(RejectCode.TICK_TAKEN, f"{req.robot} already submitted an action for tick {self.tick}")
        self.pending = req
        return None

    def ready(self) -> bool:
        attached = self.world.attached
        if not attached:
            return False
        return self.pending is not None or self.turn not in attached or not self.given

    def forget(self, robot: str) -> None:
        self.held.pop(robot, None)
        if robot == self.turn:
            self.pending = None
            self.given = False

    async def step(self) -> None:
        """Execute the action of the robot on turn, if any; then pass the turn on, closing the
        tick after its last robot, and give the next robot its observation."""
        world = self.world
        if self.pending is not None:
            req, self.pending = self.pending, None
            self.executing = req
            try:
                done = await world.execute([req], self.tick)
            finally:
                self.executing = None  # nothing awaits from here until the turn has passed on
            outcome = done.outcomes[0]
            self._evaluation = done.evaluation
            self._executed.append((req, outcome))
            began = self.makespan
            self.makespan = began + duration(req, outcome)
            self.held[req.robot] = _Held(req, outcome, self.tick, began, self.makespan)
            self.turn, self.given = self._next(req.robot), False
        elif self.turn is not None and self.turn not in world.attached:
            self.turn, self.given = self._next(self.turn), False
        if self.turn is None:
            if await self._close_tick():
                return
            await world.open_tick(self.tick)  # the scenario's events of the new tick, before anyone observes it
            self.turn, self.given = self._next(None), False
            if self.turn is None:
                return  # nobody attached: the service ends the episode
        await self._give_turn(self.turn)

    def _next(self, after: str | None) -> str | None:
        """The first attached robot after `after` in the fixed order (from the start with None)."""
        robots = self.world.robots
        start = 0 if after is None else robots.index(after) + 1
        return next((r for r in robots[start:] if r in self.world.attached), None)

    async def _observation(self, robot: str) -> Observation:
        obs = await self.world.observe(robot, self.tick)
        return obs.model_copy(update={"new_messages": self.mail.pop(robot, [])})

    async def _give_turn(self, robot: str) -> None:
        """Release `robot`'s held result with the world of now, or tell it that it is its turn."""
        obs = await self._observation(robot)
        self.given = True
        held = self.held.pop(robot, None)
        if held is None:
            self.world.give_turn(Turn(robot=robot, tick=self.tick, observation=obs))
        else:
            self.world.release([self._result(held, obs, done=False)])

    async def _close_tick(self) -> bool:
        """Publish the tick, advance the clock, end the episode on success or at the horizon
        (releasing every held result); True when the episode ended."""
        world, tick = self.world, self.tick
        executed, self._executed = self._executed, []
        evaluation = self._evaluation or (await world.execute([], tick)).evaluation
        self.tick += 1
        finished = evaluation.success or self.tick >= world.horizon
        for robot, msgs in world.deliver_messages().items():
            self.mail.setdefault(robot, []).extend(msgs)
        if finished:
            held = [(r, self.held.pop(r)) for r in world.robots if r in self.held]
            world.release([self._result(h, await self._observation(r), done=True) for r, h in held])
        world.publish_event(
            TickClosed(
                tick=tick,
                actions={r.robot: r.action.call() for r, _ in executed},
                outcomes={r.robot: o.succeeded for r, o in executed},
                placed=evaluation.placed,
                total=evaluation.total,
            )
        )
        self._log.debug("tick closed", tick=tick, placed=evaluation.placed, total=evaluation.total)
        if evaluation.success:
            world.finish("success")
        elif finished:
            world.finish("horizon")
        return finished

    @staticmethod
    def _result(held: _Held, obs: Observation, *, done: bool) -> ActionResult:
        req = held.req
        return ActionResult(
            goal_id=req.goal_id,
            robot=req.robot,
            tick=held.tick,
            action=req.action,
            outcome=held.outcome,
            observation=obs,
            done=done,
            started=round(held.started, 6),
            ended=round(held.ended, 6),
        )
