"""`centralized`: one planner decides every robot's next action from all its robots'
observations, results and messages together (SMART-LLM, COHERENT, LaMMA-P plan this way).

The planner is one participant acting for several robots: each robot keeps its own agent
(`agents/agent.py`), its own bus session and login, so the secured bus's per-robot access rules
hold, and each agent's policy is a *seat* of the one planner. A seat hands its robot's
observation to the planner and gets back its robot's command of the round.

**Rounds.** A round names one command per robot from the union of their knowledge
(knowledge.py): the work of every robot is allocated together (allocation.py, an exact
assignment), then each robot's next step of its work is read off (steps.py). When a round runs
follows the world's schedule (docs/architecture.md, "Time"):

- lockstep: every attached robot asks for tick t together; the round of tick t runs once, when
  all of them have brought their observation of t, so the commands do not depend on the order
  the observations arrived in;
- sequential: the robots are asked one at a time within a tick, each after the earlier ones
  acted: waiting for all would wait for ever. The round runs at each robot's turn, on what the
  team knows by then (the earlier robots' results of the tick included);
- async: each robot asks when it is free; the round runs then, for whoever asks.

No robot needs to `communicate`: the planner hears every observation, so nothing is told by
message (in the paper's protocol a message is an action that costs its sender a step).
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field

from mhrc.core.protocol import (
    Action,
    ActionResult,
    Coordination,
    Navigate,
    Observation,
    Place,
    RobotDetached,
    Wait,
    WorldEvent,
)

from ..heuristic_base import HANDOVER, role_of
from ..policy import Decision
from .allocation import assign
from .knowledge import Knowledge
from .steps import MAX_TRIES, Hand, Job, Taken, finisher_can_take, finisher_step, job_step, make_room, standing

__all__ = ["CentralPlanner", "Seat"]

# s: lockstep, how long after the first observation of a tick reached the planner it waits for one of its robots
# that is attached but never brings its own. The world released every robot's observation of the tick at the same
# moment (a lockstep tick closes for all), so a live agent has its own a moment after its teammates; one that has
# not has died between the release and its decision. The world detaches it as its liveliness token goes, and its
# `robot_detached` event ends the wait (`Seat.world_event`); this bound is for an agent that stopped while its
# session, and so its token, lives on.
RELEASE_SPREAD = 5.0


NEAR_POSE = 0.5  # m: a robot stopped this near a stand pose (off target) holds it: it is in the way there
EARLY = 1  # an ordered task: objects that may lie on the finisher's table before their turn (steps.job_step)
PLANNER = "planner"  # a Coordination's `by` for the jobs the central planner allocates


@dataclass
class CentralPlanner:
    """The one planner behind every seat (see the module docstring)."""

    robots: tuple[str, ...]  # the robots it acts for, in the team's order
    schedule: str = "lockstep"
    knowledge: Knowledge = field(default_factory=Knowledge)
    hands: dict[str, Hand] = field(default_factory=dict)
    rounds: int = 0
    _commands: dict[int, dict[str, Action]] = field(default_factory=dict)  # lockstep: tick -> the round's commands
    _arrived: asyncio.Condition | None = None
    _sent: dict[str, Action] = field(default_factory=dict)  # robot -> the command it was given, until its result
    _released: dict[int, float] = field(default_factory=dict)  # lockstep: tick -> when its first observation came
    _ended: set[str] = field(default_factory=set)  # robots whose last result ended the episode
    _gone: set[str] = field(default_factory=set)  # robots the world detached since their last observation

    def __post_init__(self) -> None:
        self.hands = {r: Hand(r) for r in self.robots}

    async def aclose(self) -> None:
        """The episode is over. The heuristic planner holds nothing to close."""

    # ---------------------------------------------------------------- the seats' side
    def detached(self, robot: str) -> None:
        """The world let `robot` go (its agent died, its token was lost): the round of the tick under
        way no longer waits for it. It counts again from its next observation."""
        self._gone.add(robot)
        if self._arrived is not None:
            asyncio.get_running_loop().create_task(self._wake())

    async def _wake(self) -> None:
        assert self._arrived is not None
        async with self._arrived:
            self._arrived.notify_all()

    async def command(self, obs: Observation) -> Action:
        """The command of `obs.robot` for its observation's tick."""
        self._gone.discard(obs.robot)
        self.knowledge.take(obs)
        action = await self._command(obs)
        self._sent[obs.robot] = action
        return action

    async def _command(self, obs: Observation) -> Action:
        if self.schedule != "lockstep":
            return (await self.plan((obs.robot,)))[obs.robot]
        if self._arrived is None:
            self._arrived = asyncio.Condition()
        loop, t = asyncio.get_running_loop(), obs.tick
        async with self._arrived:
            first = self._released.setdefault(t, loop.time())
            self._arrived.notify_all()  # an arrival: the barrier of its tick looks again
            while t not in self._commands and not self._all_in(t):
                left = first + RELEASE_SPREAD - loop.time()
                if left <= 0:
                    break
                try:
                    await asyncio.wait_for(self._arrived.wait(), left)
                except TimeoutError:
                    break
            if t not in self._commands:  # the round of tick t, for every robot that brought its observation
                self._commands[t] = await self.plan(tuple(r for r in self.robots if self._at(r, t)))
                for old in [u for u in self._commands if u < t - 2]:
                    del self._commands[old]
                    self._released.pop(old, None)
            elif obs.robot not in self._commands[t]:  # late (re-attached): its own command, its teammates' stand
                self._commands[t] |= await self.plan((obs.robot,))
            return self._commands[t][obs.robot]

    def _at(self, robot: str, tick: int) -> bool:
        o = self.knowledge.obs.get(robot)
        return o is not None and o.tick == tick

    def _all_in(self, tick: int) -> bool:
        """Every robot of this planner attached at `tick` brought its observation of it. Attached:
        the world's word in the observations of the tick (each lists the teammates attached when it
        was made); a robot detached is not waited for, nor one whose episode ended."""
        seen = [o for o in self.knowledge.obs.values() if o.tick == tick]
        attached = {r for o in seen for r in (o.robot, *o.teammates)} - self._ended - self._gone
        return all(self._at(r, tick) for r in self.robots if r in attached)

    def record(self, robot: str, result: ActionResult) -> None:
        self._sent.pop(robot, None)
        if result.done:
            self._ended.add(robot)
        self.knowledge.record(robot, result)
        self.hands[robot].record(result)
        a = result.action
        if isinstance(a, Place) and result.outcome.succeeded and a.location == HANDOVER:
            for h in self.hands.values():  # brought anew: the finisher tries it again
                if h.robot != robot:
                    h.tries.pop(a.obj, None)

    # ---------------------------------------------------------------- a round
    async def plan(self, asking: tuple[str, ...]) -> dict[str, Action]:
        """The round's commands for the `asking` robots (the LLM form asks its model here)."""
        return self.round(asking)

    def decision(self, robot: str, action: Action) -> Decision:
        """What `robot`'s seat publishes with its command."""
        hand = self.hands[robot]
        job = hand.job.call() if hand.job else None
        told = Coordination(job=job, by=PLANNER if job else None)
        return Decision(action=action, reasoning=f"round {self.rounds}: {job or 'no work'}", coordination=told)

    def round(self, asking: tuple[str, ...]) -> dict[str, Action]:
        """Allocate the work of every robot, then each asking robot's next step."""
        self.rounds += 1
        k = self.knowledge
        movers = [self.hands[r] for r in self.robots if r in k.obs and self._mobile(r)]
        for h in movers:
            if h.job is not None and not self._valid(h.job, h):
                h.job = None
        self._allocate(movers)
        out: dict[str, Action] = {}
        for r in asking:
            hand = self.hands[r]
            out[r] = self._step(hand)
            if isinstance(out[r], Wait) and hand.job is None and hand in movers and self._working(hand):
                self._allocate([hand])  # its work ended just now: other work at once, not a step later
                out[r] = self._step(hand)
        return out

    def _allocate(self, hands: list[Hand]) -> None:
        """Give work to those of `hands` that are free (no fetch under way, nothing held): the exact
        assignment over every job nobody is fetching already."""
        k = self.knowledge
        fetching = {h.job for h in self.hands.values() if h.job is not None and h.job.kind == "fetch"}
        free = [
            h
            for h in hands
            if self._working(h) and k.obs[h.robot].status.holding is None and (h.job is None or h.job.kind == "explore")
        ]
        jobs = [j for j in self._jobs() if j not in fetching]
        busy = sum(1 for h in self.hands.values() if h not in free and h.job is not None and h.job.kind == "fetch")
        given = assign(k, free, jobs, start=busy, scouts=self._scouting())  # its own job costs a robot less (STAY)
        for h in free:
            h.job = given.get(h.robot)

    def _step(self, hand: Hand) -> Action:
        k = self.knowledge
        obs = k.obs[hand.robot]
        if obs.tick < hand.broken_until:
            hand.job = None if k.obs[hand.robot].status.holding is None else hand.job
            return Wait()
        if not self._mobile(hand.robot):
            return finisher_step(k, hand) or Wait()
        at = {h.robot: self._where(h.robot) for h in self.hands.values() if h.robot in k.obs and self._mobile(h.robot)}
        for h in self.hands.values():
            if h.robot in at and (h.pose is None or self._idle(h)):  # without work it holds only where it stands
                h.pose = at[h.robot]
        others = [h for h in self.hands.values() if h is not hand and h.robot in at]
        idle = {h.pose for h in others if h.pose is not None and self._idle(h)}
        held = {p for h in others for p in (h.pose, at[h.robot]) if p is not None}  # where it stands, and heads
        taken = Taken(held - idle, idle)
        holding = k.obs[hand.robot].status.holding
        if holding is not None and holding in k.targets:
            hand.job = Job("fetch", holding)  # what it carries is its work: nobody else is sent for it
        if hand.job is None and holding is None:
            claimed = {h.pose for h in others if h.pose is not None and not self._idle(h)}  # (one claimed from it too)
            if not claimed and self._all_brought():
                return Wait()  # nobody comes any more: making room would be a step for nothing
            return make_room(k, hand, claimed, taken, self._needed()) or Wait()
        step = job_step(k, hand, taken, near=True, early=EARLY, pair=True)
        if step is None and hand.job is not None:
            hand.job = None  # its work is done or cannot go on: the next round gives it other work
        return step or Wait()

    # ---------------------------------------------------------------- the work there is
    def _mobile(self, robot: str) -> bool:
        return "navigate" in self.knowledge.obs[robot].status.skills

    def _where(self, robot: str) -> tuple[str, int] | None:
        """The stand pose `robot` stands at, as the team knows; one it was sent to and whose result
        is not heard yet counts as reached (in the sequential schedule a result waits for its
        robot's next turn: its teammates plan before then, on the command it was given)."""
        sent = self._sent.get(robot)
        if isinstance(sent, Navigate):
            return (sent.target, sent.stand_pose)
        return standing(self.knowledge, robot) or standing(self.knowledge, robot, near=NEAR_POSE)

    def _needed(self) -> frozenset[str]:
        """Furniture where a target lies that a robot will come for: an idle robot standing there
        leaves before the fetcher comes (which may need another of its stand poses after a failed
        grasp)."""
        k = self.knowledge
        lying = (k.located(t) for t in k.todo())
        return frozenset(
            o.on
            for o in lying
            if o is not None
            and o.on is not None
            and o.held_by is None
            and o.on != HANDOVER
            and not k.goal_fixture(o.on)
        )

    def _all_brought(self) -> bool:
        """Every target still to go lies within the finisher's reach or is in its gripper: the task
        is the finisher's alone now."""
        k, fin = self.knowledge, self._finisher()
        if fin is None or not k.targets:
            return False
        return all(
            (o := k.located(t)) is not None and (o.held_by == fin.robot or finisher_can_take(k, fin, t))
            for t in k.todo()
        )

    def _idle(self, hand: Hand) -> bool:
        """No work and nothing in its gripper (as the team last heard)."""
        return hand.job is None and self.knowledge.latest(hand.robot).status.holding is None

    def _working(self, hand: Hand) -> bool:
        o = self.knowledge.obs.get(hand.robot)
        return o is None or o.tick >= hand.broken_until

    def _scouting(self) -> bool:
        """A scout (a robot that navigates and cannot pick) is there and working to look at
        surfaces: one heard from, or one its teammates' observations list as attached."""
        k = self.knowledge
        for r in self.robots:
            o = k.obs.get(r)
            skills = (
                o.status.skills
                if o is not None
                else next((t[r] for t in (ob.teammates for ob in k.obs.values()) if r in t), None)
            )
            if (
                skills is not None
                and "navigate" in skills
                and role_of(skills) == "scout"
                and self._working(self.hands[r])
            ):
                return True
        return False

    def _finisher(self) -> Hand | None:
        k = self.knowledge
        return next(
            (self.hands[r] for r in self.robots if r in k.obs and role_of(k.obs[r].status.skills) == "finisher"), None
        )

    def _jobs(self) -> list[Job]:
        """Every job the team's knowledge calls for: each target to bring (known where, not within
        the finisher's reach), and, while a target is nowhere known, each furniture not looked at."""
        k = self.knowledge
        fin = self._finisher()
        jobs: list[Job] = []
        lost = not k.targets  # the task's list not known yet (the finisher has not been heard): look around
        fetchers = sum(1 for r in self.robots if r in k.obs and role_of(k.obs[r].status.skills) == "fetcher")
        wanted = 0  # an ordered task: only the next few are fetched (steps.next_wanted), one per fetcher and EARLY more
        to_bring = sum(
            1
            for t in k.todo()
            if (o := k.located(t)) is None
            or (
                o.held_by is None
                and not k.goal_fixture(o.on)
                and not (fin is not None and finisher_can_take(k, fin, t))
            )
        )
        early = EARLY if to_bring > EARLY + 1 else 0  # brought early only with more to bring after the next: the
        # finisher takes them in order, so one brought early at the end only lengthens the finisher's last work
        for t in k.todo():
            o = k.located(t)
            if o is None:
                lost = True
                wanted += 1  # in a sandwich, what comes after it waits until it is found
            elif o.held_by is not None and o.held_by != (fin.robot if fin else None):
                wanted += 1  # on its way
            elif (
                o.held_by is None
                and not k.goal_fixture(o.on)
                and not (fin is not None and finisher_can_take(k, fin, t))
            ):
                wanted += 1
                if k.ordered and wanted > max(1, fetchers) + (0 if lost else early):  # (early: not while one is lost)
                    continue
                if any(h.tries.get(t, 0) < MAX_TRIES for h in self.hands.values() if h is not fin):
                    jobs.append(Job("fetch", t))
        if lost:
            unseen = [
                f.name
                for f in k.furniture.values()
                if f.stand_poses and f.name != HANDOVER and f.name not in k.explored
            ]
            if not unseen:  # everything was looked at and something is still nowhere: look again
                k.explored.clear()
                unseen = [f.name for f in k.furniture.values() if f.stand_poses and f.name != HANDOVER]
            jobs += [Job("explore", name) for name in unseen]
        return jobs

    def _valid(self, job: Job, hand: Hand) -> bool:
        k = self.knowledge
        if job.kind == "explore":
            return job.target not in k.explored and (not k.targets or any(k.located(t) is None for t in k.todo()))
        o = k.located(job.target)
        fin = self._finisher()
        return (
            o is not None
            and o.held_by in (None, hand.robot)
            and not k.done(job.target)
            and (o.held_by == hand.robot or fin is None or not finisher_can_take(k, fin, job.target))
        )


@dataclass
class Seat:
    """One robot's policy under the central planner: its observations in, the round's command out."""

    robot: str
    planner: CentralPlanner
    name: str = "centralized"

    async def decide(self, obs: Observation) -> Decision:
        action = await self.planner.command(obs)
        return self.planner.decision(self.robot, action)

    def world_event(self, event: WorldEvent) -> None:
        """A world event, as this robot's agent heard it: a teammate detached is not awaited."""
        if isinstance(event, RobotDetached):
            self.planner.detached(event.robot)

    def record(self, result: ActionResult) -> None:
        self.planner.record(self.robot, result)

    async def aclose(self) -> None:
        """The episode is over: the planner lets go of what it holds (every seat says so; once is enough)."""
        await self.planner.aclose()
