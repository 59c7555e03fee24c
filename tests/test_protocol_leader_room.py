"""The leader protocol's heuristic form with more robots than stand poses: an idle robot keeps out
of the way. Whole episodes on real PyBullet and real Zenoh (loopback) that were lost before: a
fetcher idle at the finisher's table backs far enough for the next fetcher's arm; a robot refused
a stand pose asks the idle occupant to make way (in the protocol's own sentence), and it leaves;
a robot parked at an empty furniture stays there."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from mhrc.agents.protocols import leader_talk
from mhrc.agents.protocols.leader import LeaderPolicy
from mhrc.core.protocol import ActionResult, Communicate, Navigate
from mhrc.core.records import read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.world.teams import SHIPPED


def test_a_robot_asked_to_make_way_forgets_its_parking() -> None:
    p = LeaderPolicy("erin", ("alice", "erin"))
    p.parked = "counter"
    p._hear(leader_talk.MakeWay("alice", "erin", "counter"))
    assert p.make_way == "counter" and p.parked is None
    p._hear(leader_talk.MakeWay("alice", "david", "sofa"))  # asked of another robot: not mine
    assert p.make_way == "counter"


async def _episode(team: str, task: str, scene: str, n: int, trace: Path) -> list[ActionResult]:
    cfg = EpisodeConfig.build(
        protocol="leader",
        team=SHIPPED[team],
        task=task,
        scene=scene,
        n_objects=n,
        seed=0,
        horizon=50,
        schedule="sequential",
        trace=trace,
    ).resolved()
    done = await asyncio.wait_for(up_in_process(cfg), 300)
    assert done.metrics.success, (done.reason, done.metrics)
    return [r.msg for r in read_records(trace) if isinstance(r.msg, ActionResult)]


@pytest.mark.slow
async def test_a_fetcher_idle_at_the_finishers_table_leaves_room_for_the_next(tmp_path: Path) -> None:
    """`large`, pack_objects in the bedroom: Alice, done at table_0 and unable to park, backs away
    (1 m, not 0.5: Carol's arm at the same stand pose found its start in collision with her)."""
    results = await _episode("large", "pack_objects", "bedroom", 3, tmp_path / "t.jsonl")
    idle = [r for r in results if r.robot in ("david", "erin", "lucy") and isinstance(r.action, Navigate)]
    parks = [r.action.target for r in idle if r.tick > 12]  # after their jobs: each parks once, not to and fro
    assert len(parks) == len(set(parks)), parks


@pytest.mark.slow
async def test_a_refused_robot_asks_the_idle_occupant_to_make_way(tmp_path: Path) -> None:
    """`full_house`, sort_solids in the bathroom: Erin, a base that cannot `move`, stays idle at the
    furniture it explored; a fetcher sent there asks it to make way, and it goes."""
    results = await _episode("full_house", "sort_solids", "bathroom", 6, tmp_path / "t.jsonl")
    asks = [
        leader_talk.parse(r.action.content)
        for r in results
        if isinstance(r.action, Communicate) and isinstance(leader_talk.parse(r.action.content), leader_talk.MakeWay)
    ]
    assert asks, "nobody had to ask"
