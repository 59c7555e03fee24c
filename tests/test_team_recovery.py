"""A team that recovers (issue 14): an agent killed mid-episode, with and without a replacement.

The world lists only the teammates attached now in each observation; the heuristic team
re-plans around that: Alice explores the surfaces David would have, hands the rest to a David
that joins, and Bob asks a new Alice again for what he needs. Without the robot only it can
replace (Bob finishes the task, Alice fetches), the world says why the task cannot be finished.

Everything is real: the world and each agent on its own Zenoh session on loopback. An agent is
killed as a crash would: its task cancelled and its session closed (its liveliness goes)."""

from __future__ import annotations

import asyncio
import contextlib
from pathlib import Path
from typing import Any

import pytest

from mhrc.agents.agent import RobotAgent
from mhrc.agents.heuristic import heuristic_policy
from mhrc.bus import Bus
from mhrc.episode import ROBOTS, EpisodeConfig, open_client, serve_world
from mhrc.keys import Keys
from mhrc.protocol import EpisodeDone, RobotDetached, TickClosed, decode_event
from mhrc.trace import read_trace

WAIT = 180.0


class _Team:
    def __init__(self, cfg: EpisodeConfig) -> None:
        self.cfg = cfg
        self.buses: list[Bus] = []
        self.agents: dict[str, tuple[Bus, asyncio.Task[Any]]] = {}
        self.ticks = 0
        self.detached: list[RobotDetached] = []
        self._news = asyncio.Event()

    async def start(self) -> asyncio.Task[EpisodeDone]:
        world = asyncio.create_task(serve_world(self.cfg), name="world")
        observer = await self._bus()
        observer.subscribe(Keys(self.cfg.run).world_event, self._on_event)
        for robot in ROBOTS:
            await self.attach(robot)
        return world

    def _on_event(self, sample: Any) -> None:
        ev = decode_event(sample.payload)
        if isinstance(ev, TickClosed):
            self.ticks = ev.tick + 1
        if isinstance(ev, RobotDetached):
            self.detached.append(ev)
        self._news.set()

    async def _bus(self) -> Bus:
        self.buses.append(await open_client(self.cfg.endpoint, 30.0))
        return self.buses[-1]

    async def attach(self, robot: str) -> None:
        bus = await self._bus()
        task = asyncio.create_task(RobotAgent(bus, heuristic_policy(robot), run=self.cfg.run, robot=robot).run(), name=f"agent-{robot}")
        self.agents[robot] = (bus, task)

    async def kill(self, robot: str) -> None:
        bus, task = self.agents.pop(robot)
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        await bus.close()

    async def until_tick(self, tick: int) -> None:
        async def wait() -> None:
            while self.ticks < tick:
                self._news.clear()
                await self._news.wait()

        await asyncio.wait_for(wait(), WAIT)

    async def close(self) -> None:
        for _bus, task in self.agents.values():
            task.cancel()
        for _bus, task in self.agents.values():
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for bus in self.buses:
            await bus.close()


async def _episode(tmp_path: Path, robot: str, killed_at: int, replaced_at: int | None, horizon: int = 50) -> tuple[EpisodeDone, _Team]:
    cfg = EpisodeConfig.build(seed=0, n_objects=4, horizon=horizon, trace=tmp_path / "t.jsonl").resolved()
    team = _Team(cfg)
    world = await team.start()
    try:
        await team.until_tick(killed_at)
        await team.kill(robot)
        if replaced_at is not None:
            await team.until_tick(replaced_at)
            await team.attach(robot)
        return await asyncio.wait_for(world, WAIT), team
    finally:
        world.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await world
        await team.close()


def _acted_after(trace: Path, robot: str, tick: int) -> list[str]:
    return [
        line["msg"]["action"]["skill"]
        for line in read_trace(trace)
        if line["key"].endswith(f"/robot/{robot}/action/result") and line["msg"]["tick"] > tick and line["msg"]["action"]["skill"] != "wait"
    ]


@pytest.mark.parametrize(
    ("robot", "killed_at", "replaced_at"),
    [("david", 2, None), ("david", 8, None), ("david", 2, 6), ("alice", 4, 7), ("bob", 4, 7)],
)
async def test_the_team_still_succeeds_after_losing_an_agent(robot: str, killed_at: int, replaced_at: int | None, tmp_path: Path) -> None:
    done, team = await _episode(tmp_path, robot, killed_at, replaced_at)
    assert done.reason == "success" and done.metrics.success, (robot, killed_at, replaced_at, done.metrics)
    assert [d.robot for d in team.detached] == [robot]
    # the others can finish without david; without alice or bob the world says so until one comes back
    assert ("nobody attached can" in team.detached[0].reason) == (robot != "david"), team.detached[0].reason
    if replaced_at is not None:
        assert _acted_after(tmp_path / "t.jsonl", robot, replaced_at), f"the replacement {robot} never did anything"


@pytest.mark.parametrize(("robot", "why"), [("bob", "nobody attached can finish the task (only bob places on the goal fixtures)"),
                                            ("alice", "nobody attached can fetch objects from the rooms (only alice navigates and picks)")])  # fmt: skip
async def test_without_the_robot_only_it_can_replace_the_world_says_why(robot: str, why: str, tmp_path: Path) -> None:
    done, team = await _episode(tmp_path, robot, 3, None, horizon=10)
    assert done.reason == "horizon" and not done.metrics.success
    assert len(team.detached) == 1 and why in team.detached[0].reason, team.detached
