"""The world as a bus participant: attaches agents, checks and acks their action requests,
runs the actions in the simulator and publishes results, messages and events.

When actions run and results go out is the time policy's (`WorldConfig.schedule`, one of
world.schedulers.SCHEDULERS; docs/architecture.md, "Time"); this module keeps the episode's lifecycle and
the bus plumbing. Who may drive which robot is the roster's (roster.py); which requests get in,
admission's (admission.py: each goal at most once); the robots' messages wait in the mailroom
until delivered (mail.py). What the service is set up with (its WorldConfig, the simulator it
drives) is service_config.py's.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Sequence
from dataclasses import replace

from mhrc.core.bus import Bus, Sample
from mhrc.core.keys import Keys
from mhrc.core.logs import get_logger
from mhrc.core.protocol import (
    ActionAck,
    ActionRequest,
    ActionResult,
    AttachReply,
    AttachRequest,
    EpisodeDone,
    Message,
    Observation,
    ProtocolError,
    Rejection,
    RobotAttached,
    RobotDetached,
    RobotMessage,
    Snapshot,
    Turn,
    WorldState,
    decode,
)
from mhrc.core.protocol.base import MAX_REQUEST_BYTES

from .admission import Admission
from .episode import EpisodeCore
from .presence import Presence
from .roster import Roster
from .schedulers import Executed, Scheduler, make_scheduler
from .service_config import NobodyAttached, SimLike, WorldConfig

log = get_logger("mhrc.world")


class WorldService:
    """Runs one episode of `sim` on `bus` until success, the horizon, or no agents are left."""

    def __init__(self, bus: Bus, sim: SimLike, config: WorldConfig) -> None:
        self.bus = bus
        self.sim = sim
        self.cfg = config
        self.listening = False
        self.keys = Keys(config.run)
        self.started = False
        self.done: EpisodeDone | None = None
        self._log = log.bind(run=config.run)
        self.roster = Roster(sim.robots, self._log)  # which agent drives which robot
        # how actions run, what they count, the mailroom: the episode's own rules (episode.py, shared with mhrc.env)
        self.core = EpisodeCore(sim, config.run, config.horizon, self._log)
        self.mail = self.core.mail  # the robots' messages, held until delivered
        self._sim_lock = asyncio.Lock()
        self._wake = asyncio.Event()
        self._t0 = 0.0
        self.presence = Presence(
            bus,
            self.keys,
            self.roster,
            deadline=config.token_deadline,
            detach=self._detach,
            over=lambda: self.done is not None,
        )  # which attached robots still have a live agent
        self.scheduler: Scheduler = make_scheduler(config.schedule, self, time_scale=config.time_scale)
        self.admission = Admission(self.roster, self.scheduler, self._log)  # what gets to the scheduler

    @property
    def tick(self) -> int:
        """The scheduler's clock."""
        return self.scheduler.tick

    @property
    def attached(self) -> dict[str, str]:
        """Robot -> agent id, for the robots attached now."""
        return self.roster.attached

    # ------------------------------------------------------------------ running
    def listen(self) -> None:
        """Serve the world's queries, take requests and declare its token, at once (no await): a
        caller that then hands the loop to observers knows the world listens before any of them
        acts. `run` listens first if nobody has called this."""
        if self.listening:
            return
        self.listening = True
        k = self.keys
        self.bus.serve(k.world_state, self._on_state_query)
        self.bus.serve(f"{k.base}/robot/*/attach", self._on_attach)
        self.bus.subscribe(k.any_action_request, self._on_request)
        self.presence.watch()
        self.bus.declare_token(k.alive_world)
        self._log.info("world ready", task=self.sim.task_id, seed=self.sim.seed, robots=list(self.sim.robots))

    async def run(self) -> EpisodeDone:
        """Serve the episode; returns its final event (also published on world/event)."""
        self.listen()
        await self._wait_for_start()
        self._start()
        while self.done is None:
            if self.scheduler.ready():
                await self.scheduler.step()
                if self.cfg.tick_delay:
                    await asyncio.sleep(self.cfg.tick_delay)
                continue
            if not self.attached:
                self.finish("no_agents")
                break
            self._wake.clear()
            wake_at = self.scheduler.wake_at()
            if wake_at is None:
                await self._wake.wait()
            else:  # simulated time moves on by itself: a result falls due, the budget runs out
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), max(0.0, wake_at - asyncio.get_running_loop().time()))
        assert self.done is not None
        self.presence.close()
        return self.done

    async def _wait_for_start(self) -> None:
        """Until every robot attached, or the start timeout passed with at least one attached;
        NobodyAttached when it passed with none (a world nobody joins would wait forever)."""
        loop = asyncio.get_running_loop()
        deadline = None if self.cfg.start_timeout is None else loop.time() + self.cfg.start_timeout
        while len(self.attached) < len(self.sim.robots):
            self._wake.clear()
            timeout = None if deadline is None else deadline - loop.time()
            if timeout is not None and timeout <= 0:
                if self.attached:
                    break
                assert self.cfg.start_timeout is not None
                self._log.info(
                    "no robot attached within the start timeout", timeout=self.cfg.start_timeout
                )  # the error says it
                raise NobodyAttached(self.sim.robots, self.cfg.start_timeout)
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
        self.scheduler.start()
        self.bus.put(self.keys.world_event, self.core.started(self.scheduler, self.cfg.protocol))
        self.bus.put(self.keys.world_event, self.core.snapshot(0, []))  # where everything starts (nothing has run yet)
        self._log.info("episode started", attached=sorted(self.attached))
        self._wake.set()

    def _execute_batch(
        self, batch: Sequence[ActionRequest], tick: int, deliver: bool, opens: int | None
    ) -> tuple[Executed, Snapshot, Sequence[Message]]:
        """Runs in a worker thread, holding the sim lock: the batch (EpisodeCore.execute_batch), its
        observations with the teammates attached now."""
        done, snapshot, fired = self.core.execute_batch(batch, tick, deliver, opens)
        return replace(done, observations={r: self._present(o) for r, o in done.observations.items()}), snapshot, fired

    def finish(self, reason: str) -> None:
        if self.done is not None:
            return
        wall_time = time.perf_counter() - self._t0 if self._t0 else 0.0
        metrics = self.core.metrics(self.tick, self.scheduler.makespan, wall_time)
        self.done = self.core.done(reason, metrics)
        self.bus.put(self.keys.world_event, self.done)
        self._log.info(
            "episode done", reason=reason, **metrics.model_dump(exclude={"action_steps_per_robot", "failed_actions"})
        )
        self._wake.set()

    async def agents_left(self, timeout: float) -> None:
        """Until every attached robot's agent has left (its token gone: the done event reached it),
        or `timeout` seconds have passed: the episode's last messages leave before the session closes."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while self.attached and (left := deadline - loop.time()) > 0:
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), left)

    def stop(self) -> None:
        """End the episode now (e.g. on Ctrl-C); publishes episode_done with reason 'stopped'."""
        self.finish("stopped")

    # ------------------------------------------------------------------ for the scheduler (schedulers.World)
    @property
    def run_id(self) -> str:
        return self.cfg.run

    @property
    def robots(self) -> tuple[str, ...]:
        return self.sim.robots

    @property
    def horizon(self) -> int:
        return self.cfg.horizon

    async def execute(
        self, batch: Sequence[ActionRequest], tick: int, *, deliver: bool = False, opens: int | None = None
    ) -> Executed:
        """Run `batch` in order at `tick` in a worker thread, holding the sim lock; count it. `deliver`: the
        observations returned carry the batch's messages (lockstep); `opens`: and that tick's scenario events."""
        async with self._sim_lock:
            done, snapshot, fired = await asyncio.to_thread(self._execute_batch, batch, tick, deliver, opens)
        for event in [*fired, snapshot]:
            self.bus.put(self.keys.world_event, event)
        self.core.count(batch, done)
        return done

    async def open_tick(self, tick: int) -> None:
        """Tick `tick` opens: the scenario's events due by then fire, each published on world/event."""
        async with self._sim_lock:
            fired, self.core.evaluation = await asyncio.to_thread(self.core.open_tick, tick)
        for event in fired:
            self.bus.put(self.keys.world_event, event)

    async def observe(self, robot: str, tick: int) -> Observation:
        """`robot`'s observation now, from a worker thread holding the sim lock."""
        async with self._sim_lock:
            return self._present(await asyncio.to_thread(self._observe, robot, tick))

    def _observe(self, robot: str, tick: int) -> Observation:
        return self.core.observe(robot, tick)

    def _present(self, obs: Observation) -> Observation:
        """The observation with the teammates attached now: a teammate whose agent left is not
        there to help (and one that joins appears), so a team can re-plan around it. Before the
        episode starts every teammate counts: the world waits for them (attach order must not
        change what a robot plans on)."""
        if not self.started:
            return obs
        present = {r: skills for r, skills in obs.teammates.items() if r in self.attached}
        return obs if len(present) == len(obs.teammates) else obs.model_copy(update={"teammates": present})

    def deliver_messages(self) -> dict[str, list[RobotMessage]]:
        delivered = self.mail.take_all()
        for msgs in delivered.values():
            for m in msgs:
                self.bus.put(self.keys.inbox(m.to, m.sender), m)
        return delivered

    def hold_messages(self, robot: str, messages: Sequence[RobotMessage]) -> None:
        self.mail.hold(robot, messages)

    def release(self, results: Sequence[ActionResult]) -> None:
        self.core.last_results.update((r.robot, r.goal_id) for r in results)
        for result in results:
            self.bus.put(self.keys.action_result(result.robot), result)

    def give_turn(self, turn: Turn) -> None:
        self.bus.put(self.keys.turn(turn.robot), turn)

    def publish_event(self, event: Message) -> None:
        self.bus.put(self.keys.world_event, event)

    # ------------------------------------------------------------------ bus handlers
    async def _on_attach(self, key: str, params: dict[str, str], payload: bytes) -> AttachReply:
        robot = self.keys.robot_of(key)
        try:
            req = decode(payload, AttachRequest, max_bytes=MAX_REQUEST_BYTES)
        except ProtocolError as exc:
            return AttachReply(robot=robot, accepted=False, reason=self.admission.malformed_attach(robot, exc))
        session = params.get("session", "")
        refused = self.roster.refuse_attach(robot, req, session, over=self.done is not None)
        if refused is not None:
            return AttachReply(robot=robot, accepted=False, reason=refused)
        if self.roster.attach(
            robot, req.agent_id, session
        ):  # said now, before the await below, during which the episode may start
            self.bus.put(self.keys.world_event, RobotAttached(robot=robot, agent_id=req.agent_id, tick=self.tick))
            self._log.info("robot attached", robot=robot, agent=req.agent_id, tick=self.tick)
            self.presence.expect(robot, req.agent_id)
        obs = None
        wait_turn = self.scheduler.on_attach(robot)
        tick = self.scheduler.tick_of(robot)
        if not wait_turn:
            messages = self.mail.deliver(
                robot
            )  # its waiting messages come with this observation, which knows what they tell
            try:
                obs = await self.observe(robot, tick)
            except BaseException:
                self.mail.hold(robot, messages)  # no observation carried them
                raise
            obs = obs.model_copy(update={"new_messages": messages})
        self._wake.set()
        return AttachReply(
            robot=robot, accepted=True, tick=tick, horizon=self.cfg.horizon, observation=obs, wait_turn=wait_turn
        )

    def _on_request(self, sample: Sample) -> None:
        robot = self.keys.robot_of(sample.key)
        goal_id, rejection = self.admission.request(robot, sample.payload, over=self.done is not None)
        if rejection is not None:
            self._reject(robot, goal_id, rejection)
            return
        self.bus.put(self.keys.action_ack(robot), ActionAck(goal_id=goal_id, robot=robot, accepted=True))
        self._wake.set()

    def _reject(self, robot: str, goal_id: str, rejection: Rejection) -> None:
        if robot in self.sim.robots:
            ack = ActionAck(goal_id=goal_id, robot=robot, accepted=False, reason=rejection.reason, code=rejection.code)
            self.bus.put(self.keys.action_ack(robot), ack)

    def _detach(self, robot: str, why: str) -> None:
        agent_id = self.roster.detach(robot)
        self.scheduler.forget(robot)
        if self.done is not None:
            self._wake.set()  # for agents_left
            return  # agents leaving after the episode: nothing to report
        stranded = self.roster.stranded(self.sim.finishers(), self.sim.capabilities)
        self._log.warning(
            "robot detached", robot=robot, tick=self.tick, why=why, **({"stranded": stranded} if stranded else {})
        )
        reason = why + (f"; {stranded} unless an agent attaches again" if stranded else "")
        self.bus.put(
            self.keys.world_event, RobotDetached(robot=robot, tick=self.tick, reason=reason, agent_id=agent_id)
        )
        self._wake.set()

    async def _on_state_query(self, key: str, params: dict[str, str], payload: bytes) -> WorldState:
        async with self._sim_lock:
            furniture, objects = await asyncio.to_thread(self.sim.views)
        evaluation = self.core.evaluation
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
