"""Lockstep (docs/architecture.md, "Time"): tick t closes when every attached robot has submitted one
action for t; the world executes them in the fixed robot order and releases all results
together. A message sent in tick t reaches its receiver with the observation of tick t+1.
On the world's clock the robots of a tick act at the same time: a tick lasts as long as its
longest action.
"""

from __future__ import annotations

from mhrc.core.logs import get_logger
from mhrc.core.protocol import ActionRequest, ActionResult, RejectCode, Rejection, TickClosed

from .base import Scheduler, World, duration

log = get_logger("mhrc.world")


class LockstepScheduler(Scheduler):
    """One action per attached robot per tick; the tick closes when the last one arrives."""

    name = "lockstep"

    def __init__(self, world: World, *, time_scale: float = 0.0) -> None:
        super().__init__(world)
        self.tick = 0
        self.pending: dict[str, ActionRequest] = {}
        self.closing: frozenset[str] = (
            frozenset()
        )  # the robots whose actions of `tick` execute now (off `pending`, no result yet)
        self._log = log.bind(run=world.run_id)

    def admit(self, req: ActionRequest) -> Rejection | None:
        if req.tick != self.tick:
            return Rejection(
                RejectCode.STALE_TICK, f"the request is for tick {req.tick} but the world is at tick {self.tick}"
            )
        if (
            req.robot in self.pending or req.robot in self.closing
        ):  # one action per robot per tick, executing ones included
            return Rejection(RejectCode.TICK_TAKEN, f"{req.robot} already submitted an action for tick {self.tick}")
        self.pending[req.robot] = req
        return None

    def ready(self) -> bool:
        attached = self.world.attached
        return bool(attached) and all(r in self.pending for r in attached)

    def forget(self, robot: str) -> None:
        self.pending.pop(robot, None)

    async def step(self) -> None:
        """Close the tick: execute, deliver its messages, then release every result together."""
        world, tick = self.world, self.tick
        batch = [self.pending.pop(r) for r in world.robots if r in self.pending and r in world.attached]
        self.pending.clear()
        self.closing = frozenset(req.robot for req in batch)
        try:
            done = await world.execute(
                batch, tick, deliver=True, opens=tick + 1
            )  # tick + 1's scenario events before its observations
        finally:
            self.closing = frozenset()  # from here to the results' release nothing awaits, and the tick moves on
        began = self.makespan
        took = [duration(req, outcome) for req, outcome in zip(batch, done.outcomes)]
        self.makespan = began + max(took, default=0.0)
        self.tick += 1
        evaluation = done.evaluation
        finished = evaluation.success or self.tick >= world.horizon
        delivered = world.deliver_messages()
        results = []
        for req, outcome, seconds in zip(batch, done.outcomes, took):
            obs = done.observations[req.robot].model_copy(update={"new_messages": delivered[req.robot]})
            delivered[req.robot] = []
            results.append(
                ActionResult(
                    goal_id=req.goal_id,
                    robot=req.robot,
                    tick=tick,
                    action=req.action,
                    outcome=outcome,
                    observation=obs,
                    done=finished,
                    started=round(began, 6),
                    ended=round(began + seconds, 6),
                )
            )
        world.release(results)
        # messages for robots that had no action this tick wait for their next observation
        for robot, msgs in delivered.items():
            world.hold_messages(robot, msgs)
        world.publish_event(
            TickClosed(
                tick=tick,
                actions={r.robot: r.action.call() for r in batch},
                outcomes={r.robot: o.succeeded for r, o in zip(batch, done.outcomes)},
                placed=evaluation.placed,
                total=evaluation.total,
            )
        )
        self._log.debug("tick closed", tick=tick, placed=evaluation.placed, total=evaluation.total)
        if evaluation.success:
            world.finish("success")
        elif self.tick >= world.horizon:
            world.finish("horizon")
