"""The centralized planner's decisions on a small hand-made world (no simulator): who does which
work when the exact assignment weighs exploring against fetching, and what the team's knowledge
makes of a fetcher finding an object gone from the finisher's table."""

from __future__ import annotations

import asyncio

import pytest

from mhrc.agents.protocols import centralized
from mhrc.agents.protocols.allocation import assign
from mhrc.agents.protocols.centralized import CentralPlanner, Seat
from mhrc.agents.protocols.knowledge import Knowledge
from mhrc.agents.protocols.steps import Hand, Job, Taken, job_step
from mhrc.core.protocol import (
    Action,
    FurnitureView,
    Navigate,
    ObjectView,
    Observation,
    Place,
    Pose2D,
    RobotDetached,
    RobotStatus,
    Wait,
)

FETCHER = ["navigate", "move", "open", "pick", "place", "communicate", "wait"]
SCOUT = ["navigate", "communicate", "wait"]
ARM = ["pick", "place", "communicate", "wait"]


def _furniture() -> list[FurnitureView]:
    def f(name: str, x: float, openable: bool = False) -> FurnitureView:
        return FurnitureView(
            name=name,
            kind=name,
            position=(x, 0.0, 0.5),
            openable=openable,
            is_open=False if openable else None,
            stand_poses=[Pose2D(x=x, y=-1.0), Pose2D(x=x + 0.5, y=-1.0)],
            place_pose=(x, 0.0, 0.8),
        )

    tray = FurnitureView(name="tray", kind="tray", position=(0.0, 0.2, 0.8))
    return [f("table_0", 0.0), tray, f("table_1", 3.0), f("sofa", 5.0), f("fridge", 7.0, True), f("cabinet", 9.0, True)]


def _obs(robot: str, skills: list[str], x: float, objects: list[ObjectView] = (), **kw: object) -> Observation:  # type: ignore[assignment]
    mobile = "navigate" in skills
    status = RobotStatus(
        name=robot,
        kind="k",
        skills=skills,
        base=Pose2D(x=x, y=float(kw.pop("y", -2.0))) if mobile else None,  # type: ignore[arg-type]
        arm_base=(x, -1.8, 0.6) if "pick" in skills else None,
        reach=0.7 if "pick" in skills else None,
        holding=kw.pop("holding", None),  # type: ignore[arg-type]
    )
    return Observation(
        robot=robot,
        tick=int(kw.pop("tick", 1)),  # type: ignore[call-overload]
        status=status,
        furniture=_furniture(),
        objects=list(objects),
        task_brief="",
        task_detail="",
        **kw,  # type: ignore[arg-type]
    )


def _team(fetchers: int, targets: list[str], seen: list[ObjectView]) -> Knowledge:
    k = Knowledge()
    k.take(_obs("bob", ARM, 0.0, targets=targets, goals={t: "tray" for t in targets}))
    for i in range(fetchers):
        k.take(_obs(f"f{i}", FETCHER, 2.0 + i, seen))
    k.take(_obs("david", SCOUT, 4.0))
    return k


def _mug() -> ObjectView:
    return ObjectView(name="mug", position=(3.0, 0.0, 0.8), on="table_1")


def test_a_lone_fetcher_fetches_what_is_known_before_it_opens_a_container() -> None:
    k = _team(1, ["mug", "soap"], [_mug()])
    jobs = [Job("fetch", "mug"), Job("explore", "fridge"), Job("explore", "cabinet")]
    assert assign(k, [Hand("f0")], jobs, scouts=True) == {"f0": Job("fetch", "mug")}


def test_of_two_fetchers_one_opens_a_container_while_the_other_fetches() -> None:
    """Exploration is parallel work: the object still unseen cannot be fetched until someone looks."""
    k = _team(2, ["mug", "cup", "soap"], [_mug(), ObjectView(name="cup", position=(3.2, 0.0, 0.8), on="table_1")])
    jobs = [Job("fetch", "mug"), Job("fetch", "cup"), Job("explore", "fridge"), Job("explore", "cabinet")]
    given = assign(k, [Hand("f0"), Hand("f1")], jobs, scouts=True)
    assert sorted(j.kind for j in given.values()) == ["explore", "fetch"]


def test_a_fetcher_leaves_the_surfaces_to_the_scout_and_opens_containers() -> None:
    k = _team(1, ["soap"], [])
    jobs = [Job("explore", "table_1"), Job("explore", "sofa"), Job("explore", "fridge")]
    given = assign(k, [Hand("f0"), Hand("david")], jobs, scouts=True)
    assert given["f0"] == Job("explore", "fridge") and given["david"].target in ("table_1", "sofa")


def test_an_object_gone_from_the_finishers_table_is_not_lost() -> None:
    """A fetcher at the finisher's table sees an object gone from it when the finisher picks it
    up; the finisher's view of its own table counts, so nobody is sent to search for it."""
    k = _team(1, ["mug"], [ObjectView(name="mug", position=(0.5, 0.0, 0.8), on="table_0")])
    gone = ObjectView(name="mug", position=(0.5, 0.0, 0.8), on=None, last_seen_on="table_0")
    k.take(_obs("f0", FETCHER, 0.5, [gone], tick=2))
    assert k.located("mug") is not None
    planner = CentralPlanner(("f0", "bob", "david"), "sequential", knowledge=k)
    assert not [j for j in planner._jobs() if j.kind == "explore"]


def test_in_a_sandwich_only_the_object_wanted_next_is_put_down() -> None:
    """The band of the finisher's table its arm reaches holds few objects: one brought early can
    leave no room for the next, so a fetcher holding a later one waits with it at the table."""
    ham = ObjectView(name="ham", position=(9.0, 0.0, 0.8), on="cabinet", inside=True)
    k = Knowledge()
    k.take(_obs("bob", ARM, 0.0, [ham], targets=["ham", "tomato"], goals={}, ordered=True))
    held = ObjectView(name="tomato", position=(0.0, -1.0, 0.9), held_by="f0")
    k.take(_obs("f0", FETCHER, 0.0, [held], y=-1.0, holding="tomato"))  # at table_0's stand pose 0
    hand = Hand("f0", job=Job("fetch", "tomato"))
    assert job_step(k, hand, Taken(set(), set())) == Wait()
    on_goal = ObjectView(name="ham", position=(0.0, 0.2, 0.85), on="tray")
    k.take(_obs("bob", ARM, 0.0, [on_goal], targets=["ham", "tomato"], goals={}, ordered=True, tick=2))
    assert job_step(k, hand, Taken(set(), set())) == Place(obj="tomato", location="table_0")


def _lockstep() -> tuple[CentralPlanner, list[tuple[str, ...]]]:
    """A lockstep planner for f0, bob and david that notes which robots each of its rounds asked for."""
    planner = CentralPlanner(("f0", "bob", "david"), "lockstep")
    rounds: list[tuple[str, ...]] = []
    plan = planner.plan

    async def noted(asking: tuple[str, ...]) -> dict[str, Action]:
        rounds.append(asking)
        return await plan(asking)

    planner.plan = noted  # type: ignore[method-assign]
    return planner, rounds


def _tick(robot: str, tick: int, attached: tuple[str, ...]) -> Observation:
    """`robot`'s observation of `tick`, naming the `attached` teammates (the world's word)."""
    skills = {"f0": FETCHER, "bob": ARM, "david": SCOUT}
    mates = {r: skills[r] for r in attached if r != robot}
    if robot == "bob":
        return _obs("bob", ARM, 0.0, targets=["mug"], goals={"mug": "tray"}, tick=tick, teammates=mates)
    return _obs(robot, skills[robot], 2.0 if robot == "f0" else 4.0, tick=tick, teammates=mates)


async def test_the_lockstep_round_waits_for_the_attached_robots_and_a_late_one_is_planned_alone() -> None:
    """The round of a tick runs once every attached robot brought its observation (the event, not a
    clock); a robot the tick's observations do not list as attached is not waited for, and when it
    comes back later in the tick it gets its own command without its teammates' being planned again."""
    planner, rounds = _lockstep()
    everyone = ("f0", "bob", "david")
    first = [asyncio.create_task(planner.command(_tick(r, 1, everyone))) for r in ("f0", "bob")]
    await asyncio.sleep(0)  # both are in the barrier now
    assert not any(t.done() for t in first) and rounds == []  # david is attached: his observation is awaited
    last = await asyncio.wait_for(planner.command(_tick("david", 1, everyone)), 30)
    await asyncio.wait_for(asyncio.gather(*first), 30)
    assert rounds == [everyone] and last is not None
    pair = ("f0", "bob")  # david detached: the world's observations of tick 2 do not list him
    await asyncio.wait_for(asyncio.gather(*(planner.command(_tick(r, 2, pair)) for r in pair)), 30)
    assert rounds[-1] == pair
    await asyncio.wait_for(planner.command(_tick("david", 2, everyone)), 30)  # attached again, late in the tick
    assert rounds[-1] == ("david",) and len(rounds) == 3


async def test_a_robot_that_never_brings_its_observation_holds_the_round_only_for_a_bound(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """An attached robot whose agent died after the world released the tick: the round runs for the
    others once the bound since the tick's first observation has passed."""
    monkeypatch.setattr(centralized, "RELEASE_SPREAD", 0.05)
    planner, rounds = _lockstep()
    everyone = ("f0", "bob", "david")
    await asyncio.wait_for(asyncio.gather(*(planner.command(_tick(r, 1, everyone)) for r in ("f0", "bob"))), 30)
    assert rounds == [("f0", "bob")]


def test_a_fetcher_sent_to_a_closed_container_opens_it_though_its_arrival_is_not_heard_yet() -> None:
    """Its navigation is spent (in the sequential schedule its result waits for its next turn):
    leaving for a known object would have to come back for the container later."""
    k = _team(1, ["mug", "soap"], [_mug()])
    hand = Hand("f0", job=Job("explore", "fridge"), pose=("fridge", 0))
    jobs = [Job("fetch", "mug"), Job("explore", "fridge"), Job("explore", "cabinet")]
    assert assign(k, [hand], jobs, scouts=True) == {"f0": Job("explore", "fridge")}


def test_a_fetcher_standing_at_a_target_takes_it_before_the_tasks_first() -> None:
    """Any order will do for an unordered task: the object it stands at comes first (no
    navigation), not after the one the list names first (the container it just opened, say)."""
    soap = ObjectView(name="soap", position=(5.0, 0.0, 0.5), on="sofa")
    k = _team(1, ["mug", "soap"], [_mug(), soap])
    k.take(_obs("f0", FETCHER, 5.0, [_mug(), soap], y=-1.0, tick=2))  # at the sofa's stand pose 0
    jobs = [Job("fetch", "mug"), Job("fetch", "soap")]
    assert assign(k, [Hand("f0")], jobs, scouts=True) == {"f0": Job("fetch", "soap")}


def test_a_robot_is_where_it_stands_not_where_it_once_meant_to_go() -> None:
    """full_house's deadlock: an idle fetcher stood at the finisher's table while its recorded
    stand pose said elsewhere, so another fetcher, holding an object, drove into its pose until
    the horizon. Poses are worked out again each round: the other takes the free pose, and the
    idle one makes room."""
    k = _team(2, ["mug"], [])
    held = ObjectView(name="mug", position=(3.0, -2.0, 0.9), held_by="f0")
    k.take(_obs("f0", FETCHER, 3.0, [held], holding="mug", tick=3))
    k.take(_obs("f1", FETCHER, 0.0, y=-1.0, tick=3))  # at table_0's stand pose 0
    planner = CentralPlanner(("bob", "f0", "f1", "david"), "sequential", knowledge=k)
    planner.hands["f1"].pose = ("sofa", 0)  # where it was once sent
    assert planner._step(planner.hands["f0"]) == Navigate(target="table_0", stand_pose=1)
    leave = planner._step(planner.hands["f1"])
    assert isinstance(leave, Navigate) and leave.target != "table_0"


async def test_a_robot_the_world_detaches_is_not_waited_for(monkeypatch: pytest.MonkeyPatch) -> None:
    """The world's robot_detached, as a seat's agent hears it, ends the wait of the tick under way
    for that robot: the round runs for the others at once, without the bound."""
    planner, rounds = _lockstep()
    everyone = ("f0", "bob", "david")
    waiting = [asyncio.create_task(planner.command(_tick(r, 1, everyone))) for r in ("f0", "bob")]
    for _ in range(3):
        await asyncio.sleep(0)
    assert not any(t.done() for t in waiting)  # david is attached: awaited
    seat = Seat("f0", planner)
    seat.world_event(RobotDetached(robot="david", tick=1, reason="token lost"))
    for _ in range(10):  # the wake-up and the round: a few turns of the loop, no clock
        await asyncio.sleep(0)
    assert all(t.done() for t in waiting) and rounds == [("f0", "bob")]
    # back: counted again. f0 and Bob send nothing for tick 2, so David's round waits the bound for
    # them: shortened here, after the part above has run under the real one
    monkeypatch.setattr(centralized, "RELEASE_SPREAD", 0.05)
    await asyncio.wait_for(planner.command(_tick("david", 2, everyone)), 30)
    assert "david" not in planner._gone
