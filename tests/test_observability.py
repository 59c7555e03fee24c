"""Partial observability checked from a trace alone (mhrc.analysis.observability): a real
multi-robot episode passes, and the same trace with one object slipped into a robot's observation
fails, naming the robot, the tick and the object; a message naming it first explains it."""

from __future__ import annotations

import asyncio
from dataclasses import replace

import pytest

from mhrc.analysis.observability import Leak, Unchecked, check
from mhrc.core.protocol import ActionResult, EpisodeStarted, ObjectView, RobotMessage, Snapshot
from mhrc.core.records import TraceLine
from mhrc.testing import EpisodeResult, run_episode
from mhrc.world.teams import SHIPPED


@pytest.fixture(scope="module")
def episode() -> EpisodeResult:
    """A drone scouting for the paper's fetcher and arm: four kinds' worth of observations."""
    return asyncio.run(run_episode(team=SHIPPED["drone_scout"], task="pack_objects", seed=1, n_objects=4, horizon=14))


def _slip(records: list[TraceLine]) -> tuple[list[TraceLine], int, str, str]:
    """The trace with an object the scout never saw put into one of its observations: the
    record's index, the robot and the object."""
    last = next(r.msg for r in reversed(records) if isinstance(r.msg, Snapshot))
    assert isinstance(last, Snapshot)
    for i, line in enumerate(records):
        res = line.msg
        if isinstance(res, ActionResult) and res.robot == "lucy" and res.observation is not None:
            seen = {o.name for o in res.observation.objects}
            name = next(n for n in sorted(last.objects) if n not in seen)
            pose = last.objects[name]
            view = ObjectView(name=name, position=(pose.x, pose.y, pose.z), on=pose.on)
            obs = res.observation.model_copy(update={"objects": [*res.observation.objects, view]})
            doctored = [*records]
            doctored[i] = replace(line, msg=res.model_copy(update={"observation": obs}))
            return doctored, i, "lucy", name
    raise AssertionError("the drone never acted")


def test_a_real_team_episode_leaks_nothing(episode: EpisodeResult) -> None:
    report = check(episode.records)
    assert report.unchecked is None and report.observations >= 20
    assert report.leaks == []
    assert any(r.observation and r.observation.objects for r in episode.results("lucy"))  # the drone did see


def test_an_object_slipped_into_an_observation_is_a_leak(episode: EpisodeResult) -> None:
    doctored, i, robot, name = _slip(episode.records)
    res = doctored[i].msg
    assert isinstance(res, ActionResult) and res.observation is not None
    leaks = check(doctored).leaks
    assert Leak(robot, res.observation.tick, name, "result") in leaks
    # told of it first, the robot may know it
    told = RobotMessage(sender="alice", to=robot, content=f"There is a {name.replace('_', ' ')} somewhere.", tick=0)
    explained = [*doctored[:i], replace(doctored[i], msg=told), *doctored[i:]]
    assert not any(leak.obj == name and leak.robot == robot for leak in check(explained).leaks)


def test_what_cannot_be_checked_says_so(episode: EpisodeResult) -> None:
    started = next(r for r in episode.records if isinstance(r.msg, EpisodeStarted))
    assert isinstance(started.msg, EpisodeStarted)
    live = [
        replace(r, msg=started.msg.model_copy(update={"aids": ["live_state"]})) if r is started else r
        for r in episode.records
    ]
    assert check(live).unchecked is Unchecked.LIVE_STATE
    assert check([r for r in episode.records if not isinstance(r.msg, Snapshot)]).unchecked is Unchecked.NO_SNAPSHOTS
