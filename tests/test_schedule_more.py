"""More on the world's time policies: lockstep's determinism across process layouts, and the
sequential scheduler when a robot's agent leaves mid-episode (and when a new one comes back).

The detach tests use the public harness, `mhrc.testing.world_on_loopback`: the world and the
three heuristic agents run in this process, each agent on a Zenoh session of its own (a client
of the world's router on loopback), plus an observer session of ours collecting world events.
An agent "detaches" the way a crashed one would: its task is cancelled, which closes its
session and drops its liveliness token. Where the robots stand when that happens is made
deterministic by a gate in a policy (the agent blocks in `decide` at a chosen tick), so nothing
here waits on wall-clock time: every wait is on an event or on the episode's end, bounded.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from mhrc.agents.heuristic import heuristic_policy
from mhrc.agents.policy import Decision
from mhrc.core.keys import Keys
from mhrc.core.protocol import (
    ActionResult,
    EpisodeDone,
    Message,
    Observation,
    RobotAttached,
    RobotDetached,
    TickClosed,
    Turn,
    decode_event,
)
from mhrc.core.records import messages, read_records
from mhrc.run.config import ROBOTS, EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.run.processes import up_processes
from mhrc.testing import LoopbackWorld, world_on_loopback

WAIT = 120.0  # s: generous bound on every wait, so a regression fails instead of hanging


def _executed(trace: Path) -> list[tuple[int, str, str, str]]:
    """(tick, robot, action, feedback) of every action result in a trace, in the order recorded
    (a copy of tests/test_schedulers.py's helper: tests/ is no package here)."""
    return [(m.tick, m.robot, m.action.call(), m.outcome.feedback) for m in messages(read_records(trace), ActionResult)]


def _events(trace: Path, kind: str) -> list[Any]:
    """The world's events of `kind`, as their protocol models."""
    return [
        line.msg
        for line in read_records(trace)
        if line.msg is not None and line.key.endswith("/world/event") and line.msg.kind == kind
    ]


# --------------------------------------------------------------------------- lockstep


@pytest.mark.slow
async def test_lockstep_same_trace_in_one_process_or_many(tmp_path: Path) -> None:
    a = await up_in_process(
        EpisodeConfig.build(seed=0, horizon=8, schedule="lockstep", trace=tmp_path / "a.jsonl").resolved()
    )
    b = await up_processes(
        EpisodeConfig.build(seed=0, horizon=8, schedule="lockstep", trace=tmp_path / "b.jsonl").resolved()
    )
    assert a.reason == b.reason == "horizon" and a.metrics.temporal_steps == b.metrics.temporal_steps == 8
    ta, tb = _executed(tmp_path / "a.jsonl"), _executed(tmp_path / "b.jsonl")
    # every tick's results go out together, in the fixed robot order
    assert [(tick, robot) for tick, robot, _, _ in ta] == [(t, r) for t in range(8) for r in ROBOTS]
    assert ta == tb
    for name in ("a", "b"):
        assert [m.scheduler for m in _events(tmp_path / f"{name}.jsonl", "episode_started")] == ["lockstep"]
        assert not any(line.key.endswith("/turn") for line in read_records(tmp_path / f"{name}.jsonl")), (
            "lockstep gives no turns"
        )
    assert a.metrics.model_dump(exclude={"wall_time"}) == b.metrics.model_dump(exclude={"wall_time"})


# --------------------------------------------------------------------------- sequential: agents leaving and coming back


class _Gated:
    """The heuristic policy of `robot`, which blocks in `decide` on its observation of tick `at`
    (once) until `release` is set, after setting `reached`."""

    def __init__(self, robot: str, at: int | None) -> None:
        self.robot = robot
        self.name = "gated"
        self.inner = heuristic_policy(robot)
        self.at = at
        self.reached = asyncio.Event()
        self.release = asyncio.Event()

    async def decide(self, obs: Observation) -> Decision:
        if obs.tick == self.at and not self.reached.is_set():
            self.reached.set()
            await self.release.wait()
        return await self.inner.decide(obs)

    def record(self, result: ActionResult) -> None:
        self.inner.record(result)


class _Events:
    """The world events an observer session of ours sees, in order."""

    def __init__(self) -> None:
        self.seen: list[Message] = []
        self._news = asyncio.Event()

    @classmethod
    async def observe(cls, world: LoopbackWorld) -> _Events:
        events = cls()
        (await world.client()).subscribe(Keys(world.run).world_event, events._on_event)
        return events

    def _on_event(self, sample: Any) -> None:
        self.seen.append(decode_event(sample.payload))
        self._news.set()

    async def first(self, match: Callable[[Message], bool]) -> Message:
        """The first world event (seen so far or still to come) for which `match` is true."""

        async def wait() -> Message:
            while True:
                self._news.clear()
                for ev in self.seen:
                    if match(ev):
                        return ev
                await self._news.wait()

        return await asyncio.wait_for(wait(), WAIT)


async def _detach(agent: asyncio.Task[EpisodeDone | None]) -> None:
    """Kill an agent started by `LoopbackWorld.agent` as a crash would: cancel its task, which
    closes its session (its liveliness token goes)."""
    agent.cancel()
    with contextlib.suppress(asyncio.CancelledError):
        await agent


def _ticks_closed(trace: Path) -> list[TickClosed]:
    return _events(trace, "tick")


def _key_index(trace: Path, predicate: Any) -> list[int]:
    return [i for i, line in enumerate(read_records(trace)) if predicate(line)]


K = 2  # the tick at which David's agent goes away
HORIZON = 12  # the heuristic team needs 16 ticks for seed 0 (and far more without David): the horizon ends it


@pytest.mark.parametrize("on_turn", [True, False], ids=["on-its-turn", "while-alice-plans"])
async def test_sequential_goes_on_without_a_robot_whose_agent_left(tmp_path: Path, on_turn: bool) -> None:
    """David's agent dies in tick K, either on its own turn (planning; the world waits for its
    action) or while Alice, first in the order, plans (David's tick K-1 result still held).
    The world publishes robot_detached, the turn passes on, every tick still closes with Alice
    and Bob acting, the episode reaches its horizon, and David gets no result after leaving."""
    trace = tmp_path / "t.jsonl"
    async with world_on_loopback(seed=0, horizon=HORIZON, schedule="sequential", trace=trace) as world:
        events = await _Events.observe(world)
        gated = _Gated("david" if on_turn else "alice", K)
        agents = {r: await world.agent(r, gated if r == gated.robot else "heuristic") for r in ROBOTS}
        await asyncio.wait_for(gated.reached.wait(), WAIT)  # the world now waits for the gated robot's tick-K action
        await _detach(agents["david"])
        detached = await events.first(lambda ev: isinstance(ev, RobotDetached))
        gated.release.set()  # Alice plans on (a no-op when David was the gated one: its task is gone)
        done = await world.done(WAIT)
        ends = await asyncio.wait_for(asyncio.gather(agents["alice"], agents["bob"]), WAIT)

    assert isinstance(detached, RobotDetached) and detached.robot == "david" and detached.tick == K
    assert done.reason == "horizon" and done.metrics.temporal_steps == HORIZON, done
    assert all(e is not None and e.reason == "horizon" for e in ends)
    results = messages(read_records(trace), ActionResult)
    finals = [m for m in results if m.done]
    assert sorted((m.robot, m.tick) for m in finals) == [("alice", HORIZON - 1), ("bob", HORIZON - 1)]
    assert {r: g for r, g in done.final_results.items() if r != "david"} == {m.robot: m.goal_id for m in finals}
    # David's entry, if the world names one, can only be the last result it got before it left
    assert done.final_results.get("david") in (None, [m.goal_id for m in results if m.robot == "david"][-1])

    ticks = _ticks_closed(trace)
    assert [t.tick for t in ticks] == list(range(HORIZON)), "every tick closes, after the detach too"
    assert [sorted(t.actions) for t in ticks] == [sorted(ROBOTS)] * K + [["alice", "bob"]] * (HORIZON - K)

    executed = _executed(trace)
    # Alice and Bob get every turn to the end
    assert [(t, r) for t, r, _, _ in executed if r != "david"] == [
        (t, r) for t in range(HORIZON) for r in ("alice", "bob")
    ]
    # David's results: on its turn in tick K it had received its tick K-1 result (released at that
    # turn); while Alice planned, its tick K-1 action had executed but its result was still held
    # for its turn, and a detached robot's held result is dropped
    assert [t for t, r, _, _ in executed if r == "david"] == list(range(K if on_turn else K - 1))
    left = _key_index(trace, lambda line: isinstance(line.msg, RobotDetached))
    assert len(left) == 1
    assert all(i < left[0] for i in _key_index(trace, lambda line: line.key.endswith("robot/david/action/result"))), (
        "no result for David after it left"
    )
    assert not [line for line in read_records(trace)[left[0] :] if line.key.endswith("robot/david/turn")], (
        "no turn for David after it left"
    )
    # the detach happened on a live episode: the world kept publishing ticks after it
    assert _key_index(trace, lambda line: isinstance(line.msg, TickClosed) and line.msg.tick == K)[0] > left[0]


async def test_sequential_gives_turns_to_a_replacement_agent(tmp_path: Path) -> None:
    """David's agent dies on its turn in tick K; a new agent for David attaches in tick K+2
    (while Alice plans, first in the order) and is asked in that tick and every one after it;
    the episode ends at its horizon for everyone, the replacement included."""
    trace = tmp_path / "t.jsonl"
    back = K + 2
    async with world_on_loopback(seed=0, horizon=HORIZON, schedule="sequential", trace=trace) as world:
        events = await _Events.observe(world)
        david, alice = _Gated("david", K), _Gated("alice", back)
        agents = {r: await world.agent(r, {"alice": alice, "david": david}.get(r) or "heuristic") for r in ROBOTS}
        await asyncio.wait_for(david.reached.wait(), WAIT)
        await _detach(agents["david"])
        await events.first(lambda ev: isinstance(ev, RobotDetached) and ev.robot == "david")
        await asyncio.wait_for(alice.reached.wait(), WAIT)  # tick K+2, ticks K and K+1 closed without David
        replacement = await world.agent("david", "heuristic")
        again = await events.first(lambda ev: isinstance(ev, RobotAttached) and ev.robot == "david" and ev.tick > 0)
        alice.release.set()
        done = await world.done(WAIT)
        ends = await asyncio.wait_for(asyncio.gather(agents["alice"], agents["bob"], replacement), WAIT)

    assert isinstance(again, RobotAttached) and again.tick == back
    assert done.reason == "horizon" and done.metrics.temporal_steps == HORIZON, done
    assert all(e is not None and e.reason == "horizon" for e in ends), ends
    finals = [m for m in messages(read_records(trace), ActionResult) if m.done]
    assert sorted(m.robot for m in finals) == sorted(ROBOTS) and all(m.tick == HORIZON - 1 for m in finals)
    assert done.final_results == {m.robot: m.goal_id for m in finals}

    attached = _events(trace, "robot_attached")
    davids = [a for a in attached if a.robot == "david"]
    assert [a.tick for a in davids] == [0, back] and davids[0].agent_id != davids[1].agent_id
    assert [d.robot for d in _events(trace, "robot_detached")] == ["david"]

    ticks = _ticks_closed(trace)
    assert [t.tick for t in ticks] == list(range(HORIZON))
    with_david = [t.tick for t in ticks if "david" in t.actions]
    assert with_david == [*range(K), *range(back, HORIZON)], (
        "David acts before it left and in every tick from its return"
    )

    executed = _executed(trace)
    assert [t for t, r, _, _ in executed if r == "david"] == [*range(K), *range(back, HORIZON)]
    assert [(t, r) for t, r, _, _ in executed if r != "david"] == [
        (t, r) for t in range(HORIZON) for r in ("alice", "bob")
    ]
    # the replacement attached off its turn (Alice was planning), so it waited for a Turn, given
    # after Bob's tick K+2 action executed
    turns = [(m.robot, m.tick) for m in messages(read_records(trace), Turn)]
    assert turns == [("bob", 0), ("david", 0), ("david", back)]


# --------------------------------------------------------------------------- messages change scene graphs on delivery


class _Teller:
    """Bob's policy: at his first turn he tells David about the first object he sees."""

    name = "teller"

    def __init__(self) -> None:
        self.named: str | None = None

    async def decide(self, obs: Observation) -> Decision:
        from mhrc.core.protocol import Communicate, Wait

        if self.named is None and obs.objects:
            self.named = obs.objects[0].name
            return Decision(action=Communicate(content=f"The {self.named} is on my table.", to="david"))
        return Decision(action=Wait())

    def record(self, result: ActionResult) -> None:
        pass


class _Listener:
    """David's policy: waits, keeping every observation it planned on."""

    name = "listener"

    def __init__(self) -> None:
        self.observations: list[Observation] = []

    async def decide(self, obs: Observation) -> Decision:
        from mhrc.core.protocol import Wait

        self.observations.append(obs)
        return Decision(action=Wait())

    def record(self, result: ActionResult) -> None:
        pass


@pytest.mark.parametrize("schedule", ["sequential", "lockstep"])
async def test_a_message_reaches_the_scene_graph_with_its_delivery(schedule: str, tmp_path: Path) -> None:
    """Sequential: Bob tells David of an object in tick 0; David acts after Bob in that tick and
    must not know it yet; he learns it in tick 1, when the message arrives with it. Lockstep:
    message and scene graph arrive together with the results of tick 0."""
    from mhrc.testing import ScriptedPolicy, run_episode

    teller, listener = _Teller(), _Listener()
    result = await run_episode(
        {"alice": ScriptedPolicy([]), "bob": teller, "david": listener},
        seed=0,
        horizon=3,
        schedule=schedule,
        trace=tmp_path / "t.jsonl",
    )
    assert teller.named is not None
    seen = [
        (o.tick, [m.sender for m in o.new_messages], any(x.name == teller.named for x in o.objects))
        for o in listener.observations
    ]
    assert seen[0] == (0, [], False), seen  # tick 0: Bob's message is on its way, David knows nothing of it
    assert seen[1] == (1, ["bob"], True), seen  # tick 1: the message and what it tells arrive together
    assert result.done.metrics.messages == 1
