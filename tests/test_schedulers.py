"""The world's time policies: the registry, its error for unknown names, and determinism
(same seed, same deterministic team => the same actions and outcomes, tick by tick)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mhrc.bus import Bus
from mhrc.episode import EpisodeConfig, up_in_process
from mhrc.protocol import parse_action
from mhrc.trace import read_trace
from mhrc.world.schedulers import SCHEDULERS, LockstepScheduler, Scheduler, UnknownScheduler
from mhrc.world.service import WorldConfig, WorldService
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
    return [
        (m["tick"], m["robot"], parse_action(m["action"]).call(), m["outcome"]["feedback"])
        for line in read_trace(trace)
        if line["key"].endswith("/action/result") and (m := line["msg"])
    ]


async def test_same_seed_same_actions_and_outcomes(tmp_path: Path) -> None:
    runs = []
    for name in ("a", "b"):
        done = await up_in_process(EpisodeConfig.build(seed=0, horizon=6, trace=tmp_path / f"{name}.jsonl").resolved())
        assert done.reason == "horizon" and done.metrics.temporal_steps == 6
        runs.append(_executed(tmp_path / f"{name}.jsonl"))
    a, b = runs
    assert [(tick, robot) for tick, robot, _, _ in a] == [(t, r) for t in range(6) for r in ("alice", "bob", "david")]
    assert a == b
