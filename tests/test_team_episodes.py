"""Teams in whole episodes (issue 33): eight robots as separate processes on the secured bus (and
their video), and partial observability for every kind of robot in a team of eight, in the
simulator and over the whole trace of every multi-robot episode here
(mhrc.analysis.observability)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from mhrc.analysis.observability import check
from mhrc.core.protocol import Navigate, OutcomeCode
from mhrc.core.records import read_records
from mhrc.core.team import RobotSpec, TeamSpec
from mhrc.testing import run_episode
from mhrc.world.sim import Sim
from mhrc.world.teams import SHIPPED

FULL_HOUSE = SHIPPED["full_house"]


@pytest.mark.slow
def test_eight_robots_as_separate_processes_on_the_secured_bus(tmp_path: Path) -> None:
    """`mhrc up --processes` with the team of eight: the world and eight agent processes, each
    logged in as its own robot (the default bus is secured), every robot attached and acting."""
    done = subprocess.run(
        [sys.executable, "-m", "mhrc", "up", "--team", "full_house", "--processes", "--horizon", "4", "--json"]
        + ["--video", "v.gif"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "credentials in" in done.stderr and "insecure" not in done.stderr
    assert (tmp_path / "v.gif").stat().st_size > 0  # the video rebuilds the team's world, not the paper's
    metrics = json.loads(done.stdout.strip().splitlines()[-1])
    assert set(metrics["action_steps_per_robot"]) == set(FULL_HOUSE.names)
    (run,) = (tmp_path / "runs").iterdir()
    logins = {p.stem for p in (run / "credentials").glob("*.json")}
    assert set(FULL_HOUSE.names) <= logins  # one login per robot
    records = read_records(run / "trace.jsonl")
    attached = {r.msg.robot for r in records if r.msg is not None and getattr(r.msg, "kind", "") == "robot_attached"}
    assert attached == set(FULL_HOUSE.names)
    acted = {r.msg.robot for r in records if r.msg is not None and getattr(r.msg, "kind", "") == "action_result"}
    assert acted == set(FULL_HOUSE.names)  # each agent's requests reached the world as its own robot's
    started = next(r.msg for r in records if getattr(r.msg, "kind", "") == "episode_started")
    assert started.team is not None and started.team.kinds == FULL_HOUSE.kinds  # the team in the trace
    seen = check(records)  # partial observability over the eight robots' whole trace
    assert seen.leaks == [] and seen.observations >= 8


def test_every_kind_sees_only_what_it_has_seen() -> None:
    """A team of eight, four kinds: at the start only the arm sees anything (its table); a robot
    of each mobile kind that looks at a surface learns what lies there, and nobody else does; a
    closed container hides its contents from a robot of any kind standing at it."""
    with Sim(team=FULL_HOUSE, seed=2, n_objects=6, aids=("exact_motion",)) as sim:
        table_0 = {o.name for o in sim.objects.values() if o.on in ("table_0", "tray")}
        assert {o.name for o in sim.observe("bob", 0).objects} == table_0
        for robot in FULL_HOUSE.names:
            obs = sim.observe(robot, 0)
            assert set(obs.teammates) == set(FULL_HOUSE.names) - {robot}
            if robot != "bob":
                assert obs.objects == [] and obs.targets == [] and obs.task_status is None
        surfaces = sorted(
            {o.on for o in sim.objects.values() if o.on and not o.inside and o.on not in ("table_0", "tray")}
        )
        lookers = [r for r in ("alice", "david", "lucy") if surfaces]  # a mobile manipulator, a mobile base, a drone
        for tick, (robot, surface) in enumerate(zip(lookers, surfaces, strict=False), start=1):
            out = sim.execute(robot, Navigate(target=surface, stand_pose=0))
            assert out.succeeded, (robot, out.feedback)
            there = {o.name for o in sim.objects.values() if o.on == surface and not o.inside}
            assert there <= {o.name for o in sim.observe(robot, tick).objects}
            for other in FULL_HOUSE.names:
                if other not in (robot, "bob") and other not in lookers[: lookers.index(robot)]:
                    assert not there & {o.name for o in sim.observe(other, tick).objects}, (other, surface)
        hidden = {o.name for o in sim.objects.values() if o.inside}
        container = next(o.on for o in sim.objects.values() if o.inside)
        assert container is not None
        for robot in ("carol", "erin", "mia"):
            out = sim.execute(robot, Navigate(target=container, stand_pose=0))
            if out.code is OutcomeCode.OCCUPIED:
                continue  # another robot of its level holds the pose: nothing to see from here
            assert not hidden & {o.name for o in sim.observe(robot, 9).objects}, robot


FIVE = TeamSpec(
    name="five",
    robots=tuple(
        RobotSpec(name=n, kind=k)
        for n, k in (
            ("alice", "mobile_manipulator"),
            ("bob", "tabletop_arm"),
            ("carol", "mobile_manipulator"),
            ("david", "mobile_base"),
            ("lucy", "drone"),
        )
    ),
)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("team", "task"),
    [(SHIPPED["scout_and_drone"], t) for t in ("pack_objects", "sort_solids", "make_sandwich")]
    + [(FIVE, t) for t in ("sort_solids", "make_sandwich")],  # pack_objects: tests/test_heuristic_teams.py
    ids=lambda v: getattr(v, "name", v),
)
async def test_a_team_with_a_drone_solves_every_task_with_every_robot_working(team: TeamSpec, task: str) -> None:
    """The heuristic team of four with a drone, and of five (two fetchers, a ground scout and a
    drone), each solves an episode of every task; every robot does real work: the finisher
    places, each fetcher picks and places, each scout (the drone too) navigates and reports."""
    ep = await run_episode(team=team, task=task, scene="kitchen", seed=0, n_objects=5, horizon=60, schedule="lockstep")
    assert ep.done.metrics.success, (ep.done.reason, ep.done.metrics)
    seen = check(ep.records)  # no robot's observation names an object it had no way to know
    assert seen.unchecked is None and seen.leaks == []
    did: dict[str, set[str]] = {r: set() for r in team.names}
    for r in ep.results():
        if r.outcome.succeeded:
            did[r.robot].add(r.action.skill)
    for spec in team.robots:
        want = {
            "tabletop_arm": {"place"},
            "mobile_manipulator": {"pick", "place"},
            "mobile_base": {"navigate", "communicate"},
            "drone": {"navigate", "communicate"},
        }[spec.kind]
        assert want <= did[spec.name], (spec.name, did[spec.name])
