"""The world service over real Zenoh on loopback with the real PyBullet world.

A `ManualAgent` here speaks the protocol by hand (attach query, request, ack, result) so each
test can send exactly the message it is about, malformed ones included.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
from structlog.testing import capture_logs
from waits import robots_alive, served
from watched_sim import watched

from mhrc.agents.agent import RobotAgent, WorldGone
from mhrc.agents.heuristic import heuristic_policy
from mhrc.core.bus import Bus, Sample
from mhrc.core.endpoints import endpoint
from mhrc.core.keys import Keys
from mhrc.core.protocol import (
    Action,
    ActionAck,
    ActionRequest,
    ActionResult,
    AttachReply,
    AttachRequest,
    Communicate,
    EpisodeDone,
    EpisodeStarted,
    Navigate,
    OutcomeCode,
    Pick,
    Place,
    RobotDetached,
    SkillOutcome,
    Snapshot,
    Wait,
    decode,
    decode_event,
    encode,
)
from mhrc.core.records import messages, read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.processes import agent_command, wait_for_port, world_command
from mhrc.run.serve import serve_world
from mhrc.world.service import WorldService


class ManualAgent:
    def __init__(self, bus: Bus, run: str, robot: str, agent_id: str | None = None) -> None:
        self.bus, self.robot, self.keys = bus, robot, Keys(run)
        self.agent_id = agent_id or f"manual-{robot}"
        self.acks: asyncio.Queue[ActionAck] = asyncio.Queue()
        self.results: asyncio.Queue[ActionResult] = asyncio.Queue()
        self.events: list[object] = []
        self.started = asyncio.Event()
        self._news = asyncio.Event()
        bus.subscribe(self.keys.action_ack(robot), lambda s: self.acks.put_nowait(decode(s.payload, ActionAck)))
        bus.subscribe(
            self.keys.action_result(robot), lambda s: self.results.put_nowait(decode(s.payload, ActionResult))
        )
        bus.subscribe(self.keys.world_event, self._on_event)
        self.tick = 0

    def _on_event(self, sample: Sample) -> None:
        event = decode_event(sample.payload)
        self.events.append(event)
        self._news.set()
        if isinstance(event, EpisodeStarted):
            self.started.set()

    async def seen(self, match: Callable[[object], bool], timeout: float = 30) -> object:
        """The first world event (seen so far or still to come) for which `match` is true."""

        async def first() -> object:
            while True:
                self._news.clear()
                found = next((event for event in self.events if match(event)), None)
                if found is not None:
                    return found
                await self._news.wait()

        return await asyncio.wait_for(first(), timeout)

    async def attach(self) -> AttachReply:
        await served(self.bus, self.keys.attach(self.robot))  # the world's attach queryable reached this session
        replies = await self.bus.get(
            self.keys.attach(self.robot), AttachRequest(robot=self.robot, agent_id=self.agent_id)
        )
        assert replies, "the world did not answer the attach query"
        reply = decode(replies[0], AttachReply)
        if reply.accepted:
            self.bus.declare_token(self.keys.alive_robot(self.robot))
            self.tick = reply.tick
        return reply

    async def act(self, action: Action) -> tuple[ActionAck, ActionResult | None]:
        req = ActionRequest(robot=self.robot, agent_id=self.agent_id, tick=self.tick, action=action)
        self.bus.put(self.keys.action_request(self.robot), req)
        ack = await asyncio.wait_for(self.acks.get(), 10)
        assert ack.goal_id == req.goal_id
        if not ack.accepted:
            return ack, None
        result = await asyncio.wait_for(self.results.get(), 60)
        assert result.goal_id == req.goal_id
        self.tick = result.tick + 1
        return ack, result


async def test_request_ack_result_and_bad_input(mhrc_world) -> None:  # type: ignore[no-untyped-def]
    # one robot attached, so every tick closes on its action alone
    async with mhrc_world(seed=1, start_timeout=3.0) as world:
        bus = await world.client()
        try:
            alice = ManualAgent(bus, world.config.run, "alice")
            reply = await alice.attach()
            assert reply.accepted and reply.observation is not None
            assert reply.observation.robot == "alice" and reply.horizon == 50
            await asyncio.wait_for(alice.started.wait(), 30)  # the world starts with alice alone, after start_timeout

            ack, res = await alice.act(Navigate(target="table_0", stand_pose=0))
            assert ack.accepted and res is not None
            assert res.outcome.succeeded, res.outcome.feedback
            assert res.observation.tick == 1 and res.tick == 0

            ack, res = await alice.act(Pick(obj="applle"))
            assert res is not None and not res.outcome.succeeded
            assert res.outcome.code == OutcomeCode.OBJECT_UNKNOWN and "applle" in res.outcome.feedback

            ack, res = await alice.act(Navigate(target="table_0", stand_pose=99))
            assert res is not None and res.outcome.code == OutcomeCode.STAND_POSE_INVALID

            ack, res = await alice.act(Place(obj="apple", location="table_0"))
            assert res is not None and res.outcome.code == OutcomeCode.GRIPPER_EMPTY

            ack, res = await alice.act(Communicate(content="hi", to="zed"))
            assert res is not None and res.outcome.code == OutcomeCode.RECIPIENT_UNKNOWN

            # a malformed payload is rejected with a reason; the world goes on
            request_key = Keys(world.config.run).action_request("alice")
            bus.put(
                request_key,
                b'{"v": 1, "goal_id": "bad1", "robot": "alice", "tick": 0, "action": {"skill": "teleport"}}',
            )
            bad = await asyncio.wait_for(alice.acks.get(), 10)
            assert bad.goal_id == "bad1" and not bad.accepted and "malformed" in bad.reason
            bus.put(request_key, b"\x00garbage")
            bad = await asyncio.wait_for(alice.acks.get(), 10)
            assert not bad.accepted and "malformed" in bad.reason

            # a stale tick is rejected, not executed
            alice.tick -= 1
            ack, res = await alice.act(Wait())
            assert not ack.accepted and "tick" in ack.reason
            alice.tick += 1
            ack, res = await alice.act(Wait())
            assert ack.accepted and res is not None and res.outcome.succeeded
        finally:
            await bus.close()


async def test_capabilities_duplicates_and_messages(mhrc_world) -> None:  # type: ignore[no-untyped-def]
    async with mhrc_world(seed=2, start_timeout=3.0) as world:
        bus = await world.client()
        try:
            david = ManualAgent(bus, world.config.run, "david")
            bob = ManualAgent(bus, world.config.run, "bob")
            assert (await david.attach()).accepted
            assert (await bob.attach()).accepted
            impostor = ManualAgent(bus, world.config.run, "david", agent_id="impostor")
            reply = await impostor.attach()
            assert not reply.accepted and "already attached" in reply.reason

            # both submit for tick 0: results come back together
            (ack_d, res_d), (ack_b, res_b) = await asyncio.gather(
                david.act(Pick(obj="apple")), bob.act(Communicate(content="David, hello.", to="david"))
            )
            assert res_d is not None and res_d.outcome.code == OutcomeCode.NOT_CAPABLE
            assert "david" in res_d.outcome.feedback.lower() and "pick" in res_d.outcome.feedback
            assert res_b is not None and res_b.outcome.succeeded
        finally:
            await bus.close()


async def test_message_reaches_receiver_next_tick(mhrc_world) -> None:  # type: ignore[no-untyped-def]
    async with mhrc_world(seed=3, start_timeout=3.0) as world:
        bus = await world.client()
        try:
            alice = ManualAgent(bus, world.config.run, "alice")
            bob = ManualAgent(bus, world.config.run, "bob")
            await alice.attach()
            await bob.attach()
            (_, ra), (_, rb) = await asyncio.gather(
                alice.act(Wait()), bob.act(Communicate(content="Alice, go.", to="alice"))
            )
            assert ra is not None and [m.content for m in ra.observation.new_messages] == ["Alice, go."]
            assert ra.observation.new_messages[0].sender == "bob" and ra.observation.new_messages[0].tick == 0
            (_, ra), _ = await asyncio.gather(alice.act(Wait()), bob.act(Wait()))
            assert ra is not None and ra.observation.new_messages == []
        finally:
            await bus.close()


# --------------------------------------------------------------------------- each goal once, one action a tick (issue 31)
REFUSED_WHILE_EXECUTING = {"sequential": "tick_taken", "lockstep": "tick_taken", "async": "busy"}


@pytest.mark.parametrize("schedule", sorted(REFUSED_WHILE_EXECUTING))
async def test_a_goal_executes_once_and_a_robot_acts_once_a_tick(mhrc_world, schedule: str) -> None:  # type: ignore[no-untyped-def]
    """Alice acts alone (Bob and David leave once the episode started). While her first goal
    executes (the simulator's thread held inside it): the same payload again is refused as a
    duplicate, however often it comes, and logged once an interval, not once a message; a second
    goal for the same tick is refused (async: busy). After the first's result the payload is
    refused again. Nothing refused reaches the simulator: it runs the first goal and the next
    one, in ticks 0 and 1, and the trace has one result and one snapshot for each."""
    first = ActionRequest(
        robot="alice", agent_id="manual-alice", tick=0, action=Navigate(target="table_0", stand_pose=0)
    )
    payload = encode(first)
    ran: asyncio.Queue[str] = asyncio.Queue()  # the calls, as the simulator (tests/watched_sim.py) executes each
    release = threading.Event()
    loop = asyncio.get_running_loop()

    def held(robot: str, action: Action, outcome: SkillOutcome) -> None:
        loop.call_soon_threadsafe(ran.put_nowait, action.call())
        if action == first.action:
            release.wait(60)  # until the test has sent what comes while it executes (bounded: never a hang)

    repeats = 10
    with capture_logs() as logs:
        async with mhrc_world(seed=0, schedule=schedule, simulator=watched(held)) as world:
            bus, team = await world.client(), await world.client()
            try:
                alice = ManualAgent(bus, world.run, "alice")
                assert (await alice.attach()).accepted
                for robot in ("bob", "david"):
                    assert (await ManualAgent(team, world.run, robot).attach()).accepted
                await asyncio.wait_for(alice.started.wait(), 30)
                await team.close()  # bob and david leave: alice's action is each tick's only one
                await alice.seen(lambda event: isinstance(event, RobotDetached) and event.robot == "bob")
                await alice.seen(lambda event: isinstance(event, RobotDetached) and event.robot == "david")
                bus.put(alice.keys.action_request("alice"), payload)
                assert (ack := await asyncio.wait_for(alice.acks.get(), 30)).accepted and ack.goal_id == first.goal_id
                assert await asyncio.wait_for(ran.get(), 30) == first.action.call()  # executing now, no result yet

                for _ in range(repeats):
                    bus.put(alice.keys.action_request("alice"), payload)
                for _ in range(repeats):
                    ack = await asyncio.wait_for(alice.acks.get(), 30)
                    assert (ack.goal_id, ack.accepted, ack.code) == (first.goal_id, False, "duplicate_goal"), ack
                    assert first.goal_id in ack.reason
                second = ActionRequest(robot="alice", agent_id="manual-alice", tick=0, action=Wait())
                bus.put(alice.keys.action_request("alice"), second)
                ack = await asyncio.wait_for(alice.acks.get(), 30)
                assert (ack.goal_id, ack.accepted, ack.code) == (
                    second.goal_id,
                    False,
                    REFUSED_WHILE_EXECUTING[schedule],
                ), ack
                assert ack.reason

                release.set()
                result = await asyncio.wait_for(alice.results.get(), 60)
                assert (result.goal_id, result.tick, result.observation.tick) == (first.goal_id, 0, 1)
                bus.put(alice.keys.action_request("alice"), payload)  # finished: still a goal it sent
                ack = await asyncio.wait_for(alice.acks.get(), 30)
                assert (ack.goal_id, ack.accepted, ack.code) == (first.goal_id, False, "duplicate_goal"), ack

                third = ActionRequest(robot="alice", agent_id="manual-alice", tick=1, action=Wait())
                bus.put(alice.keys.action_request("alice"), third)
                assert (
                    ack := await asyncio.wait_for(alice.acks.get(), 30)
                ).accepted and ack.goal_id == third.goal_id, ack
                result = await asyncio.wait_for(alice.results.get(), 60)
                assert (result.goal_id, result.tick) == (third.goal_id, 1)
            finally:
                release.set()
                await bus.close()  # alice's token goes: the episode ends with nobody attached
            done = await world.done(60)
    assert done.reason == "no_agents" and done.metrics.action_steps == 1  # the navigation, once (waits are not counted)
    assert [ran.get_nowait() for _ in range(ran.qsize())] == [third.action.call()], (
        "after the first, only the third reached the simulator"
    )
    records = read_records(world.trace)
    assert [m.goal_id for m in messages(records, ActionResult)] == [first.goal_id, third.goal_id]
    assert [(m.tick, m.goals) for m in messages(records, Snapshot) if m.goals] == [
        (0, [first.goal_id]),
        (1, [third.goal_id]),
    ]
    lines = [entry for entry in logs if entry["event"] == "duplicate goal rejected"]
    assert 1 <= len(lines) <= 2, lines  # 11 duplicates: a line per 5 s interval, not a line a message
    assert lines[0]["code"] == "duplicate_goal" and lines[0]["goal"] == first.goal_id


# --------------------------------------------------------------------------- a re-attach during a tick (issue 32)
async def test_a_message_sent_while_its_receiver_reattaches_is_delivered_once_and_told(
    mhrc_world, monkeypatch: pytest.MonkeyPatch
) -> None:  # type: ignore[no-untyped-def]
    """Bob tells Alice about an object only he has seen. While the simulator's thread is held
    right after his message was sent (mid-tick), Alice's agent attaches again, and the world
    handles that attach up to its observation. Released, the message reaches Alice exactly once
    (in the attach reply or in her result, not both, not neither), every observation that
    carries it or comes after it knows the object, and no later observation repeats it."""
    release, loop = threading.Event(), asyncio.get_running_loop()
    held: asyncio.Queue[str] = asyncio.Queue()  # senders, as the simulator's thread stops after each message
    observing: asyncio.Queue[str] = asyncio.Queue()  # robots, as the world starts making an observation on the loop
    observe = WorldService.observe

    def hold_after_a_message(robot: str, action: Action, outcome: SkillOutcome) -> None:
        if isinstance(action, Communicate):
            loop.call_soon_threadsafe(held.put_nowait, robot)
            release.wait(60)  # until the test has re-attached Alice (bounded: never a hang)

    async def observe_seen(self: WorldService, robot: str, tick: int):  # type: ignore[no-untyped-def]
        observing.put_nowait(robot)
        return await observe(self, robot, tick)

    monkeypatch.setattr(WorldService, "observe", observe_seen)
    async with mhrc_world(seed=3, start_timeout=3.0, simulator=watched(hold_after_a_message)) as world:
        bus = await world.client()
        try:
            alice, bob = ManualAgent(bus, world.run, "alice"), ManualAgent(bus, world.run, "bob")
            assert (first := await alice.attach()).accepted and first.observation is not None
            assert (reply := await bob.attach()).accepted and reply.observation is not None
            unknown = sorted({o.name for o in reply.observation.objects} - {o.name for o in first.observation.objects})
            assert unknown, "Bob has seen an object Alice has not"
            thing = unknown[0]
            await asyncio.wait_for(alice.started.wait(), 30)
            while not observing.empty():
                observing.get_nowait()  # the attaches' own observations

            acting = asyncio.ensure_future(
                asyncio.gather(
                    alice.act(Wait()), bob.act(Communicate(content=f"Alice, the {thing} is near me.", to="alice"))
                )
            )
            await asyncio.wait_for(held.get(), 30)  # the message is sent, the tick not over
            again = asyncio.ensure_future(alice.attach())
            assert await asyncio.wait_for(observing.get(), 30) == "alice"  # the world is answering her attach, mid-tick
            release.set()
            reattached = await asyncio.wait_for(again, 60)
            (_, result), _ = await asyncio.wait_for(acting, 60)
            assert reattached.accepted and reattached.observation is not None and result is not None

            carried = [m.content for obs in (reattached.observation, result.observation) for m in obs.new_messages]
            assert carried == [f"Alice, the {thing} is near me."], carried
            for obs in (reattached.observation, result.observation):
                assert thing in {o.name for o in obs.objects}, (
                    f"Alice's observation of tick {obs.tick} does not know what Bob told"
                )
            alice.tick = result.tick + 1  # the attach reply said the tick it was asked in, which has closed since
            (_, later), _ = await asyncio.gather(alice.act(Wait()), bob.act(Wait()))
            assert (
                later is not None
                and later.observation.new_messages == []
                and thing in {o.name for o in later.observation.objects}
            )
        finally:
            release.set()
            await bus.close()


@pytest.mark.slow
async def test_world_notices_a_dead_agent_and_goes_on(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """An agent process killed mid-episode: liveliness tells the world, which does not hang."""
    cfg = EpisodeConfig.build(seed=0, horizon=12, trace=tmp_path / "t.jsonl").resolved()
    world_proc = subprocess.Popen(world_command(cfg))
    agents: list[subprocess.Popen[bytes]] = []
    bus = None
    try:
        await asyncio.to_thread(wait_for_port, cfg.host, cfg.port, 60, world_proc)
        bus = await Bus.open(mode="client", connect=[cfg.endpoint])
        events: asyncio.Queue[object] = asyncio.Queue()
        bus.subscribe(Keys(cfg.run).world_event, lambda s: events.put_nowait(decode_event(s.payload)))
        agents = [subprocess.Popen(agent_command(r, cfg)) for r in ("alice", "bob", "david")]
        ticks = 0
        while ticks < 2:  # let the episode run a little
            ev = await asyncio.wait_for(events.get(), 90)
            ticks += ev.kind == "tick"  # type: ignore[attr-defined]
        agents[2].send_signal(signal.SIGKILL)
        detached = done = None
        while done is None:
            ev = await asyncio.wait_for(events.get(), 90)
            if isinstance(ev, RobotDetached):
                detached = ev
            if isinstance(ev, EpisodeDone):
                done = ev
        assert detached is not None and detached.robot == "david"
        assert done.metrics.temporal_steps <= 12
        assert await asyncio.to_thread(world_proc.wait, 30) == 0
        for p in agents[:2]:
            assert await asyncio.to_thread(p.wait, 30) == 0
    finally:
        if bus is not None:
            await bus.close()
        for p in [world_proc, *agents]:
            if p.poll() is None:
                p.kill()
                p.wait()


async def test_agent_fails_fast_when_the_world_vanishes(tmp_path) -> None:  # type: ignore[no-untyped-def]
    cfg = EpisodeConfig.build(seed=0, trace=tmp_path / "t.jsonl").resolved()
    world_proc = subprocess.Popen(world_command(cfg))
    bus = None
    try:
        await asyncio.to_thread(wait_for_port, cfg.host, cfg.port, 60, world_proc)
        bus = await Bus.open(mode="client", connect=[cfg.endpoint])
        # alone, alice's first action never completes: the world waits for bob and david
        agent = RobotAgent(bus, heuristic_policy("alice"), run=cfg.run, robot="alice")
        task = asyncio.create_task(agent.run())
        await robots_alive(bus, cfg.run, {"alice"})  # attached, and waiting for her teammates
        assert not task.done()
        world_proc.send_signal(signal.SIGKILL)
        with pytest.raises(WorldGone):
            await asyncio.wait_for(task, 10)  # the lease is 2 s: far sooner than any timeout
    finally:
        if bus is not None:
            await bus.close()
        if world_proc.poll() is None:
            world_proc.kill()
        world_proc.wait()


async def _forward(world_port: int, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    """One connection to the forwarding port, piped to the world's (closed at once when the world is gone)."""
    try:
        up_reader, up_writer = await asyncio.open_connection("127.0.0.1", world_port)
    except OSError:
        writer.close()
        return

    async def pipe(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
        try:
            while data := await src.read(65536):
                dst.write(data)
                await dst.drain()
        except OSError:
            pass
        finally:
            dst.close()

    await asyncio.gather(pipe(reader, up_writer), pipe(up_reader, writer))


async def test_an_agent_behind_a_port_that_outlives_the_world_fails_once_it_closes(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A port that still listens after the world died (a forwarder in front of it, as docker's
    userland proxy is, or a dying world whose port closes a moment after its links): the agent's
    probe finds it listening and attaches again, and fails as soon as the port closes, not at the
    end of its 30 s attach timeout."""
    cfg = EpisodeConfig.build(seed=0, trace=tmp_path / "t.jsonl").resolved()
    world_proc = subprocess.Popen(world_command(cfg))
    bus = None
    forwarder = await asyncio.start_server(lambda r, w: _forward(cfg.port, r, w), "127.0.0.1", 0)
    try:
        await asyncio.to_thread(wait_for_port, cfg.host, cfg.port, 60, world_proc)
        bus = await Bus.open(mode="client", connect=[endpoint("127.0.0.1", forwarder.sockets[0].getsockname()[1])])
        agent = RobotAgent(bus, heuristic_policy("alice"), run=cfg.run, robot="alice")
        task = asyncio.create_task(agent.run())
        await robots_alive(bus, cfg.run, {"alice"})
        world_proc.send_signal(signal.SIGKILL)
        await asyncio.to_thread(world_proc.wait)
        await asyncio.sleep(3)  # the behaviour under test: the port outlives the world by 3 s
        assert not task.done()
        forwarder.close()
        with pytest.raises(WorldGone, match="did not answer an attach since"):
            await asyncio.wait_for(task, 10)  # an attach attempt takes 2 s; the attach timeout is 30 s
    finally:
        forwarder.close()
        if bus is not None:
            await bus.close()
        if world_proc.poll() is None:
            world_proc.kill()
        world_proc.wait()


def _stray(run: str) -> list[str]:
    found = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                cmd = f.read().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if run in cmd:
            found.append(cmd)
    return found


@pytest.mark.slow
def test_processes_mode_exits_cleanly(tmp_path) -> None:  # type: ignore[no-untyped-def]
    run = "clean-exit-test"
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "mhrc",
            "up",
            "--processes",
            "--quiet",
            "--json",
            "--seed",
            "4",
            "--objects",
            "3",
            "--run",
            run,
            "--trace",
            str(tmp_path / "t.jsonl"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    metrics = json.loads(out.stdout.strip().splitlines()[-1])
    assert metrics["success"] is True and metrics["temporal_steps"] > 0
    assert _stray(run) == []


async def test_the_world_listens_before_an_observer_can_act(tmp_path: Path) -> None:
    """serve_world's observers subscribe before the world exists; the first thing the loop runs
    after them finds the world already serving attaches and requests (WorldService.listen), so
    an observer that reacts at once (a flood, an attach) never meets a world not yet listening."""
    cfg = EpisodeConfig.build(
        seed=1, n_objects=4, horizon=1, start_timeout=60.0, trace=tmp_path / "t.jsonl"
    ).resolved()  # not ./runs/ of the checkout
    services: list[WorldService] = []
    first: asyncio.Future[bool] = asyncio.get_running_loop().create_future()

    def observe(bus: Bus, run: str) -> None:
        asyncio.get_running_loop().call_soon(lambda: first.done() or first.set_result(services[0].listening))

    world = asyncio.create_task(serve_world(cfg, observe=observe, on_service=services.append))
    try:
        assert await asyncio.wait_for(first, 120) is True
    finally:
        world.cancel()
        await asyncio.gather(world, return_exceptions=True)
