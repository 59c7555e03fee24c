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
from sweep import sweep

from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionResult, EpisodeDone, RobotDetached, TickClosed, decode_event
from mhrc.core.records import messages, read_records
from mhrc.testing import world_on_loopback

WAIT = 180.0


async def _episode(
    tmp_path: Path, robot: str, killed_at: int, replaced_at: int | None, horizon: int = 50
) -> tuple[EpisodeDone, list[RobotDetached]]:
    """The heuristic team; `robot`'s agent killed when tick `killed_at` closed, a new one
    started when tick `replaced_at` closed (None: never)."""
    ticks = 0
    detached: list[RobotDetached] = []
    news = asyncio.Event()

    def on_event(sample: Any) -> None:
        nonlocal ticks
        ev = decode_event(sample.payload)
        if isinstance(ev, TickClosed):
            ticks = ev.tick + 1
        if isinstance(ev, RobotDetached):
            detached.append(ev)
        news.set()

    async def until_tick(tick: int) -> None:
        while ticks < tick:
            news.clear()
            await asyncio.wait_for(news.wait(), WAIT)

    async with world_on_loopback(seed=0, n_objects=4, horizon=horizon, trace=tmp_path / "t.jsonl") as world:
        (await world.client()).subscribe(Keys(world.run).world_event, on_event)
        agents = {r: await world.agent(r, "heuristic") for r in ("alice", "bob", "david")}
        await until_tick(killed_at)
        agents[robot].cancel()  # a crash, as the world sees it: the agent's session closes, its liveliness goes
        with contextlib.suppress(asyncio.CancelledError):
            await agents[robot]
        if replaced_at is not None:
            await until_tick(replaced_at)
            await world.agent(robot, "heuristic")
        return await world.done(WAIT), detached


def _acted_after(trace: Path, robot: str, tick: int) -> list[str]:
    return [
        r.action.skill
        for r in messages(read_records(trace), ActionResult)
        if r.robot == robot and r.tick > tick and r.action.skill != "wait"
    ]


@pytest.mark.parametrize(
    ("robot", "killed_at", "replaced_at"),
    sweep([("david", 2, 6), ("alice", 4, 7), ("david", 2, None), ("david", 8, None), ("bob", 4, 7)], fast=2),
)
async def test_the_team_still_succeeds_after_losing_an_agent(
    robot: str, killed_at: int, replaced_at: int | None, tmp_path: Path
) -> None:
    done, detached = await _episode(tmp_path, robot, killed_at, replaced_at)
    assert done.reason == "success" and done.metrics.success, (robot, killed_at, replaced_at, done.metrics)
    assert [d.robot for d in detached] == [robot]
    # the others can finish without david; without alice or bob the world says so until one comes back
    assert ("nobody attached can" in detached[0].reason) == (robot != "david"), detached[0].reason
    if replaced_at is not None:
        assert _acted_after(tmp_path / "t.jsonl", robot, replaced_at), f"the replacement {robot} never did anything"


@pytest.mark.parametrize(
    ("robot", "why"),
    sweep(
        [
            ("alice", "nobody attached can fetch objects from the rooms (only alice navigates and picks)"),
            ("bob", "nobody attached can finish the task (only bob places on the goal fixtures)"),
        ]
    ),
)
async def test_without_the_robot_only_it_can_replace_the_world_says_why(robot: str, why: str, tmp_path: Path) -> None:
    done, detached = await _episode(tmp_path, robot, 3, None, horizon=10)
    assert done.reason == "horizon" and not done.metrics.success
    assert len(detached) == 1 and why in detached[0].reason, detached
