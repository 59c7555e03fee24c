"""The heuristic team for any team (issue 33): roles by skills, not names; several fetchers and
several scouts split the work by claims over messages, without doing any of it twice.

The unit tests play the world with `PolicyHarness`. The episodes are real: the world and each
robot's agent on its own Zenoh session on loopback (`run_episode`), in the lockstep schedule, for
the two-fetcher team (Carol, a second mobile manipulator, started at a free stand pose) and a
five-robot team (two fetchers, two ground scouts and the arm)."""

from __future__ import annotations

from collections import defaultdict

import pytest

from mhrc.agents.heuristic import CLAIM_RE, EXPLORE_RE, MAKE_ROOM_RE, REPORT_RE, Heuristic, heuristic_policy
from mhrc.core.protocol import (
    ActionResult,
    Communicate,
    Navigate,
    Observation,
    Open,
    OutcomeCode,
    Pick,
    Place,
    Pose2D,
    RobotStatus,
    SkillOutcome,
    Wait,
)
from mhrc.core.team import RobotSpec, TeamSpec
from mhrc.testing import PolicyHarness, observation, outcome, run_episode
from mhrc.testing.policy_harness import FURNITURE
from mhrc.world.teams import SHIPPED

CAROL = (-2.65, 2.42, 1.570796)  # the dishwasher's stand pose in the kitchen: a free floor pose
ERIN = (3.5, 1.9, 0.0)  # the sofa's first stand pose


def _as(obs: Observation, name: str, teammates: dict[str, list[str]] | None = None) -> Observation:
    """`obs` as the robot `name` would see it (its status renamed; other teammates if given)."""
    status: RobotStatus = obs.status.model_copy(update={"name": name})
    update: dict[str, object] = {"robot": name, "status": status}
    if teammates is not None:
        update["teammates"] = teammates
    return obs.model_copy(update=update)


FETCHER = observation("alice").status.skills
ARM = observation("bob").status.skills
BASE = observation("david").status.skills


# --------------------------------------------------------------------------- roles


@pytest.mark.parametrize(("template", "role"), [("alice", "fetcher"), ("bob", "finisher"), ("david", "scout")])
async def test_a_robot_of_any_name_plays_the_role_its_skills_give(template: str, role: str) -> None:
    policy = heuristic_policy("zed")
    assert isinstance(policy, Heuristic)
    await PolicyHarness(policy).decide(_as(observation(template), "zed"))
    assert type(policy.role).__name__ == {"fetcher": "AliceHeuristic", "finisher": "BobHeuristic"}.get(
        role, "DavidHeuristic"
    )


async def test_the_finisher_asks_every_fetcher_by_name_one_a_step() -> None:
    team = {"alice": list(FETCHER), "carol": list(FETCHER), "david": list(BASE)}
    harness = PolicyHarness(heuristic_policy("bob"))
    first = await harness.decide(observation("bob", objects={"apple": "table_2"}, targets=["apple"], teammates=team))
    assert first.action == Communicate(
        to="alice", content="Alice, please bring these to table_0 within my reach: apple."
    )
    harness.answer(observation=observation("bob", objects={"apple": "table_2"}, targets=["apple"], tick=1))
    second = await harness.decide(_as(harness.next_observation, "bob", team))
    assert isinstance(second.action, Communicate) and second.action.to == "carol"
    assert second.action.content.startswith("Carol, please bring")


async def test_the_lead_splits_the_surfaces_among_the_scouts() -> None:
    team = {"bob": list(ARM), "david": list(BASE), "erin": list(BASE)}
    table_1 = FURNITURE["table_2"].model_copy(update={"name": "table_1", "position": (2.5, 2.5, 0.72)})
    room = [*FURNITURE.values(), table_1]
    harness = PolicyHarness(heuristic_policy("alice"))
    first = await harness.decide(observation("alice", teammates=team, furniture=room))
    harness.answer(observation=observation("alice", teammates=team, furniture=room, tick=1))
    second = await harness.decide(harness.next_observation)
    handed: dict[str, list[str]] = {}
    for d in (first, second):
        assert isinstance(d.action, Communicate) and (hit := EXPLORE_RE.search(d.action.content)) is not None
        handed[d.action.to] = [s.strip() for s in hit.group(1).split(",")]
    assert handed == {"david": ["table_2"], "erin": ["table_1"]}  # one share each, nothing twice


async def test_two_claims_that_cross_are_settled_by_name_order() -> None:
    """Alice and Carol both claim the apple in one step: Carol lets it go, Alice keeps it."""
    team = {"alice": list(FETCHER), "bob": list(ARM)}
    request = ("bob", "Carol, please bring these to table_0 within my reach: apple.")
    carol = PolicyHarness(heuristic_policy("carol"))
    obs = _as(observation("alice", objects={"apple": "table_2"}, messages=[request]), "carol", team)
    claim = await carol.decide(obs)
    assert claim.action == Communicate(to="alice", content="Alice, I am fetching these: apple.")
    crossed = ("alice", "Carol, I am fetching these: apple.")
    carol.answer(
        observation=_as(observation("alice", objects={"apple": "table_2"}, messages=[crossed], tick=1), "carol", team)
    )
    after = await carol.decide(carol.next_observation)
    assert not isinstance(after.action, (Navigate, Pick)) or getattr(after.action, "obj", None) != "apple"
    assert not (isinstance(after.action, Navigate) and after.action.target == "table_2")

    alice = PolicyHarness(heuristic_policy("alice"))
    team_a = {"bob": list(ARM), "carol": list(FETCHER)}
    obs_a = _as(
        observation(
            "alice",
            objects={"apple": "table_2"},
            furniture=["table_0", "tray", "table_2"],
            messages=[("bob", request[1].replace("Carol", "Alice"))],
        ),
        "alice",
        team_a,
    )
    mine = await alice.decide(obs_a)
    assert mine.action == Communicate(to="carol", content="Carol, I am fetching these: apple.")
    alice.answer(
        observation=_as(
            observation(
                "alice",
                objects={"apple": "table_2"},
                furniture=["table_0", "tray", "table_2"],
                messages=[("carol", "Alice, I am fetching these: apple.")],
                tick=1,
            ),
            "alice",
            team_a,
        )
    )
    keeps = await alice.decide(alice.next_observation)
    assert keeps.action == Navigate(target="table_2", stand_pose=0)


# --------------------------------------------------------------------------- whole episodes


def _team(name: str, robots: list[RobotSpec]) -> TeamSpec:
    return TeamSpec(name=name, robots=tuple(robots))


def _with_starts(team: TeamSpec, **starts: tuple[float, float, float]) -> list[RobotSpec]:
    return [r.model_copy(update={"start": starts.get(r.name)}) for r in team.robots]


TWO_FETCHERS = _team("two_fetchers", _with_starts(SHIPPED["two_fetchers"], carol=CAROL))
FIVE = _team(
    "five", [r for r in _with_starts(SHIPPED["large"], carol=CAROL, erin=ERIN) if r.name != "lucy"]
)  # the large team without its drone (a kind the world does not have yet)


def _kinds(team: TeamSpec) -> tuple[list[str], list[str]]:
    fetchers = [r.name for r in team.robots if r.kind == "mobile_manipulator"]
    scouts = [r.name for r in team.robots if r.kind == "mobile_base"]
    return fetchers, scouts


@pytest.mark.parametrize(
    ("team", "seed"), [(TWO_FETCHERS, 1), (TWO_FETCHERS, 2), (FIVE, 0), (FIVE, 1)], ids=lambda v: getattr(v, "name", v)
)
async def test_a_bigger_team_solves_pack_objects_with_every_robot_working_and_nothing_done_twice(
    team: TeamSpec, seed: int
) -> None:
    ep = await run_episode(
        team=team, task="pack_objects", scene="kitchen", seed=seed, n_objects=5, horizon=60, schedule="lockstep"
    )
    assert ep.done.reason == "success" and ep.done.metrics.success, ep.done.metrics
    results: list[ActionResult] = [r for r in ep.results() if r.outcome.succeeded]
    fetchers, scouts = _kinds(team)
    did: dict[str, set[str]] = defaultdict(set)
    picked_by: dict[str, set[str]] = defaultdict(set)
    opened_by: dict[str, set[str]] = defaultdict(set)
    explored_by: dict[str, set[str]] = defaultdict(set)  # a surface a scout reported on -> who reported it
    for r in results:
        a = r.action
        did[r.robot].add(a.skill)
        if isinstance(a, Pick) and r.robot in fetchers:
            picked_by[a.obj].add(r.robot)
        if isinstance(a, Open):
            opened_by[a.target].add(r.robot)
        if isinstance(a, Communicate) and r.robot in scouts and (hit := REPORT_RE.search(a.content)):
            explored_by[hit.group(1)].add(r.robot)
    for f in fetchers:  # each fetcher picks and places at least once
        assert {"pick", "place"} <= did[f], (f, did[f])
    for s in scouts:  # each scout navigates and reports
        assert {"navigate", "communicate"} <= did[s], (s, did[s])
        assert any(s in who for who in explored_by.values()), s
    assert all(len(who) == 1 for who in picked_by.values()), picked_by  # no object fetched by two fetchers
    assert all(len(who) == 1 for who in opened_by.values()), opened_by  # no container opened by two
    assert all(len(who) == 1 for who in explored_by.values()), explored_by  # no surface reported by two scouts
    claims = [r for r in results if isinstance(r.action, Communicate) and CLAIM_RE.search(r.action.content)]
    assert claims  # the fetchers did claim, over messages
    assert not any(isinstance(r.action, Place) and r.robot in scouts for r in results)


# --------------------------------------------------------------------------- one robot per stand pose


def _refused(occupant: str, place: str = "table_2", pose: int = 0) -> SkillOutcome:
    return outcome(
        OutcomeCode.OCCUPIED,
        f"Navigation failed: stand pose {pose} of {place} is occupied by {occupant.capitalize()}.",
        occupant=occupant,
    )


async def test_a_fetcher_refused_a_stand_pose_asks_the_occupant_to_make_room_and_comes_back() -> None:
    """Alice must pick at table_2's stand pose 0, where David stands: she asks him by name, waits
    a step, and navigates there again (not to another stand pose, from which she could not reach)."""
    team = ["bob", "david"]
    request = ("bob", "Alice, please bring these to table_0 within my reach: apple.")
    alice = PolicyHarness(heuristic_policy("alice"))
    obs = observation("alice", objects={"apple": "table_2"}, messages=[request], teammates=team)
    handed = await alice.step(obs)  # the open surfaces to the scout first
    assert isinstance(handed.action, Communicate) and EXPLORE_RE.search(handed.action.content)
    go = await alice.step(alice.next_observation, _refused("david"))
    assert go.action == Navigate(target="table_2", stand_pose=0)
    after = [await alice.step(alice.next_observation) for _ in range(2)]
    assert [d.action for d in after] == [
        Communicate(to="david", content="David, please make room at table_2 stand pose 0."),
        Wait(),
    ]
    assert MAKE_ROOM_RE.search(after[0].action.content)  # type: ignore[union-attr]
    again = await alice.decide(alice.next_observation)
    assert again.action == Navigate(target="table_2", stand_pose=0)  # the same stand pose, not another
    there = observation("alice", objects={"apple": "table_2"}, teammates=team, tick=5, status=_at(obs, "table_2", 0))
    alice.answer(observation=there)
    assert (await alice.decide(alice.next_observation)).action == Pick(obj="apple")


async def test_an_idle_scout_asked_to_make_room_leaves_for_a_stand_pose_nobody_needs() -> None:
    """David has reported table_2 and has nothing to do; asked to make room there, he navigates
    to table_1 (nothing known on it), not to Bob's table nor a container; not asked, he waits."""
    table_1 = FURNITURE["table_2"].model_copy(update={"name": "table_1", "position": (2.5, 2.5, 0.72)})
    table_1 = table_1.model_copy(update={"stand_poses": [Pose2D(x=2.5, y=1.7, yaw=1.57)]})
    room = [*FURNITURE.values(), table_1]
    base = observation("david", furniture=room, objects={"apple": "table_2"})
    here = _at(base, "table_2", 0)
    david = PolicyHarness(heuristic_policy("david"))
    idle = await david.step(base.model_copy(update={"status": here}))
    assert idle.action == Wait()
    ask = ("alice", "David, please make room at table_2 stand pose 0.")
    asked = observation("david", furniture=room, objects={"apple": "table_2"}, messages=[ask], tick=1)
    leave = await david.step(asked.model_copy(update={"status": here}))
    assert leave.action == Navigate(target="table_1", stand_pose=0)
    elsewhere = observation("david", furniture=room, objects={"apple": "table_2"}, messages=[ask], tick=2)
    assert (await david.decide(elsewhere)).action == Wait()  # asked where it does not stand: nothing to do


def _at(obs: Observation, place: str, pose: int) -> RobotStatus:
    f = next(f for f in obs.furniture if f.name == place)
    sp = f.stand_poses[pose]
    return obs.status.model_copy(update={"base": Pose2D(x=sp.x, y=sp.y, yaw=sp.yaw)})


TRIO = _team(
    "trio",
    [
        RobotSpec(name="alice", kind="mobile_manipulator"),
        RobotSpec(name="bob", kind="tabletop_arm"),
        RobotSpec(name="dave", kind="mobile_base"),
    ],
)  # the paper's kinds under another scout's name: one robot per stand pose holds for it


async def test_a_scout_parked_where_the_fetcher_must_pick_makes_room_and_the_episode_succeeds() -> None:
    """Dave reports bread_slice_2 on table_2 and stays at its stand pose 0, the one Alice can pick
    it from: she is refused, asks him to make room, he leaves, she gets there and picks it (before
    the heuristic made room, she tried stand pose 1, could not reach it and the episode failed)."""
    ep = await run_episode(
        team=TRIO, task="make_sandwich", scene="bedroom", seed=0, n_objects=4, horizon=40, schedule="sequential"
    )
    assert ep.done.reason == "success" and ep.done.metrics.success, ep.done.metrics
    results = list(ep.results())
    refused = [
        i
        for i, r in enumerate(results)
        if r.robot == "alice" and r.outcome.code == OutcomeCode.OCCUPIED and r.outcome.details.get("occupant") == "dave"
    ]
    assert refused, "the scenario no longer arises: Dave is never in Alice's way"
    after = results[refused[0] + 1 :]
    asked = next(r for r in after if r.robot == "alice" and isinstance(r.action, Communicate))
    assert asked.action == Communicate(to="dave", content="Dave, please make room at table_2 stand pose 0.")
    left = next(r for r in after if r.robot == "dave" and isinstance(r.action, Navigate))
    assert left.outcome.succeeded and left.action.target != "table_2"
    there = next(r for r in after if r.robot == "alice" and isinstance(r.action, Navigate))
    assert there.action == Navigate(target="table_2", stand_pose=0) and there.outcome.succeeded
    assert any(r.robot == "alice" and r.action == Pick(obj="bread_slice_2") and r.outcome.succeeded for r in after)
