"""The async schedule (world/schedulers/asynchronous.py): no step barrier, actions take simulated
time, results go out when it has passed. Options and their errors, the heuristic team in every
task and scene, a slow robot that does not hold back the fast ones, two robots going for one
object, a request while the robot's previous action still runs, and a clock against wall time."""

from __future__ import annotations

import asyncio
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from sweep import sweep

from mhrc.agents.agent import RobotAgent
from mhrc.agents.parse import parse_command
from mhrc.analysis.metrics import from_trace
from mhrc.cli import main
from mhrc.core.bus import Bus
from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionAck, ActionRequest, ActionResult, EpisodeStarted, Pick, Wait, decode
from mhrc.core.records import TraceLine, messages, read_records
from mhrc.run.config import ConfigError, EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.testing import ModelReply, ScriptedModelServer, ScriptedPolicy, run_episode, world_on_loopback
from mhrc.world.scene import LAYOUTS
from mhrc.world.schedulers import SCHEDULERS, STEP_SECONDS, AsyncScheduler, SchedulerOptionError
from mhrc.world.service import WorldService
from mhrc.world.service_config import WorldConfig
from mhrc.world.sim import Sim

WAIT = 180.0  # s: a bound on every wait, so that a regression fails instead of hanging


def _results(trace: Path) -> list[ActionResult]:
    return messages(read_records(trace), ActionResult)


# --------------------------------------------------------------------------- options


def test_async_is_registered_and_its_options_are_checked() -> None:
    assert SCHEDULERS["async"] is AsyncScheduler
    assert EpisodeConfig.build(schedule="async", time_scale=2.5).time_scale == 2.5
    with pytest.raises(ConfigError, match=r"^--time-scale: .*greater than or equal to 0"):
        EpisodeConfig.build(schedule="async", time_scale=-1)
    with pytest.raises(ConfigError, match=r"^--time-scale: only the async schedule"):
        EpisodeConfig.build(schedule="lockstep", time_scale=2)
    for argv in (
        ["up", "--schedule", "async", "--time-scale", "-1"],
        ["world", "--schedule", "async", "--time-scale", "-0.5"],
    ):
        result = CliRunner().invoke(main, argv)
        assert result.exit_code == 2 and "--time-scale" in result.output and "Traceback" not in result.output, (
            result.output
        )
    result = CliRunner().invoke(main, ["eval", "--schedule", "async", "--time-scale", "nan"])
    assert result.exit_code == 2, result.output


async def test_the_scheduler_refuses_a_negative_time_scale() -> None:
    sim = Sim(task="pack_objects", scene="kitchen", seed=0, n_objects=3)
    bus = await Bus.open()
    try:
        with pytest.raises(SchedulerOptionError, match="--time-scale"):
            WorldService(bus, sim, WorldConfig(run="r", schedule="async", time_scale=-1.0))
    finally:
        await bus.close()
        sim.close()


# --------------------------------------------------------------------------- the heuristic team


@pytest.mark.parametrize(
    ("task", "scene"),
    sweep([(t, s) for s in sorted(LAYOUTS) for t in ("pack_objects", "sort_solids", "make_sandwich")]),
)
async def test_heuristic_team_solves_every_task_async(task: str, scene: str, tmp_path: Path) -> None:
    trace = tmp_path / "t.jsonl"
    cfg = EpisodeConfig.build(task=task, scene=scene, seed=0, n_objects=4, schedule="async", trace=trace)
    done = await asyncio.wait_for(up_in_process(cfg.resolved()), WAIT)
    assert done.reason == "success" and done.metrics.success, (task, scene, done.metrics)
    m = from_trace(read_records(trace))
    # TS is the makespan in steps of STEP_SECONDS; the trace and the world agree on both
    assert m.scheduler == "async" and m.makespan == pytest.approx(done.metrics.makespan, abs=1e-3)
    assert (
        m.temporal_steps == done.metrics.temporal_steps
        and (m.temporal_steps - 1) * STEP_SECONDS < m.makespan <= m.temporal_steps * STEP_SECONDS
    )
    results = _results(trace)
    assert len({r.goal_id for r in results}) == len(results), "a result went out twice"
    for robot in cfg.robots:
        own = [r for r in results if r.robot == robot]
        assert [r.tick for r in own] == list(range(len(own))), "a robot's ticks are its own step count"
        # a robot's actions never overlap and never start before the one executed before them
        assert all(a.ended <= b.started + 1e-9 for a, b in zip(own, own[1:]))
        assert m.busy[robot] + m.idle[robot] == pytest.approx(m.makespan, abs=0.01)
        assert m.actions_per_robot[robot] == len(own)
    starts = [r.started for r in results]
    assert starts == sorted(starts), (
        "the clock never runs backwards (0 = as fast as possible: results go out as executed)"
    )
    assert results[-1].done and results[-1].ended == pytest.approx(m.makespan, abs=1e-3)


# --------------------------------------------------------------------------- a slow robot


def _robot_of(body: dict[str, Any]) -> str:
    return body["messages"][0]["content"].split(",")[0].removeprefix("You are ").lower()


@pytest.mark.slow
@pytest.mark.parametrize("schedule", ["async", "lockstep"])
async def test_a_slow_robot_does_not_hold_back_the_fast_ones(schedule: str, tmp_path: Path) -> None:
    """Scripted replies (every robot waits), David's model answers in 2 s, the others' in 0.05 s:
    in lockstep every robot acts once per tick, in async the fast ones act many times meanwhile.
    (Async, as fast as possible: the budget of 10 steps is 80 one-second waits, which take the
    fast robots at least 80 x 0.05 s of model latency, so David has time for at least one.)"""
    latency = {"alice": 0.05, "bob": 0.05, "david": 2.0}

    server = ScriptedModelServer(
        lambda body: ModelReply("Command: wait()", latency=latency[_robot_of(body)]), when_done=None
    )
    try:
        trace = tmp_path / "t.jsonl"
        cfg = EpisodeConfig.build(
            seed=0,
            horizon=10 if schedule == "async" else 3,
            schedule=schedule,
            llm="openai:scripted",
            base_url=server.url,
            trace=trace,
        )
        done = await asyncio.wait_for(up_in_process(cfg.resolved()), WAIT)
    finally:
        server.close()
    assert done.reason == "horizon"
    counts = Counter(r.robot for r in _results(trace))
    calls = Counter(_robot_of(body) for body in server.requests)
    if schedule == "lockstep":
        assert counts == {"alice": 3, "bob": 3, "david": 3}
    else:
        assert counts["david"] >= 1 and min(counts["alice"], counts["bob"]) >= 3 * counts["david"], counts
        assert calls["alice"] >= counts["alice"] and calls["david"] <= counts["david"] + 1, calls
        assert done.metrics.makespan == pytest.approx(10 * STEP_SECONDS) and done.metrics.temporal_steps == 10


# --------------------------------------------------------------------------- two robots, one object


@pytest.mark.slow
async def test_two_robots_go_for_the_same_object(tmp_path: Path) -> None:
    """Alice brings the soap to Bob's table and reaches for it again as Bob does: whichever
    request the world executes first gets it, the other fails with the feedback any robot would
    get; each request has exactly one result, and the soap is held by one robot."""
    trace = tmp_path / "t.jsonl"
    alice = ScriptedPolicy(
        [
            "navigate(cabinet_1, 0)",
            "open(cabinet_1)",
            "pick(soap)",
            "navigate(table_0, 0)",
            "place(soap, table_0)",
            "pick(soap)",
        ]
    )
    bob = ScriptedPolicy(
        ["pick(soap)"], until=lambda obs: any(o.name == "soap" and o.on == "table_0" for o in obs.objects)
    )
    episode = {"seed": 0, "horizon": 12, "schedule": "async", "start_timeout": 5.0, "trace": trace}
    done = (await run_episode({"alice": alice, "bob": bob, "david": None}, timeout=WAIT, **episode)).done  # no David
    assert done.reason == "horizon"
    picks = [r for r in _results(trace) if r.action == Pick(obj="soap")]
    assert [r.robot for r in picks[:1]] == ["alice"]  # her first pick, in cabinet_1
    contest = picks[1:]
    assert sorted(r.robot for r in contest) == ["alice", "bob"], contest
    winners = [r for r in contest if r.outcome.succeeded]
    losers = [r for r in contest if not r.outcome.succeeded]
    assert len(winners) == 1 and len(losers) == 1, contest
    assert f"held by {winners[0].robot}" in losers[0].outcome.feedback.lower(), losers[0].outcome
    holding = {r: p.results[-1].observation.status.holding for r, p in (("alice", alice), ("bob", bob)) if p.results}
    assert sorted(holding.values(), key=str) == sorted([None, "soap"], key=str), holding
    # nothing duplicated, nothing lost: every accepted request has exactly one result
    lines = read_records(trace)
    accepted = [a.goal_id for a in messages(lines, ActionAck) if a.accepted]
    released = [r.goal_id for r in _results(trace)]
    assert len(released) == len(set(released)) and set(released) <= set(accepted)
    assert set(accepted) - set(released) <= set(done.final_results.values()) | _unfinished(lines), (
        "an accepted request got no result"
    )
    script = [
        "navigate(cabinet_1, 0)",
        "open(cabinet_1)",
        "pick(soap)",
        "navigate(table_0, 0)",
        "place(soap, table_0)",
        "pick(soap)",
    ]
    assert [r.action.call() for r in alice.results[:6]] == script and all(
        r.outcome.succeeded for r in alice.results[:5]
    )


def _unfinished(lines: list[TraceLine]) -> set[str]:
    """Goal ids of requests sent after the last result each robot got (the episode ended first)."""
    last: dict[str, int] = {}
    for i, line in enumerate(lines):
        if isinstance(line.msg, ActionResult):
            last[line.msg.robot] = i
    return {
        line.msg.goal_id
        for i, line in enumerate(lines)
        if isinstance(line.msg, ActionRequest) and i > last.get(line.msg.robot, -1)
    }


# --------------------------------------------------------------------------- a request while the previous one runs


@pytest.mark.slow
async def test_a_request_while_the_previous_action_runs_is_rejected_and_nothing_is_lost(tmp_path: Path) -> None:
    """On a clock at real time, Alice's navigation takes seconds: a second request meanwhile is
    rejected with the reason, and the first one's result still comes."""
    async with world_on_loopback(
        seed=0, horizon=5, schedule="async", time_scale=1.0, start_timeout=3.0, trace=tmp_path / "t.jsonl"
    ) as world:
        cfg = world.config
        bus = await world.client()
        keys = Keys(cfg.run)
        acks: asyncio.Queue[ActionAck] = asyncio.Queue()
        results: asyncio.Queue[ActionResult] = asyncio.Queue()
        bus.subscribe(keys.action_ack("alice"), lambda s: acks.put_nowait(decode(s.payload, ActionAck)))
        bus.subscribe(keys.action_result("alice"), lambda s: results.put_nowait(decode(s.payload, ActionResult)))
        agent = RobotAgent(bus, ScriptedPolicy([]), run=cfg.run, robot="alice")
        obs = await asyncio.wait_for(agent._attach(), 30)  # attach (and declare liveliness) as an agent would
        assert obs is not None and obs.tick == 0
        first = ActionRequest(
            robot="alice", agent_id=agent.agent_id, tick=0, action=parse_command("Command: navigate(table_0, 0)")
        )
        bus.put(keys.action_request("alice"), first)
        assert (await asyncio.wait_for(acks.get(), 30)).accepted
        sent = asyncio.get_running_loop().time()
        second = ActionRequest(robot="alice", agent_id=agent.agent_id, tick=1, action=Wait())
        bus.put(keys.action_request("alice"), second)
        ack = await asyncio.wait_for(acks.get(), 30)
        assert ack.goal_id == second.goal_id and not ack.accepted
        assert "alice is still busy with navigate(table_0, 0)" in ack.reason and ack.code == "busy", ack
        result = await asyncio.wait_for(results.get(), 60)
        waited = asyncio.get_running_loop().time() - sent
        assert (
            result.goal_id == first.goal_id
            and result.tick == 0
            and result.observation.tick == 1
            and result.outcome.succeeded
        )
        assert result.ended is not None and result.started is not None and result.ended - result.started >= 0.5
        # the clock runs at real time: the result is held until its simulated duration has passed
        assert waited >= 0.9 * (result.ended - result.started), (waited, result.started, result.ended)
        stale = ActionRequest(robot="alice", agent_id=agent.agent_id, tick=0, action=Wait())
        bus.put(keys.action_request("alice"), stale)
        ack = await asyncio.wait_for(acks.get(), 30)
        assert not ack.accepted and "is for tick 0 but alice is at tick 1" in ack.reason and ack.code == "stale_tick"
    started = messages(read_records(tmp_path / "t.jsonl"), EpisodeStarted)
    assert (
        started
        and started[0].scheduler == "async"
        and started[0].time_scale == 1.0
        and started[0].step_seconds == STEP_SECONDS
    )


@pytest.mark.slow
async def test_async_runs_across_processes_with_its_time_scale(tmp_path: Path) -> None:
    """`--processes` gives the world process the schedule and its time scale (parsed back by the CLI)."""
    from mhrc.cli.world import world as world_command_cli
    from mhrc.run.processes import up_processes, world_command

    cfg = EpisodeConfig.build(seed=0, schedule="async", time_scale=40.0, trace=tmp_path / "t.jsonl").resolved()
    argv = world_command(cfg)[3:]  # after `python -m mhrc`
    assert (
        argv[0] == "world"
        and argv[argv.index("--schedule") + 1] == "async"
        and argv[argv.index("--time-scale") + 1] == "40.0"
    )
    parsed = world_command_cli.make_context("world", argv[1:])
    assert parsed.params["schedule"] == "async" and parsed.params["time_scale"] == 40.0
    done = await asyncio.wait_for(up_processes(cfg), WAIT)
    assert done.reason == "success"
    started = messages(read_records(tmp_path / "t.jsonl"), EpisodeStarted)
    assert [(m.scheduler, m.time_scale) for m in started] == [("async", 40.0)]
