"""`leader`: DynaHMRC's loop, with every stage a `communicate` action (it costs its sender a step,
as every message does in the paper's protocol), in the fixed sentences of leader_talk.py.

1. **Self-description and bid.** Each robot tells the *convener* what it is, what it can do, and
   its bid to lead: the estimated cost of leading, the steps of its own work it would set aside
   (`ROLE_BID`: a scout's are the cheapest, a fetcher's the dearest). The convener is the robot
   every robot can name from its teammates' skills: the lowest bid by role, first in the team's
   order (one message per robot, not one to every teammate).
2. **Election.** Once the convener has every attached robot's bid (or waited `ELECTION_WAIT`
   ticks) it elects the lowest bidder, ties by the team's order, and announces the winner when it
   is not itself. The finisher then tells the leader the task's targets and those it takes itself.
3. **Allocation by auction.** The leader holds what it saw and what it was told, and each round
   auctions the work to the robots holding fewer than `QUEUE` jobs, one job after another (the
   first fetch, then the closed containers to look into, then the other fetches, then the
   surfaces), each to the lowest bid: the estimated steps of that robot for that job, from its
   self-description and where it last reported from, plus `LOAD` per job it holds. Each
   allocation is a message ("Leader david assigns alice: fetch(book)."); the leader's own job
   needs none.
4. **Reflective execution.** A robot carries out its jobs a step at a time (steps.py, the
   experts' recoveries), and reports each: done (with what it found, for a look), or failed, with
   the failure's code and a reflection that says what should happen next; the leader books it
   and allocates again. A robot with no work steps out of the stand pose it stands at.

**Re-election.** A robot whose leader is no longer attached (its agent detached: gone from the
observation's teammates) drops the leader's bid and the election is held again among those
attached; each robot then tells the new leader what it is working on, and the finisher tells it
the task again.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from mhrc.core.protocol import Action, ActionResult, Communicate, Move, Navigate, Observation, OutcomeCode, Wait
from mhrc.core.protocol.thoughts import Coordination

from ..heuristic_base import HANDOVER, failed, role_of
from ..policy import Decision, Policy
from . import leader_talk as talk
from .base import Seating
from .knowledge import Knowledge
from .steps import BOB_TRIES, Hand, Job, Taken, finisher_step, job_step

__all__ = ["ROLE_BID", "LeaderPolicy", "build_heuristic"]

ROLE_BID = {"scout": 2.0, "finisher": 5.0, "fetcher": 9.0}  # steps of its own work a robot sets aside to lead
BLOCKED = 3  # navigations in a row to an occupied stand pose before a robot reports and leaves the job
TRIES = 3  # failed grasps of one object before a robot reports and leaves it to another
AT_POSE = 0.3  # m: a robot this near a stand pose stands at it
ASIDE = 0.5  # m: how far an idle robot steps away from the furniture it stood at
ASIDE_HANDOVER = 1.0  # m: ... from the finisher's table, where the next fetcher's arm must have room (one move's most)
ELECTION_WAIT = 3  # ticks a convener waits for bids before it elects among those it has
QUEUE = 2  # jobs a robot holds at most (the one under way and the next): it goes on without waiting for the leader
LOAD = 4.0  # steps: a bid's share for each job the robot holds already
SCOUT_SURFACE = 3.0  # steps: a robot that can pick bids this much more to look at a surface while a scout can
REFLECTIONS = {
    OutcomeCode.TOO_FAR: "it lies beyond my arm from every stand pose I tried, another robot should try",
    OutcomeCode.OFF_TARGET: "I could not stop at a stand pose there, another robot should try",
    OutcomeCode.OCCUPIED: "another robot stands where I must stand; it should do it, or leave",
}


@dataclass
class LeaderPolicy:
    """One robot under the leader protocol (see the module docstring)."""

    robot: str
    team: tuple[str, ...]
    name: str = "leader"
    k: Knowledge = field(default_factory=Knowledge)
    hand: Hand = field(init=False)
    skills: dict[str, tuple[str, ...]] = field(default_factory=dict)
    bids: dict[str, float] = field(default_factory=dict)
    described_to: str | None = None  # the convener told my self-description and bid
    convened_at: int | None = None  # the tick I began collecting bids as the convener
    had_leader: bool = False
    tell_status: bool = False
    leader: str | None = None
    outbox: list[Communicate] = field(default_factory=list)
    attached: set[str] = field(default_factory=set)
    told_task: str | None = None  # the finisher: the leader it told the task
    reported_fails: set[str] = field(default_factory=set)  # the finisher: targets it gave back
    # the leader's book
    assigned: dict[str, list[Job]] = field(default_factory=dict)  # robot -> its jobs, the one under way first
    queue: list[Job] = field(default_factory=list)  # my jobs after the one under way
    awaiting: set[str] = field(default_factory=set)  # robots whose work a new leader has not heard yet
    theirs: set[str] = field(default_factory=set)  # targets the finisher takes itself
    failed_by: dict[Job, set[str]] = field(default_factory=dict)
    where: dict[str, str] = field(default_factory=dict)  # robot -> the furniture it last reported from
    aside: bool = False  # stepped out of a stand pose since its last job
    parked: str | None = None  # the empty furniture it parked at since its last job: it stays there
    park_failed: set[str] = field(default_factory=set)  # furniture it could not park at since its last job
    make_way: str | None = None  # idle: the furniture a teammate asked me to leave
    asked: set[tuple[str, str, str]] = field(default_factory=set)  # (occupant, furniture, my job) I asked to make way
    blocked: int = 0  # navigations in a row that found the stand pose occupied

    def __post_init__(self) -> None:
        self.hand = Hand(self.robot)

    # ---------------------------------------------------------------- the policy
    async def decide(self, obs: Observation) -> Decision:
        self.k.take(obs)
        self.skills[self.robot] = tuple(obs.status.skills)
        self.attached = {self.robot, *obs.teammates}
        for r, s in obs.teammates.items():
            self.skills.setdefault(r, tuple(s))
        self.bids.setdefault(self.robot, ROLE_BID[role_of(obs.status.skills)])
        for m in obs.new_messages:
            said = talk.parse(m.content)
            if said is not None:
                self._hear(said)
        if self.leader is not None and self.leader not in self.attached:
            self._lost_leader()
        if obs.tick < self.hand.broken_until:
            return self._say(Wait(), "broken down: waiting")
        if self.leader is None:
            held = self._election(obs)
            if held is not None:
                return held
        assert self.leader is not None
        self._tell_task(obs)
        if self.leader == self.robot:
            self._allocate()
        if self.outbox:
            return self._send()
        return self._act(obs)

    def record(self, result: ActionResult) -> None:
        self.k.record(self.robot, result)
        self.hand.record(result)

    # ---------------------------------------------------------------- stages 1 and 2
    def _convener(self) -> str:
        """The robot that collects the bids: the lowest bid by role (every robot can work it out
        from its teammates' skills), first in the team's order."""
        order = {r: i for i, r in enumerate(self.team)}
        return min(self.attached, key=lambda r: (ROLE_BID[role_of(self.skills.get(r, ()))], order.get(r, len(order))))

    def _election(self, obs: Observation) -> Decision | None:
        """Stages 1 and 2: my self-description and bid to the convener; the convener elects once it
        has every attached robot's bid (or waited `ELECTION_WAIT` ticks). Until a leader is known
        (or presumed: the convener, unless it announces another), a decision that waits."""
        conv = self._convener()
        if conv != self.robot:
            if self.described_to != conv:
                self.described_to = conv
                text = talk.describe(self.robot, obs.status.kind, obs.status.skills, self.bids[self.robot])
                return self._say(Communicate(to=conv, content=text), "self-description and bid to the convener " + conv)
            self.leader = conv  # presumed until the convener announces another
            return None
        self.convened_at = self.convened_at if self.convened_at is not None else obs.tick
        if not all(r in self.bids for r in self.attached) and obs.tick < self.convened_at + ELECTION_WAIT:
            return self._say(Wait(), "convener: waiting for every teammate's bid")
        self._elect()
        return None

    def _elect(self) -> None:
        order = {r: i for i, r in enumerate(self.team)}
        candidates = [r for r in self.bids if r in self.attached]
        self.leader = min(candidates, key=lambda r: (self.bids[r], order.get(r, len(order))))
        if self.leader == self.robot:
            self.assigned = {}
            if self.had_leader:  # what each robot is doing is told again
                self.awaiting = {r for r in self.attached if r != self.robot and "navigate" in self.skills.get(r, ())}
        else:
            for r in self.team:
                if r in self.attached and r != self.robot:
                    self._queue(talk.elected(self.robot, self.leader), to=r)
        self.had_leader = True

    def _lost_leader(self) -> None:
        """The leader detached: its bid goes, a new election is held (stages 1 and 2 again), and each
        robot will tell the new leader what it is working on."""
        gone = self.leader
        assert gone is not None
        self.bids.pop(gone, None)
        self.leader, self.described_to, self.convened_at, self.told_task = None, None, None, None
        self.had_leader = True
        self.outbox = [m for m in self.outbox if m.to != gone]
        if "navigate" in self.skills.get(self.robot, ()):
            self.queue.clear()  # the new leader allocates the rest again
            self.tell_status = True

    def _tell_task(self, obs: Observation) -> None:
        """The finisher tells the leader the targets and which it takes itself (once per leader);
        after a new election, a mobile robot tells the new leader what it is working on."""
        if self.tell_status and self.leader != self.robot:
            self.tell_status = False
            job = self.hand.job
            self._queue(talk.status(self.robot, job.kind if job else None, job.target if job else None))
        if not obs.targets or self.told_task == self.leader:
            return
        self.told_task = self.leader
        mine = [t for t in self.k.todo() if (o := self.k.located(t)) is not None and self.k.in_reach(self.robot, o)]
        if self.leader == self.robot:
            self.theirs = set(mine)
            return
        self._queue(talk.task_list(self.robot, list(obs.targets), obs.ordered, mine))

    # ---------------------------------------------------------------- hearing
    def _hear(self, said: talk.Said) -> None:
        if isinstance(said, talk.Describe):
            self.bids[said.robot] = said.bid
            self.skills[said.robot] = said.skills
        elif isinstance(said, talk.Elected):
            self.leader = said.leader
        elif isinstance(said, talk.Assign) and said.robot == self.robot:
            self.leader = said.leader
            self._take(Job(said.kind, said.target))
        elif isinstance(said, talk.TaskList):
            self.k.told, self.k.told_ordered, self.theirs = list(said.targets), said.ordered, set(said.mine)
        elif isinstance(said, talk.Done):
            self._free(said.robot, Job(said.kind, said.target))
            if said.kind == "fetch":
                self.k.brought.add(said.target)
                self.where[said.robot] = HANDOVER
            else:
                self.k.explored.add(said.target)
                self.where[said.robot] = said.target
        elif isinstance(said, talk.Failed):
            self._free(said.robot, Job(said.kind, said.target))
            if said.robot == self._finisher():  # it cannot take it from its table: to be brought nearer
                self.k.brought.discard(said.target)
                self.theirs.discard(said.target)
            else:
                self.failed_by.setdefault(Job(said.kind, said.target), set()).add(said.robot)
        elif isinstance(said, talk.MakeWay) and said.asked == self.robot:
            self.make_way, self.parked = said.furniture, None
        elif isinstance(said, talk.Status):
            self.awaiting.discard(said.robot)
            if said.kind is not None and said.target is not None:
                self.assigned[said.robot] = [Job(said.kind, said.target)]
            else:
                self.assigned.pop(said.robot, None)

    def _take(self, job: Job) -> None:
        """A job given to me: now, or after the one under way."""
        if self.hand.job is None:
            self.hand.job = job
        elif job != self.hand.job and job not in self.queue:
            self.queue.append(job)

    def _free(self, robot: str, job: Job) -> None:
        jobs = self.assigned.get(robot, [])
        if job in jobs:
            jobs.remove(job)
        self.awaiting.discard(robot)

    def _finisher(self) -> str | None:
        return next((r for r in self.team if role_of(self.skills.get(r, ())) == "finisher"), None)

    # ---------------------------------------------------------------- stage 3: the leader's auction
    def _allocate(self) -> None:
        mine = [j for j in (self.hand.job, *self.queue) if j is not None]
        self.assigned[self.robot] = mine
        free = [
            r
            for r in self.team
            if r in self.attached
            and len(self.assigned.get(r, [])) < QUEUE
            and r not in self.awaiting
            and "navigate" in self.skills.get(r, ())
        ]
        if not free:
            return
        order = {r: i for i, r in enumerate(self.team)}
        for job in self._jobs():
            if not free:
                break
            bids = sorted((self._bid(r, job), order[r], r) for r in free)
            cost, _, winner = bids[0]
            if cost >= 1e6:
                continue
            self.assigned.setdefault(winner, []).append(job)
            if len(self.assigned[winner]) >= QUEUE:
                free.remove(winner)
            if winner == self.robot:
                self._take(job)
            else:
                self._queue(talk.assign(self.robot, winner, job.kind, job.target), to=winner)

    def _jobs(self) -> list[Job]:
        """The work there is, in the auction's order (see the module docstring)."""
        k = self.k
        busy = {j for jobs in self.assigned.values() for j in jobs}
        lost, fetches, wanted = not k.targets, [], 0
        for t in k.targets:
            if t in k.brought or t in self.theirs or self._on_goal(t):
                continue
            o = k.located(t)
            if o is None:
                lost = True
                wanted += 1  # in a sandwich, what comes after it waits until it is found
                continue
            wanted += 1
            if Job("fetch", t) in busy or o.held_by is not None or (k.ordered and wanted > 1):
                continue
            fetches.append(Job("fetch", t))
        looks: list[Job] = []
        if lost:
            places = [f for f in k.furniture.values() if f.stand_poses and f.name != HANDOVER]
            unseen = [f for f in places if f.name not in k.explored and Job("explore", f.name) not in busy]
            if not unseen and not any(j.kind == "explore" for j in busy):
                k.explored.clear()  # everything was looked at and something is still nowhere: look again
                unseen = places
            closed = [Job("explore", f.name) for f in unseen if f.openable and not f.is_open]
            looks = closed + [Job("explore", f.name) for f in unseen if not (f.openable and not f.is_open)]
            n = len(closed)
            return fetches[:1] + looks[:n] + fetches[1:] + looks[n:]
        return fetches

    def _on_goal(self, t: str) -> bool:
        o = self.k.objects.get(t)
        return o is not None and self.k.goal_fixture(o.on)

    def _bid(self, robot: str, job: Job) -> float:
        """`robot`'s estimated steps for `job` (1e6: it cannot, or it failed it already)."""
        skills = set(self.skills.get(robot, ()))
        if "navigate" not in skills or robot in self.failed_by.get(job, set()):
            return 1e6
        return self._steps(robot, skills, job) + LOAD * len(self.assigned.get(robot, []))

    def _steps(self, robot: str, skills: set[str], job: Job) -> float:
        if job.kind == "explore":
            f = self.k.furniture[job.target]
            closed = f.openable and not f.is_open
            if closed and "open" not in skills:
                return 1e6
            scouts = any(role_of(self.skills.get(r, ())) == "scout" for r in self.attached)
            extra = SCOUT_SURFACE if not closed and "pick" in skills and scouts else 0.0
            return (0 if self.where.get(robot) == f.name else 1) + (1 if closed else 0) + extra
        if "pick" not in skills:
            return 1e6
        o = self.k.located(job.target)
        src = self.k.furniture.get(o.on or "") if o is not None else None
        there = src is not None and self.where.get(robot) == src.name
        return (3.0 if there else 4.0) + (1 if src is not None and src.openable and not src.is_open else 0)

    # ---------------------------------------------------------------- stage 4: execution and reflection
    def _act(self, obs: Observation) -> Decision:
        if "navigate" not in obs.status.skills:
            return self._finish(obs)
        job = self.hand.job
        if job is not None and job.kind == "fetch" and self.hand.tries.get(job.target, 0) >= TRIES:
            self.hand.tries.pop(job.target)  # reflect now: another robot may do better than an eighth try
            return self._give_up(obs, job)
        last = self.hand.last
        occupied = last is not None and isinstance(last.action, Navigate) and last.outcome.code == OutcomeCode.OCCUPIED
        self.blocked = self.blocked + 1 if occupied else 0
        who = last.outcome.details.get("occupant") if occupied and last is not None else None
        busy = job is not None or obs.status.holding is not None
        if busy and isinstance(who, str) and who in self.attached - {self.robot} and last is not None:
            where = getattr(last.action, "target", "")
            if (who, where, str(job)) not in self.asked:  # once a job: it leaves if idle, else its work takes it away
                self.asked.add((who, where, str(job)))
                self._queue(talk.make_way(self.robot, who, where), to=who)
                return self._send()
        if job is not None and obs.status.holding is None and self.blocked >= BLOCKED:
            self.blocked = 0
            return self._give_up(obs, job)
        if job is None and obs.status.holding is None:
            return self._step_aside(obs)
        self.aside, self.parked, self.make_way = False, None, None
        self.park_failed.clear()
        step = job_step(self.k, self.hand, Taken(set(), set()))
        if step is not None:
            return self._say(step, f"my job: {job.call() if job else 'deliver what I hold'}")
        if job is None:
            return self._say(Wait(), "no work")
        done = job.target in self.k.explored if job.kind == "explore" else self.k.done(job.target)
        if not done:
            return self._give_up(obs, job)
        self.hand.job = self.queue.pop(0) if self.queue else None
        found = [o.name for o in self.k.objects.values() if o.on == job.target] if job.kind == "explore" else []
        self._report(talk.done(self.robot, job.kind, job.target, found))
        return self._send() if self.outbox else self._act(obs)  # (the leader's own report: on to the next job)

    def _give_up(self, obs: Observation, job: Job) -> Decision:
        """Reflect on a job that failed and report it; the leader gives it to another robot."""
        self.hand.job = self.queue.pop(0) if self.queue else None
        last = self.hand.last
        code = last.outcome.code if last is not None and failed(last) else OutcomeCode.OBJECT_UNKNOWN
        why = REFLECTIONS.get(code, "I could not go on from what I know; the job is free for another robot")
        self._report(talk.failed(self.robot, job.kind, job.target, code.value, why))
        return self._send() if self.outbox else self._act(obs)

    def _step_aside(self, obs: Observation) -> Decision:
        """No work: out of the stand pose it stands at (nobody else knows it is idle there, and one
        robot stands at a stand pose at a time): to a stand pose of a furniture it saw empty, where
        it then stays (another empty furniture next when that one was taken), else by a move away
        from the furniture, longer from the finisher's table, where another fetcher's arm must have
        room; tried again while it still stands there."""
        base = obs.status.base
        if base is None:
            return self._say(Wait(), "no work")
        at = {
            f.name
            for f in self.k.furniture.values()
            if any(math.hypot(base.x - sp.x, base.y - sp.y) <= AT_POSE for sp in f.stand_poses)
        }
        last = self.hand.last
        if self.aside and last is not None and isinstance(last.action, Navigate):
            if last.outcome.succeeded:
                self.parked = last.action.target
            else:
                self.park_failed.add(last.action.target)
        asked = self.make_way in at
        if not at or (self.parked in at and not asked):
            return self._say(Wait(), "no work: parked" if at else "no work")
        moved_failed = last is not None and isinstance(last.action, Move) and failed(last)
        park = self._park(obs, at | self.park_failed, anywhere=asked)
        if park is not None:
            self.aside = True
            return self._say(park, "no work: out of the way")
        if "move" in obs.status.skills and not moved_failed:
            f = self.k.furniture[HANDOVER if HANDOVER in at else sorted(at)[0]]
            dx, dy = base.x - f.position[0], base.y - f.position[1]
            d = math.hypot(dx, dy) or 1.0
            step = ASIDE_HANDOVER if f.name == HANDOVER else ASIDE
            return self._say(Move(dx=step * dx / d, dy=step * dy / d), "no work: out of the way")
        return self._say(Wait(), "no work")

    def _finish(self, obs: Observation) -> Decision:
        step = finisher_step(self.k, self.hand)
        for t in self.k.todo():
            if self.hand.tries.get(t, 0) >= BOB_TRIES and t not in self.reported_fails:
                self.reported_fails.add(t)
                self._report(talk.failed(self.robot, "fetch", t, "too_far", "bring it nearer to my arm"))
        if self.outbox:
            return self._send()
        return self._say(step or Wait(), "the finisher: what is within my reach onto its goal")

    def _park(self, obs: Observation, here: set[str], anywhere: bool = False) -> Navigate | None:
        """A stand pose of the nearest furniture it saw empty, not one in `here` (nobody is sent to
        an empty furniture); `anywhere` (asked to make way), else of a surface it knows nothing on;
        None when it knows none."""
        base = obs.status.base
        assert base is not None
        empty = [
            f
            for f in self.k.furniture.values()
            if f.stand_poses
            and f.name != HANDOVER
            and f.name not in here
            and f.name in self.k.explored
            and not any(o.on == f.name for o in self.k.objects.values())
        ]
        if not empty and anywhere:
            known = {o.on for o in self.k.objects.values()}
            empty = [
                f
                for f in self.k.furniture.values()
                if f.stand_poses and f.name not in here | known | {HANDOVER} and not f.openable
            ]
        spots = (
            (math.hypot(base.x - sp.x, base.y - sp.y), f.name, i) for f in empty for i, sp in enumerate(f.stand_poses)
        )
        best = min(spots, default=None)
        return None if best is None else Navigate(target=best[1], stand_pose=best[2])

    def _report(self, text: str) -> None:
        """A report goes to the leader; the leader books its own at once."""
        if self.leader == self.robot:
            said = talk.parse(text)
            if said is not None:
                self._hear(said)
        else:
            self._queue(text)

    # ---------------------------------------------------------------- messages
    def _queue(self, text: str, to: str | None = None) -> None:
        target = to or self.leader
        if target is not None and target != self.robot:
            self.outbox.append(Communicate(to=target, content=text))

    def _send(self) -> Decision:
        msg = self.outbox.pop(0)
        return self._say(msg, "telling " + msg.to)

    def _say(self, action: Action, why: str) -> Decision:
        lead = f"leader {self.leader}" if self.leader else "no leader yet"
        job = self.hand.job.call() if self.hand.job else None
        told = Coordination(leader=self.leader, job=job, by=self.leader if job else None)
        return Decision(action=action, reasoning=f"{lead}; {why}", coordination=told)


def build_heuristic(seating: Seating) -> Mapping[str, Policy]:
    """Each robot its own policy (they share nothing but messages): the heuristic form."""
    return {r: LeaderPolicy(r, seating.team.names) for r in seating.robots}
