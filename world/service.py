"""The world as a bus participant: attaches agents, schedules their actions in lockstep,
runs them in the simulator and publishes acks, results, messages and events.

Lockstep (DESIGN.md, "Time"): tick t closes when every attached robot has submitted one
action for t; the world executes them in the fixed robot order and releases all results
together. A message sent in tick t reaches its receiver with the observation of tick t+1.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Protocol

import structlog

from mhrc.bus import Bus, Sample
from mhrc.fidelity import label as fidelity_label
from mhrc.keys import Keys
from mhrc.protocol import (
    Action,
    ActionAck,
    ActionRequest,
    ActionResult,
    AttachReply,
    AttachRequest,
    Communicate,
    EpisodeDone,
    EpisodeStarted,
    FurnitureView,
    Metrics,
    ObjectView,
    Observation,
    OutcomeCode,
    ProtocolError,
    RobotAttached,
    RobotDetached,
    RobotMessage,
    SkillOutcome,
    TickClosed,
    Wait,
    WorldState,
    decode,
)

log = structlog.get_logger("mhrc.world")


class TaskResultLike(Protocol):
    success: bool
    placed: int
    total: int
    partial_success: float


class SimLike(Protocol):
    """What the service needs of a simulator (world.sim.Sim provides it)."""

    robots: tuple[str, ...]
    task_id: str
    scene_id: str
    seed: int
    n_objects: int

    def capabilities(self, robot: str) -> frozenset[str]: ...
    def execute(self, robot: str, action: Action) -> SkillOutcome: ...
    def observe(self, robot: str, tick: int) -> Observation: ...
    def tell(self, receiver: str, sender: str, text: str) -> None: ...
    def evaluate(self) -> TaskResultLike: ...
    def views(self) -> tuple[list[FurnitureView], list[ObjectView]]: ...
    def lower_bound(self) -> int: ...
    @property
    def aids(self) -> frozenset[str]: ...


@dataclass
class WorldConfig:
    run: str
    horizon: int = 50
    start_timeout: float | None = None  # start with the robots attached by then; None: wait for all
    tick_delay: float = 0.0  # pause between ticks, for watching with --gui


@dataclass
class _Tally:
    actions: Counter[str] = field(default_factory=Counter)
    failed: Counter[str] = field(default_factory=Counter)
    messages: int = 0
    sim_time: float = 0.0


class WorldService:
    """Runs one episode of `sim` on `bus` until success, the horizon, or no agents are left."""

    def __init__(self, bus: Bus, sim: SimLike, config: WorldConfig) -> None:
        self.bus = bus
        self.sim = sim
        self.cfg = config
        self.keys = Keys(config.run)
        self.tick = 0
        self.started = False
        self.done: EpisodeDone | None = None
        self.attached: dict[str, str] = {}  # robot -> agent id
        self.pending: dict[str, ActionRequest] = {}
        self._inbox: dict[str, list[RobotMessage]] = {r: [] for r in sim.robots}
        self._tally = _Tally()
        self._bound = sim.lower_bound()
        self._sim_lock = asyncio.Lock()
        self._wake = asyncio.Event()
        self._t0 = 0.0
        self._evaluation: TaskResultLike = sim.evaluate()
        self._last_results: dict[str, str] = {}  # robot -> goal id, results of the last closed tick
        self._log = log.bind(run=config.run)

    # ------------------------------------------------------------------ running
    async def run(self) -> EpisodeDone:
        """Serve the episode; returns its final event (also published on world/event)."""
        k = self.keys
        self.bus.serve(k.world_state, self._on_state_query)
        self.bus.serve(f"{k.base}/robot/*/attach", self._on_attach)
        self.bus.subscribe(k.any_action_request, self._on_request)
        self.bus.watch_liveliness(k.alive_any_robot, self._on_liveliness)
        self.bus.declare_token(k.alive_world)
        self._log.info("world ready", task=self.sim.task_id, seed=self.sim.seed, robots=list(self.sim.robots))

        await self._wait_for_start()
        self._start()
        while self.done is None:
            if self._tick_ready():
                await self._close_tick()
                if self.cfg.tick_delay:
                    await asyncio.sleep(self.cfg.tick_delay)
                continue
            if not self.attached:
                self._finish("no_agents")
                break
            self._wake.clear()
            await self._wake.wait()
        assert self.done is not None
        return self.done

    async def _wait_for_start(self) -> None:
        loop = asyncio.get_running_loop()
        deadline = None if self.cfg.start_timeout is None else loop.time() + self.cfg.start_timeout
        while len(self.attached) < len(self.sim.robots):
            self._wake.clear()
            timeout = None if deadline is None else deadline - loop.time()
            if timeout is not None and timeout <= 0:
                if self.attached:
                    break
                deadline = None  # nobody yet: keep waiting for the first agent
                continue
            try:
                await asyncio.wait_for(self._wake.wait(), timeout)
            except TimeoutError:
                pass
        missing = sorted(set(self.sim.robots) - set(self.attached))
        if missing:
            self._log.warning("starting without robots", missing=missing)

    def _start(self) -> None:
        self.started = True
        self._t0 = time.perf_counter()
        self.bus.put(
            self.keys.world_event,
            EpisodeStarted(
                run=self.cfg.run,
                task=self.sim.task_id,
                scene=self.sim.scene_id,
                seed=self.sim.seed,
                n_objects=self.sim.n_objects,
                robots=list(self.sim.robots),
                horizon=self.cfg.horizon,
                lower_bound=self._bound,
                fidelity=fidelity_label(self.sim.aids),
                aids=sorted(self.sim.aids),
            ),
        )
        self._log.info("episode started", attached=sorted(self.attached))
        self._wake.set()

    def _tick_ready(self) -> bool:
        return self.started and bool(self.attached) and all(r in self.pending for r in self.attached)

    async def _close_tick(self) -> None:
        tick = self.tick
        batch = [self.pending.pop(r) for r in self.sim.robots if r in self.pending and r in self.attached]
        self.pending.clear()
        async with self._sim_lock:
            outcomes, evaluation, observations = await asyncio.to_thread(self._execute_batch, batch, tick)
        self.tick += 1
        self._evaluation = evaluation
        finished = evaluation.success or self.tick >= self.cfg.horizon
        for req, outcome in zip(batch, outcomes):
            self._tally.sim_time += outcome.sim_time
            if not isinstance(req.action, Wait):
                self._tally.actions[req.robot] += 1
            if not outcome.succeeded:
                self._tally.failed[req.action.skill] += 1
        # deliver messages (visible from the next tick on), then results together
        delivered: dict[str, list[RobotMessage]] = {r: self._inbox[r] for r in self.sim.robots}
        self._inbox = {r: [] for r in self.sim.robots}
        for msgs in delivered.values():
            for m in msgs:
                self.bus.put(self.keys.inbox(m.to, m.sender), m)
        self._last_results = {req.robot: req.goal_id for req in batch}
        for req, outcome in zip(batch, outcomes):
            obs = observations[req.robot].model_copy(update={"new_messages": delivered[req.robot]})
            delivered[req.robot] = []
            self.bus.put(
                self.keys.action_result(req.robot),
                ActionResult(goal_id=req.goal_id, robot=req.robot, tick=tick, action=req.action, outcome=outcome, observation=obs, done=finished),
            )
        # messages for robots that had no action this tick wait for their next observation
        for robot, msgs in delivered.items():
            self._inbox[robot] = msgs + self._inbox[robot]
        self.bus.put(
            self.keys.world_event,
            TickClosed(
                tick=tick,
                actions={r.robot: r.action.call() for r in batch},
                outcomes={r.robot: o.succeeded for r, o in zip(batch, outcomes)},
                placed=evaluation.placed,
                total=evaluation.total,
            ),
        )
        self._log.debug("tick closed", tick=tick, placed=evaluation.placed, total=evaluation.total)
        if evaluation.success:
            self._finish("success")
        elif self.tick >= self.cfg.horizon:
            self._finish("horizon")

    def _execute_batch(
        self, batch: list[ActionRequest], tick: int
    ) -> tuple[list[SkillOutcome], TaskResultLike, dict[str, Observation]]:
        """Runs in a worker thread, holding the sim lock: the tick's actions in robot order,
        then the evaluation and every acting robot's observation of tick + 1."""
        outcomes = [self._execute(req, tick) for req in batch]
        evaluation = self.sim.evaluate()
        observations = {req.robot: self.sim.observe(req.robot, tick + 1) for req in batch}
        return outcomes, evaluation, observations

    def _execute(self, req: ActionRequest, tick: int) -> SkillOutcome:
        action = req.action
        if not isinstance(action, Communicate):
            try:
                return self.sim.execute(req.robot, action)
            except Exception as exc:  # a simulator bug must not take the world down
                self._log.exception("skill crashed", robot=req.robot, action=action.call())
                return SkillOutcome.fail(OutcomeCode.PLAN_FAILED, f"The {action.skill} skill failed unexpectedly: {exc}.")
        if "communicate" not in self.sim.capabilities(req.robot):
            return SkillOutcome.fail(OutcomeCode.NOT_CAPABLE, f"{req.robot} cannot communicate.")
        if action.to not in self.sim.robots or action.to == req.robot:
            others = ", ".join(r for r in self.sim.robots if r != req.robot)
            return SkillOutcome.fail(
                OutcomeCode.RECIPIENT_UNKNOWN, f"There is no teammate called {action.to!r}; you can message {others}."
            )
        self._inbox[action.to].append(RobotMessage(sender=req.robot, to=action.to, content=action.content, tick=tick))
        self.sim.tell(action.to, req.robot, action.content)
        self._tally.messages += 1
        return SkillOutcome.ok(f"Your message to {action.to} was sent.")

    def _finish(self, reason: str) -> None:
        if self.done is not None:
            return
        evaluation = self._evaluation
        t = self._tally
        metrics = Metrics(
            success=evaluation.success,
            partial_success=evaluation.partial_success,
            placed=evaluation.placed,
            total=evaluation.total,
            temporal_steps=self.tick,
            action_steps=sum(t.actions.values()),
            action_steps_per_robot={r: t.actions.get(r, 0) for r in self.sim.robots},
            failed_actions=dict(t.failed),
            messages=t.messages,
            wall_time=time.perf_counter() - self._t0 if self._t0 else 0.0,
            sim_time=t.sim_time,
            lower_bound=self._bound,
        )
        self.done = EpisodeDone(run=self.cfg.run, reason=reason, metrics=metrics, final_results=dict(self._last_results))  # type: ignore[arg-type]
        self.bus.put(self.keys.world_event, self.done)
        self._log.info("episode done", reason=reason, **metrics.model_dump(exclude={"action_steps_per_robot", "failed_actions"}))
        self._wake.set()

    def stop(self) -> None:
        """End the episode now (e.g. on Ctrl-C); publishes episode_done with reason 'stopped'."""
        self._finish("stopped")

    # ------------------------------------------------------------------ bus handlers
    async def _on_attach(self, key: str, params: dict[str, str], payload: bytes) -> AttachReply:
        robot = self.keys.robot_of(key)
        try:
            req = decode(payload, AttachRequest)
        except ProtocolError as exc:
            self._log.warning("malformed attach request rejected", robot=robot, reason=str(exc))
            return AttachReply(robot=robot, accepted=False, reason=f"malformed attach request: {exc}")
        if req.robot != robot:
            return AttachReply(robot=robot, accepted=False, reason=f"attach for {req.robot!r} sent on the key of {robot!r}")
        if robot not in self.sim.robots:
            return AttachReply(robot=robot, accepted=False, reason=f"there is no robot {robot!r} in this episode ({', '.join(self.sim.robots)})")
        if self.done is not None:
            return AttachReply(robot=robot, accepted=False, reason="the episode is over")
        holder = self.attached.get(robot)
        if holder is not None and holder != req.agent_id:
            self._log.warning("duplicate attach rejected", robot=robot, agent=req.agent_id)
            return AttachReply(robot=robot, accepted=False, reason=f"robot {robot} is already attached to another agent ({holder})")
        self.attached[robot] = req.agent_id
        async with self._sim_lock:
            obs = await asyncio.to_thread(self.sim.observe, robot, self.tick)
        obs = obs.model_copy(update={"new_messages": self._inbox[robot]})
        self._inbox[robot] = []
        if holder is None:
            self.bus.put(self.keys.world_event, RobotAttached(robot=robot, agent_id=req.agent_id, tick=self.tick))
            self._log.info("robot attached", robot=robot, agent=req.agent_id, tick=self.tick)
        self._wake.set()
        return AttachReply(robot=robot, accepted=True, tick=self.tick, horizon=self.cfg.horizon, observation=obs)

    def _on_request(self, sample: Sample) -> None:
        robot = self.keys.robot_of(sample.key)
        try:
            req = decode(sample.payload, ActionRequest)
        except ProtocolError as exc:
            self._log.warning("malformed action request rejected", robot=robot, reason=str(exc))
            self._reject(robot, _goal_id_of(sample.payload), f"malformed action request: {exc}")
            return
        reason = self._check_request(robot, req)
        if reason:
            self._log.info("action rejected", robot=robot, goal=req.goal_id, reason=reason)
            self._reject(robot, req.goal_id, reason)
            return
        self.pending[robot] = req
        self.bus.put(self.keys.action_ack(robot), ActionAck(goal_id=req.goal_id, robot=robot, accepted=True))
        self._wake.set()

    def _check_request(self, robot: str, req: ActionRequest) -> str:
        if req.robot != robot:
            return f"request for {req.robot!r} sent on the key of {robot!r}"
        if robot not in self.sim.robots:
            return f"there is no robot {robot!r} in this episode ({', '.join(self.sim.robots)})"
        if self.done is not None:
            return "the episode is over"
        holder = self.attached.get(robot)
        if holder is None:
            return f"robot {robot} is not attached: attach first"
        if holder != req.agent_id:
            return f"robot {robot} is attached to another agent"
        if req.tick != self.tick:
            return f"the request is for tick {req.tick} but the world is at tick {self.tick}"
        if robot in self.pending:
            return f"{robot} already submitted an action for tick {self.tick}"
        return ""

    def _reject(self, robot: str, goal_id: str, reason: str) -> None:
        if robot in self.sim.robots:
            self.bus.put(self.keys.action_ack(robot), ActionAck(goal_id=goal_id, robot=robot, accepted=False, reason=reason))

    def _on_liveliness(self, sample: Sample) -> None:
        robot = self.keys.robot_of(sample.key)
        if sample.is_put or robot not in self.attached:
            return
        del self.attached[robot]
        self.pending.pop(robot, None)
        if self.done is not None:
            return  # agents leaving after the episode: nothing to report
        self._log.warning("robot detached", robot=robot, tick=self.tick)
        self.bus.put(self.keys.world_event, RobotDetached(robot=robot, tick=self.tick, reason="agent vanished (liveliness lost)"))
        self._wake.set()

    async def _on_state_query(self, key: str, params: dict[str, str], payload: bytes) -> WorldState:
        async with self._sim_lock:
            furniture, objects = await asyncio.to_thread(self.sim.views)
        evaluation = self._evaluation
        return WorldState(
            run=self.cfg.run,
            task=self.sim.task_id,
            scene=self.sim.scene_id,
            seed=self.sim.seed,
            tick=self.tick,
            horizon=self.cfg.horizon,
            started=self.started,
            done=self.done is not None,
            attached=dict(self.attached),
            robots=list(self.sim.robots),
            furniture=furniture,
            objects=objects,
            placed=evaluation.placed,
            total=evaluation.total,
        )


def _goal_id_of(payload: bytes) -> str:
    """Best-effort goal id of a malformed request, so its sender can match the rejection."""
    try:
        data = json.loads(payload)
        goal = data.get("goal_id") if isinstance(data, dict) else None
        return goal if isinstance(goal, str) and goal else "unknown"
    except (ValueError, UnicodeDecodeError):
        return "unknown"

