"""The world's time policies: the registry, its error for unknown names, and determinism
(same seed, same deterministic team => the same actions and outcomes, tick by tick)."""

from __future__ import annotations

import asyncio
import typing
from pathlib import Path

import pytest
from sweep import sweep
from watched_sim import watched

from mhrc.agents.agent import RobotAgent
from mhrc.agents.heuristic import heuristic_policy
from mhrc.agents.policy import Decision
from mhrc.core.bus import Bus
from mhrc.core.protocol import Action, ActionResult, EpisodeStarted, Observation, SkillOutcome, Turn
from mhrc.core.records import messages, read_records
from mhrc.run.config import ROBOTS, SCHEDULES, ConfigError, EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.run.processes import up_processes
from mhrc.world.scene import LAYOUTS
from mhrc.world.schedulers import SCHEDULERS, LockstepScheduler, Scheduler, SequentialScheduler, UnknownScheduler
from mhrc.world.service import WorldService
from mhrc.world.service_config import WorldConfig
from mhrc.world.sim import Sim


def test_registry_has_lockstep() -> None:
    assert SCHEDULERS["lockstep"] is LockstepScheduler
    assert all(issubclass(cls, Scheduler) and cls.name == name for name, cls in SCHEDULERS.items())
    assert WorldConfig(run="r").schedule == "lockstep"


async def test_unknown_schedule_names_the_known_ones() -> None:
    sim = Sim(task="pack_objects", scene="kitchen", seed=0, n_objects=3)
    bus = await Bus.open()
    try:
        with pytest.raises(UnknownScheduler, match=r"unknown schedule 'warp'.*lockstep") as err:
            WorldService(bus, sim, WorldConfig(run="r", schedule="warp"))
        assert isinstance(err.value, ValueError)
        assert WorldService(bus, sim, WorldConfig(run="r")).scheduler.name == "lockstep"
    finally:
        await bus.close()
        sim.close()


def _executed(trace: Path) -> list[tuple[int, str, str, str]]:
    """(tick, robot, action, feedback) of every action result in a trace, in the order recorded
    (the recorder shares the world's session, so that is the order the world released them)."""
    return [(m.tick, m.robot, m.action.call(), m.outcome.feedback) for m in messages(read_records(trace), ActionResult)]


async def test_same_seed_same_actions_and_outcomes(tmp_path: Path) -> None:
    runs = []
    for name in ("a", "b"):
        done = await up_in_process(EpisodeConfig.build(seed=0, horizon=6, trace=tmp_path / f"{name}.jsonl").resolved())
        assert done.reason == "horizon" and done.metrics.temporal_steps == 6
        runs.append(_executed(tmp_path / f"{name}.jsonl"))
    a, b = runs
    assert [(tick, robot) for tick, robot, _, _ in a] == [(t, r) for t in range(6) for r in ("alice", "bob", "david")]
    assert a == b


# --------------------------------------------------------------------------- sequential (the paper's Algorithm 1)


def test_registry_has_sequential_and_the_cli_offers_every_schedule() -> None:
    assert SCHEDULERS["sequential"] is SequentialScheduler
    assert SCHEDULES == tuple(SCHEDULERS)  # mhrc.world.schedules: the registry's names, in its order
    assert typing.get_args(EpisodeConfig.model_fields["schedule"].annotation) == SCHEDULES
    assert EpisodeConfig.build().schedule == "lockstep"
    with pytest.raises(ConfigError, match="--schedule"):
        EpisodeConfig.build(schedule="warp")


def test_unknown_schedule_option_is_a_usage_error() -> None:
    from click.testing import CliRunner

    from mhrc.cli import main

    for command in ("up", "world", "eval"):
        result = CliRunner().invoke(main, [command, "--schedule", "warp"])
        assert result.exit_code == 2 and "'warp' is not one of 'sequential', 'lockstep'" in result.output, result.output


@pytest.mark.slow
async def test_sequential_same_trace_in_one_process_or_many(tmp_path: Path) -> None:
    a = await up_in_process(
        EpisodeConfig.build(seed=0, horizon=8, schedule="sequential", trace=tmp_path / "a.jsonl").resolved()
    )
    b = await up_processes(
        EpisodeConfig.build(seed=0, horizon=8, schedule="sequential", trace=tmp_path / "b.jsonl").resolved()
    )
    assert a.reason == b.reason == "horizon" and a.metrics.temporal_steps == b.metrics.temporal_steps == 8
    ta, tb = _executed(tmp_path / "a.jsonl"), _executed(tmp_path / "b.jsonl")
    # results go out one at a time, each at its robot's next turn (the last tick's together at the end)
    assert [(tick, robot) for tick, robot, _, _ in ta] == [(t, r) for t in range(8) for r in ("alice", "bob", "david")]
    assert ta == tb
    for name in ("a", "b"):
        started = messages(read_records(tmp_path / f"{name}.jsonl"), EpisodeStarted)
        assert [m.scheduler for m in started] == ["sequential"]
    turns = [m.robot for m in messages(read_records(tmp_path / "a.jsonl"), Turn)]
    assert turns == ["bob", "david"]  # tick 0: Alice plans on the attach reply, the others wait for their turn
    finals = messages(read_records(tmp_path / "a.jsonl"), ActionResult)[-3:]
    assert all(m.done and m.tick == 7 for m in finals)
    assert set(a.final_results) == {"alice", "bob", "david"}
    assert a.final_results == {m.robot: m.goal_id for m in finals}


class _Recording:
    """The heuristic policy of `robot`, noting each decision in a log shared with the simulator."""

    def __init__(self, robot: str, events: list[tuple[str, ...]], seen: dict[tuple[str, int], Observation]) -> None:
        self.robot = robot
        self.name = "recording"
        self.inner = heuristic_policy(robot)
        self.events = events
        self.seen = seen

    async def decide(self, obs: Observation) -> Decision:
        self.events.append(("decide", self.robot, str(obs.tick)))
        self.seen[(self.robot, obs.tick)] = obs
        return await self.inner.decide(obs)

    def record(self, result: ActionResult) -> None:
        self.inner.record(result)


async def test_sequential_is_algorithm_1(mhrc_world) -> None:  # type: ignore[no-untyped-def]
    """Within a tick the robots plan and act one at a time, in order, each on the world the earlier
    ones left: robot k decides only after robot k-1's action of the same tick executed, and the
    observation it decides on already shows that action's effect."""
    events: list[tuple[str, ...]] = []
    seen: dict[tuple[str, int], Observation] = {}
    decided: dict[str, str] = {}  # robot -> the tick of its last decision

    def logged(robot: str, action: Action, outcome: SkillOutcome) -> None:
        decided.update({e[1]: e[2] for e in events if e[0] == "decide"})
        events.append(("execute", robot, decided.get(robot, "?"), action.call(), str(outcome.succeeded)))

    horizon = 12
    async with mhrc_world(seed=0, horizon=horizon, schedule="sequential", simulator=watched(logged)) as world:
        buses = [await world.client() for _ in ROBOTS]
        try:
            agents = [
                RobotAgent(bus, _Recording(r, events, seen), run=world.config.run, robot=r)
                for bus, r in zip(buses, ROBOTS)
            ]  # type: ignore[arg-type]
            dones = await asyncio.wait_for(asyncio.gather(*(a.run() for a in agents)), 120)
            done = await world.done()
        finally:
            for bus in buses:
                await bus.close()
    assert done.reason == "horizon" and all(d is not None and d.reason == "horizon" for d in dones)
    order = [event[:3] for event in events]
    assert order == [(kind, r, str(t)) for t in range(horizon) for r in ROBOTS for kind in ("decide", "execute")], (
        "robots must plan and act one at a time, in order, on the observation of the tick they act in"
    )
    # Alice hands objects to Bob on table_0: Bob plans that same tick on a world where they lie there
    handed = [
        (int(t), call)
        for kind, robot, t, *rest in events
        if kind == "execute" and robot == "alice"
        for call, ok in [rest]
        if ok == "True" and call.startswith("place(") and call.endswith(", table_0)")
    ]
    assert handed, "the heuristic Alice places something on Bob's table within the horizon"
    for tick, call in handed:
        obj = call.removeprefix("place(").split(",")[0]
        assert any(o.name == obj and o.on == "table_0" for o in seen[("bob", tick)].objects), (tick, call)


@pytest.mark.parametrize(
    ("task", "scene"),
    sweep([(t, s) for s in sorted(LAYOUTS) for t in ("pack_objects", "sort_solids", "make_sandwich")]),
)
async def test_heuristic_team_solves_every_task_in_sequence(task: str, scene: str, tmp_path: Path) -> None:
    cfg = EpisodeConfig.build(
        task=task, scene=scene, seed=0, n_objects=4, schedule="sequential", trace=tmp_path / "t.jsonl"
    )
    done = await up_in_process(cfg.resolved())
    assert done.reason == "success" and done.metrics.success, (task, scene, done.metrics)


async def test_sequential_skips_a_robot_that_never_attached(tmp_path: Path) -> None:
    """Alice, first in the order, is missing: Bob gets the first turn when the episode starts."""
    cfg = EpisodeConfig.build(
        seed=0, horizon=3, schedule="sequential", start_timeout=2, trace=tmp_path / "t.jsonl"
    ).resolved()
    done = await asyncio.wait_for(up_in_process(cfg, robots=("bob", "david")), 60)
    assert done.reason == "horizon" and done.metrics.temporal_steps == 3 and set(done.final_results) == {"bob", "david"}
    lines = read_records(tmp_path / "t.jsonl")
    assert [m.robot for m in messages(lines, Turn)] == ["bob", "david"]
    assert [(t, r) for t, r, _, _ in _executed(tmp_path / "t.jsonl")] == [
        (t, r) for t in range(3) for r in ("bob", "david")
    ]
