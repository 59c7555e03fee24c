"""The PyBullet world directly: solvability of every generated episode, failure feedback for bad
arguments, the drawer, partial views and determinism. Real PyBullet and OMPL, no mocks.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator

import numpy as np
import pybullet as p
import pytest
from sweep import sweep

from mhrc.core.protocol import (
    Communicate,
    Move,
    Navigate,
    ObjectView,
    Observation,
    Open,
    OutcomeCode,
    Pick,
    Place,
    SkillOutcome,
    Wait,
)
from mhrc.world.checks import check_episode
from mhrc.world.render import render
from mhrc.world.scene import LAYOUTS
from mhrc.world.sim import Sim
from mhrc.world.tasks import TASKS


def _ok(out: SkillOutcome) -> SkillOutcome:
    assert out.succeeded, out.feedback
    return out


def _obj(obs: Observation, name: str) -> ObjectView | None:
    return next((o for o in obs.objects if o.name == name), None)


def _nearest_pose(obs: Observation, furniture: str, xy: tuple[float, ...]) -> int:
    f = next(f for f in obs.furniture if f.name == furniture)
    return min(
        range(len(f.stand_poses)), key=lambda i: math.hypot(f.stand_poses[i].x - xy[0], f.stand_poses[i].y - xy[1])
    )


def _make_room(sim: Sim, robot: str, furniture: str, pose: int) -> None:
    """`robot` leaves stand pose `pose` of `furniture` for the free stand pose farthest from it."""
    spec = sim.layout.get(furniture)
    assert spec is not None
    x, y, _ = spec.stand_poses[pose]
    spots = [
        (f.name, i, math.hypot(sx - x, sy - y))
        for f in sim.layout.furniture
        for i, (sx, sy, _) in enumerate(f.stand_poses)
    ]
    for name, i, _ in sorted(spots, key=lambda s: -s[2]):
        if (out := sim.execute(robot, Navigate(target=name, stand_pose=i))).code != OutcomeCode.OCCUPIED:
            _ok(out)
            return


def _bob_can_reach(obs: Observation, o: ObjectView) -> bool:
    ab, reach = obs.status.arm_base, obs.status.reach
    assert ab is not None and reach is not None
    return o.on == "table_0" and math.hypot(o.position[0] - ab[0], o.position[1] - ab[1]) <= reach


def _fetch(sim: Sim, name: str) -> None:
    """Alice brings a known object to table_0 and Bob puts it on its goal; every step must succeed."""
    alice = sim.observe("alice", 0)
    o = _obj(alice, name)
    assert o is not None and o.on is not None, f"Alice does not know where {name} is"
    pose = _nearest_pose(alice, o.on, o.position)
    out = sim.execute("alice", Navigate(target=o.on, stand_pose=pose))
    if out.code == OutcomeCode.OCCUPIED:  # one robot per stand pose: the occupant makes room, then Alice goes
        _make_room(sim, str(out.details["occupant"]), o.on, pose)
        out = sim.execute("alice", Navigate(target=o.on, stand_pose=pose))
    _ok(out)
    out = sim.execute("alice", Pick(obj=name))
    if out.code == OutcomeCode.TOO_FAR and "dx" in out.details:  # the paper's recovery: move by the offsets
        _ok(sim.execute("alice", Move(dx=float(out.details["dx"]), dy=float(out.details["dy"]))))
        out = sim.execute("alice", Pick(obj=name))
    _ok(out)
    _ok(sim.execute("alice", Navigate(target="table_0", stand_pose=0)))
    _ok(sim.execute("alice", Place(obj=name, location="table_0")))
    bob = sim.observe("bob", 0)
    handed = _obj(bob, name)
    assert handed is not None and _bob_can_reach(bob, handed), f"{name} was handed over beyond Bob's reach"
    sim.tell("bob", "alice", f"{name} is on table_0 near you")
    _ok(sim.execute("bob", Pick(obj=name)))
    _ok(sim.execute("bob", Place(obj=name, location=bob.goals[name])))


def play_by_the_rules(sim: Sim) -> None:
    """The intended team plan, using only what each robot observes and is told, target by
    target in the task's order."""
    bob = sim.observe("bob", 0)
    assert set(bob.goals) == set(bob.targets)
    missing = [t for t in bob.targets if (o := _obj(bob, t)) is None or not _bob_can_reach(bob, o)]
    sim.tell("alice", "bob", f"Please bring: {', '.join(missing)}")  # names Alice learns only if Bob knows them
    # Alice opens the closed containers; David explores the open surfaces and reports
    alice = sim.observe("alice", 0)
    for f in alice.furniture:
        if f.openable and not f.is_open:
            _ok(sim.execute("alice", Navigate(target=f.name, stand_pose=0)))
            _ok(sim.execute("alice", Open(target=f.name)))
    for f in alice.furniture:
        if not f.openable and f.stand_poses and f.name != "table_0":
            out = _ok(sim.execute("david", Navigate(target=f.name, stand_pose=0)))
            sim.tell("alice", "david", out.feedback)
    for name in bob.targets:
        if name in missing:
            _fetch(sim, name)
        else:
            _ok(sim.execute("bob", Pick(obj=name)))
            _ok(sim.execute("bob", Place(obj=name, location=bob.goals[name])))


# every scene x task x size; the fast tier solves one episode of each task, each in another scene
SOLVABLE = [
    (scene, task, n, seed)
    for scene in sorted(LAYOUTS)
    for task in sorted(TASKS)
    for n, seed in [(3, 0), (4, 1), (5, 5), (6, 3)]
]
FIRST = [("kitchen", "pack_objects", 4, 1), ("bedroom", "make_sandwich", 5, 5), ("bathroom", "sort_solids", 6, 3)]


@pytest.mark.parametrize(
    ("scene", "task", "n_objects", "seed"), sweep(FIRST + [c for c in SOLVABLE if c not in FIRST], fast=len(FIRST))
)
def test_every_generated_episode_is_solvable_by_the_team(scene: str, task: str, n_objects: int, seed: int) -> None:
    with Sim(
        task=task, scene=scene, seed=seed, n_objects=n_objects, aids=("goal_map", "solved_move", "exact_motion")
    ) as sim:
        result = sim.evaluate()
        assert (result.placed, result.total, result.success) == (0, n_objects, False)
        play_by_the_rules(sim)
        result = sim.evaluate()
        assert result.success and result.placed == n_objects and result.partial_success == 1.0
        status = sim.task_status()  # Bob's progress text names every target and nothing left to do
        assert all(t in status for t in sim.targets) and not any(w in status for w in ("Not yet", "Next:", "rong")), (
            status
        )


@pytest.mark.slow
def test_each_episode_has_the_work_the_paper_describes() -> None:
    for seed in range(12):
        with Sim(seed=seed, n_objects=3) as sim:
            bob = sim.observe("bob", 0)
            targets = {t: sim.objects[t] for t in sim.targets}
            near = [t for t in targets if (o := _obj(bob, t)) is not None and _bob_can_reach(bob, o)]
            far = [t for t, o in targets.items() if o.on == "table_0" and t not in near]
            hidden = [
                t
                for t, o in targets.items()
                if o.inside and (f := sim.layout.get(o.on or "")) is not None and f.container is not None
            ]
            assert near and far and hidden, (seed, near, far, hidden)
            assert 1 <= len(sim.objects) - len(sim.targets) <= 2  # distractors
        with Sim(seed=seed, n_objects=6) as sim:
            elsewhere = [t for t in sim.targets if sim.objects[t].on != "table_0" and not sim.objects[t].inside]
            assert len(elsewhere) == 3


def _visual_meshes(sim: Sim) -> int:
    """The robots' links drawn with a visual mesh (without them pybullet draws the collision mesh)."""
    return sum(
        b"/meshes/visual/" in shape[4]
        for bot in sim.bots.values()
        for body in (bot.body, bot.arm)
        if body >= 0
        for shape in p.getVisualShapeData(body, physicsClientId=sim.cid)
    )


def test_same_seed_same_actions_same_outcomes() -> None:
    """Two worlds side by side (gymnasium style): every outcome and the final state agree, the
    first built with its robots' visual meshes (for a camera) and the second without (the default:
    the world service's, which no camera sees); the second refuses to be drawn."""
    with Sim(seed=2, n_objects=4, visuals=True) as a, Sim(seed=2, n_objects=4) as b:
        assert _visual_meshes(a) > 0 and _visual_meshes(b) == 0
        with pytest.raises(ValueError, match="visuals=True"):
            render(b, "top")
        bob = a.observe("bob", 0)
        far = next(
            t for t in a.targets if (o := _obj(bob, t)) is not None and o.on == "table_0" and not _bob_can_reach(bob, o)
        )
        assert a.execute("bob", Pick(obj=far)) == b.execute("bob", Pick(obj=far))
        for sim in (a, b):
            sim.tell("alice", "bob", f"bring {far}")
        actions = [
            ("alice", Navigate(target="drawer_unit", stand_pose=0)),
            ("alice", Open(target="drawer_unit")),
            ("alice", Navigate(target="table_0", stand_pose=0)),
            ("alice", Pick(obj=far)),
            ("alice", Move(dx=0.5, dy=0.0)),
            ("alice", Pick(obj=far)),
            ("alice", Navigate(target="table_0", stand_pose=0)),
            ("alice", Place(obj=far, location="table_0")),
            ("bob", Pick(obj=far)),
            ("bob", Place(obj=far, location="tray")),
            ("david", Navigate(target="sofa", stand_pose=1)),
        ]
        for robot, action in actions:
            assert a.execute(robot, action) == b.execute(robot, action), action
        assert a.snapshot() == b.snapshot()
        assert a.observe("bob", 9) == b.observe("bob", 9)


@pytest.fixture
def sim() -> Iterator[Sim]:
    with Sim(seed=1, n_objects=4, aids=("goal_map", "solved_move", "exact_motion", "feedback_advice")) as s:
        yield s


def _fails(sim: Sim, robot: str, action: object, code: OutcomeCode, *texts: str) -> SkillOutcome:
    out = sim.execute(robot, action)  # type: ignore[arg-type]
    assert not out.succeeded and out.code == code, (action, out)
    for text in texts:
        assert text in out.feedback, (text, out.feedback)
    return out


def test_bad_arguments_get_failure_feedback_not_exceptions(sim: Sim) -> None:
    _fails(sim, "alice", Pick(obj="applle"), OutcomeCode.OBJECT_UNKNOWN, "'applle'", "objects you know: none")
    _fails(sim, "alice", Navigate(target="garage"), OutcomeCode.TARGET_UNKNOWN, "'garage'", "table_0")
    _fails(
        sim,
        "alice",
        Navigate(target="table_0", stand_pose=7),
        OutcomeCode.STAND_POSE_INVALID,
        "3 stand pose(s)",
        "0 to 2",
    )
    _fails(sim, "alice", Navigate(target="tray"), OutcomeCode.NOT_NAVIGABLE, "tray", "table_0")
    _fails(sim, "alice", Place(obj="apple", location="table_0"), OutcomeCode.GRIPPER_EMPTY, "empty")
    _fails(sim, "alice", Open(target="table_1"), OutcomeCode.NOT_OPENABLE, "table_1")
    _fails(sim, "alice", Open(target="wardrobe"), OutcomeCode.TARGET_UNKNOWN, "'wardrobe'")
    _fails(sim, "alice", Open(target="drawer_unit"), OutcomeCode.OUT_OF_REACH, "handle of drawer_unit")
    _fails(sim, "alice", Move(dx=3.0, dy=0.0), OutcomeCode.GOAL_INVALID, "1.0 m")
    _fails(
        sim,
        "david",
        Pick(obj="apple"),
        OutcomeCode.NOT_CAPABLE,
        "David cannot pick: its skills are navigate, communicate, wait.",
    )
    _fails(sim, "bob", Navigate(target="table_0"), OutcomeCode.NOT_CAPABLE, "Bob cannot navigate")
    _fails(sim, "bob", Place(obj="x", location="tray"), OutcomeCode.GRIPPER_EMPTY)
    _fails(sim, "carol", Wait(), OutcomeCode.NOT_CAPABLE, "no robot 'carol'")
    assert sim.execute("david", Wait()).succeeded
    with pytest.raises(ValueError, match="world service"):
        sim.execute("alice", Communicate(content="hi", to="bob"))


def test_construction_rejects_unknown_names_with_a_clear_message() -> None:
    with pytest.raises(ValueError, match="unknown task 'juggle'; known tasks: pack_objects"):
        Sim(task="juggle")
    with pytest.raises(ValueError, match="unknown scene 'castle'; known scenes: bathroom, bedroom, kitchen"):
        Sim(scene="castle")
    for n in (2, 7):
        with pytest.raises(ValueError, match="between 3 and 6"):
            check_episode(task="pack_objects", scene="kitchen", n_objects=n)


def test_navigation_failures_of_a_broken_layout(monkeypatch: pytest.MonkeyPatch) -> None:
    """Layouts are data: one with a stand pose inside a wall shows the goal check."""
    table_1 = LAYOUTS["kitchen"].get("table_1")
    assert table_1 is not None
    bad = dataclasses.replace(table_1, stand_poses=((0.5, 0.0, 0.0),) + table_1.stand_poses)  # pose 0 in a wall
    layout = dataclasses.replace(
        LAYOUTS["kitchen"],
        name="broken",
        furniture=tuple(bad if f.name == "table_1" else f for f in LAYOUTS["kitchen"].furniture),
    )
    monkeypatch.setitem(LAYOUTS, "broken", layout)
    with Sim(scene="broken", seed=0, aids=("exact_motion",)) as s:
        _fails(
            s, "alice", Navigate(target="table_1", stand_pose=0), OutcomeCode.GOAL_INVALID, "stand pose 0 of table_1"
        )
        _ok(s.execute("alice", Navigate(target="table_1", stand_pose=1)))
        s.bots["alice"].set_base((2.5, 2.5, 0.0))  # dropped onto the table: the start is invalid
        _fails(s, "alice", Navigate(target="sofa", stand_pose=0), OutcomeCode.START_INVALID, "start pose")
        _fails(s, "alice", Move(dx=0.1, dy=0.0), OutcomeCode.START_INVALID)


def test_no_path_into_a_walled_off_pocket(monkeypatch: pytest.MonkeyPatch) -> None:
    ring = ((3.0, 0.6, 1.6, 0.1), (3.0, 2.6, 1.6, 0.1), (2.2, 1.6, 0.1, 2.1), (3.8, 1.6, 0.1, 2.1))
    table_1 = LAYOUTS["kitchen"].get("table_1")
    assert table_1 is not None
    pocket = dataclasses.replace(table_1, stand_poses=table_1.stand_poses + ((3.0, 1.6, 0.0),))
    layout = dataclasses.replace(
        LAYOUTS["kitchen"],
        name="pocket",
        walls=LAYOUTS["kitchen"].walls + ring,
        furniture=tuple(pocket if f.name == "table_1" else f for f in LAYOUTS["kitchen"].furniture),
    )
    monkeypatch.setitem(LAYOUTS, "pocket", layout)
    with Sim(scene="pocket", seed=0) as s:
        assert s.grid.free(3.0, 1.6)
        _fails(s, "alice", Navigate(target="table_1", stand_pose=2), OutcomeCode.NO_PATH, "no collision-free path")


def test_drawer_opens_for_real_and_contents_wait_for_it(sim: Sim) -> None:
    inside = next(o for o in sim.objects.values() if o.inside)
    if (f := sim.layout.get(inside.on or "")) is None or f.drawer is None:  # the generator's container may have a door
        unit = next(
            g for g in sim.layout.furniture if g.drawer is not None and g.drawer.max_object_height >= inside.kind.height
        )
        assert unit.drawer is not None
        inside.on, inside.local = unit.name, unit.drawer.slots[0]
        sim.world.follow_container(inside)
    drawer = inside.on or ""
    spec = sim.layout.get(drawer)
    assert spec is not None and spec.drawer is not None, f"{inside.name} is in {drawer}, not in a drawer"
    travel = spec.drawer.travel
    before = sim.position(inside)
    _ok(sim.execute("alice", Navigate(target=drawer, stand_pose=0)))
    assert "closed: open it" in sim.execute("alice", Navigate(target=drawer, stand_pose=0)).feedback
    assert _obj(sim.observe("alice", 1), inside.name) is None  # standing at it is not seeing inside
    sim.known["alice"].add(inside.name)  # suppose she was told
    _fails(sim, "alice", Pick(obj=inside.name), OutcomeCode.NOT_REACHABLE_CONTAINER, "closed", "open it first")
    out = _ok(sim.execute("alice", Open(target=drawer)))
    assert inside.name in out.feedback and out.sim_time > 0
    body, joint = sim.scene.bodies[drawer], sim.scene.joints[drawer]
    assert p.getJointState(body, joint, physicsClientId=sim.cid)[0] == pytest.approx(travel)
    after = sim.position(inside)
    assert math.dist(before, after) == pytest.approx(travel, abs=1e-6)  # moved out with the drawer
    view = next(f for f in sim.observe("alice", 2).furniture if f.name == drawer)
    assert view.openable and view.is_open
    _fails(sim, "alice", Open(target=drawer), OutcomeCode.ALREADY_OPEN, "already open")
    _ok(sim.execute("alice", Pick(obj=inside.name)))
    held = _obj(sim.observe("alice", 3), inside.name)
    assert held is not None and held.held_by == "alice" and held.on is None
    _fails(sim, "alice", Pick(obj=inside.name), OutcomeCode.GRIPPER_FULL, inside.name)
    _fails(sim, "alice", Place(obj="apple", location="table_0"), OutcomeCode.WRONG_OBJECT, f"You hold {inside.name}")
    _fails(
        sim, "alice", Place(obj=inside.name, location="attic"), OutcomeCode.LOCATION_UNKNOWN, "'attic'", "table_0"
    )  # the places Alice may use
    _fails(sim, "alice", Place(obj=inside.name, location=drawer), OutcomeCode.LOCATION_UNKNOWN)
    _fails(sim, "alice", Place(obj=inside.name, location="table_1"), OutcomeCode.TOO_FAR, "table_1")


@pytest.mark.parametrize(("scene", "chest"), [("bedroom", "toy_chest"), ("bathroom", "laundry_chest")])
def test_a_chest_lid_swings_up_on_its_hinge_and_shows_what_is_inside(scene: str, chest: str) -> None:
    with Sim(task="pack_objects", scene=scene, seed=0, n_objects=6, aids=("exact_motion",)) as sim:
        obj = next(o for o in sim.objects.values() if not o.inside)  # put one object in the chest
        obj.on, obj.inside, obj.local = chest, True, (0.0, -0.05)
        sim.world.follow_container(obj)
        sim.known["alice"].add(obj.name)
        assert sim.position(obj)[2] < sim.layout.get(chest).top  # type: ignore[union-attr]
        body, joint = sim.scene.bodies[chest], sim.scene.joints[chest]
        assert p.getJointInfo(body, joint, physicsClientId=sim.cid)[2] == p.JOINT_REVOLUTE
        handle_shut = sim.handle_position(chest)
        out = _ok(sim.execute("alice", Navigate(target=chest, stand_pose=0)))
        assert "is closed" in out.feedback and obj.name not in out.feedback
        _fails(sim, "alice", Pick(obj=obj.name), OutcomeCode.NOT_REACHABLE_CONTAINER, "closed")
        out = _ok(sim.execute("alice", Open(target=chest)))
        assert obj.name in out.feedback
        assert p.getJointState(body, joint, physicsClientId=sim.cid)[0] == pytest.approx(math.radians(75))
        handle_open = sim.handle_position(chest)
        assert handle_open[2] - handle_shut[2] > 0.4  # the lid stands up, its handle high above the rim
        view = next(f for f in sim.observe("alice", 2).furniture if f.name == chest)
        assert view.openable and view.is_open
        _ok(sim.execute("alice", Pick(obj=obj.name)))


def test_a_far_grasp_reports_the_offsets_that_fix_it(sim: Sim) -> None:
    bob = sim.observe("bob", 0)
    far = next(
        t for t in bob.targets if (o := _obj(bob, t)) is not None and o.on == "table_0" and not _bob_can_reach(bob, o)
    )
    _fails(sim, "bob", Pick(obj=far), OutcomeCode.TOO_FAR, far)
    sim.tell("alice", "bob", f"I cannot reach the {far}.")
    _ok(sim.execute("alice", Navigate(target="table_0", stand_pose=0)))  # the stand pose at Bob's end
    _fails(sim, "alice", Move(dx=0.0, dy=0.5), OutcomeCode.GOAL_INVALID, "obstacle")  # into the table
    out = _fails(sim, "alice", Pick(obj=far), OutcomeCode.TOO_FAR, far, "dx=")
    assert float(out.details["distance"]) > 0.01 and {"dx", "dy"} <= set(out.details)
    _ok(sim.execute("alice", Move(dx=float(out.details["dx"]), dy=float(out.details["dy"]))))
    _ok(sim.execute("alice", Pick(obj=far)))


def test_a_planner_that_starts_in_collision_says_so(sim: Sim) -> None:
    bob = sim.bots["bob"]
    near = next(
        t
        for t in sim.targets
        if (o := _obj(sim.observe("bob", 0), t)) is not None and _bob_can_reach(sim.observe("bob", 0), o)
    )
    bob.set_arm(np.array([0.0, 1.2, 0.0, -1.0, 0.0, 2.0, 0.785]))  # the hand pushed into the table top
    _fails(sim, "bob", Pick(obj=near), OutcomeCode.CONFIG_INVALID, "start configuration invalid")


def test_placing_checks_where_the_object_ends_up(sim: Sim) -> None:
    bob = sim.observe("bob", 0)
    near = next(t for t in bob.targets if (o := _obj(bob, t)) is not None and _bob_can_reach(bob, o))
    _ok(sim.execute("bob", Pick(obj=near)))
    _ok(sim.execute("bob", Place(obj=near, location="tray")))
    x, y, z = sim.position(sim.objects[near])
    assert sim.layout.in_goal_area(x, y) and sim.objects[near].on == "tray"
    assert sim.evaluate().placed == 1
    assert sim.task_status() == f"In the tray: {near}."  # the paper's status: what is in the tray, nothing judged
    # out again onto the table, within Bob's reach
    _ok(sim.execute("bob", Pick(obj=near)))
    _ok(sim.execute("bob", Place(obj=near, location="table_0")))
    assert sim.objects[near].on == "table_0" and sim.evaluate().placed == 0


def test_a_distractor_in_the_tray_spoils_success() -> None:
    with Sim(seed=4, n_objects=3, aids=("status_hints",)) as s:
        extra = next(o.name for o in s.objects.values() if not o.target)
        obj = s.objects[extra]
        obj.on = "tray"  # as if it had been packed
        assert not s.evaluate().success
        assert f"not on the list (take it out): {extra}" in s.task_status()


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_no_observation_leaks_an_unseen_object(scene: str) -> None:
    with Sim(scene=scene, seed=2, n_objects=6, aids=("exact_motion",)) as sim:
        table_0 = {o.name for o in sim.objects.values() if o.on in ("table_0", "tray")}
        assert {o.name for o in sim.observe("bob", 0).objects} == table_0
        assert sim.observe("alice", 0).objects == [] and sim.observe("david", 0).objects == []
        bob, alice = sim.observe("bob", 0), sim.observe("alice", 0)
        assert bob.targets == sim.targets and alice.targets == [] and sim.observe("david", 0).targets == []
        assert bob.task_status is not None and alice.task_status is None
        assert alice.teammates == {
            "bob": ["pick", "place", "communicate", "wait"],
            "david": ["navigate", "communicate", "wait"],
        }
        assert bob.status.base is None and bob.status.arm_base is not None and bob.status.reach
        assert sim.observe("david", 0).status.arm_base is None and sim.observe("david", 0).status.reach is None
        # David looks at a surface: he learns what is on it, nobody else does
        container = next(o.on for o in sim.objects.values() if o.inside)
        assert container is not None
        far = next(o for o in sim.objects.values() if o.on not in ("table_0", container) and not o.inside)
        out = _ok(sim.execute("david", Navigate(target=far.on or "", stand_pose=0)))
        assert far.name in out.feedback and float(out.details["path_length"]) > 0
        assert far.name in {o.name for o in sim.observe("david", 1).objects}
        assert far.name not in {o.name for o in sim.observe("alice", 1).objects}
        # a closed container hides its contents even from a robot standing at it
        _ok(sim.execute("alice", Navigate(target=container, stand_pose=0)))
        hidden = {o.name for o in sim.objects.values() if o.inside}
        assert not hidden & {o.name for o in sim.observe("alice", 2).objects}
        # told by David, Alice learns only what David knows; names may be written with spaces
        spaced = far.name.replace("_", " ")
        sim.tell("alice", "david", f"On {far.on} I found a {spaced.upper()}; maybe {', '.join(hidden)} too.")
        seen = {o.name for o in sim.observe("alice", 3).objects}
        assert far.name in seen and not hidden & seen
        # an object Alice never learned is unknown to her pick, and the failure names nothing new
        secret = next(iter(hidden))
        out = _fails(sim, "alice", Pick(obj=secret), OutcomeCode.OBJECT_UNKNOWN)
        assert not (hidden - {secret}) & set(out.feedback.replace(",", " ").replace(".", " ").split())
        _fails(sim, "alice", Navigate(target=secret), OutcomeCode.TARGET_UNKNOWN)
        # full ground truth stays available to observers
        furniture, objects = sim.views()
        assert {o.name for o in objects} == set(sim.objects) and {f.name for f in furniture} >= {
            "table_0",
            "tray",
            container,
        }
