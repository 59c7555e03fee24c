"""The PyBullet world directly: solvability, feedback for bad input, partial views, determinism."""

from __future__ import annotations

import math

import pytest

from mhrc.protocol import Move, Navigate, Open, OutcomeCode, Pick, Place, Wait
from mhrc.world.astar import astar
from mhrc.world.scene import LAYOUTS
from mhrc.world.sim import Sim, check_episode
from mhrc.world.tasks import TASKS
from mhrc.world.team_plan import play_team_plan


def _ok(outcome) -> None:  # type: ignore[no-untyped-def]
    assert outcome.succeeded, outcome.feedback


def _checked(sim: Sim):  # type: ignore[no-untyped-def]
    """sim.execute, asserting success except for the failures the plan expects and recovers from."""

    def run(robot: str, action):  # type: ignore[no-untyped-def]
        out = sim.execute(robot, action)
        expected = (robot == "bob" and isinstance(action, Pick)) or (isinstance(action, Pick) and out.code == OutcomeCode.TOO_FAR)
        assert out.succeeded or expected, (robot, action, out.feedback)
        return out

    return run


@pytest.mark.parametrize("task", sorted(TASKS))
@pytest.mark.parametrize("n_objects", [3, 4, 5, 6])
@pytest.mark.parametrize("seed", [0, 7])
def test_every_generated_episode_is_solvable(task: str, n_objects: int, seed: int) -> None:
    with Sim(task=task, seed=seed, n_objects=n_objects) as sim:
        assert len(sim.targets) == n_objects
        assert sim.evaluate().placed == 0
        play_team_plan(sim, _checked(sim))
        result = sim.evaluate()
        assert result.success and result.placed == n_objects and result.partial_success == 1.0


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_every_stand_pose_is_free_and_reachable(scene: str) -> None:
    with Sim(scene=scene) as sim:
        for robot in ("alice", "david"):
            start = sim.layout.starts[robot]
            for f in sim.layout.furniture:
                for i, (x, y, _) in enumerate(f.stand_poses):
                    assert sim.grid.free(x, y), f"{f.name} stand pose {i} is on an obstacle"
                    assert astar(sim.grid, start[:2], (x, y)) is not None, f"{robot} cannot reach {f.name} pose {i}"


def test_generation_is_deterministic_per_seed() -> None:
    def layout(seed: int) -> dict[str, tuple[object, ...]]:
        with Sim(seed=seed, n_objects=5) as sim:
            return {o.name: (o.on, o.inside, o.target, sim._pos(o)) for o in sim.objects.values()}

    assert layout(3) == layout(3)
    assert layout(3) != layout(4)


def test_each_episode_has_the_work_the_paper_describes() -> None:
    for seed in range(10):
        with Sim(seed=seed, n_objects=3) as sim:
            bob = sim.observe("bob", 0)
            on_table = {o.name for o in bob.objects if o.on == "table_0"}
            reach = bob.status.reach or 0.0
            base = bob.status.arm_base or (0.0, 0.0, 0.0)
            targets = {t: sim.objects[t] for t in sim.targets}
            near = [t for t in targets if t in on_table and math.dist(sim._pos(targets[t])[:2], base[:2]) <= reach]
            far = [t for t in targets if t in on_table and t not in near]
            hidden = [t for t, o in targets.items() if o.inside]
            assert near and far and hidden, (seed, near, far, hidden)
            assert len(sim.objects) > len(sim.targets)  # distractors


def test_bad_arguments_get_failure_feedback_not_exceptions() -> None:
    with Sim(seed=1) as sim:
        cases = [
            ("alice", Pick(obj="applle"), OutcomeCode.OBJECT_UNKNOWN, "applle"),
            ("alice", Navigate(target="fridge"), OutcomeCode.TARGET_UNKNOWN, "fridge"),
            ("alice", Navigate(target="table_0", stand_pose=7), OutcomeCode.STAND_POSE_INVALID, "3 stand pose"),
            ("alice", Navigate(target="tray"), OutcomeCode.NOT_NAVIGABLE, "tray"),
            ("alice", Place(obj="apple", location="table_0"), OutcomeCode.GRIPPER_EMPTY, "empty"),
            ("alice", Open(target="table_1"), OutcomeCode.NOT_OPENABLE, "table_1"),
            ("alice", Move(dx=3.0, dy=0.0), OutcomeCode.GOAL_INVALID, "1.0 m"),
            ("david", Pick(obj="apple"), OutcomeCode.NOT_CAPABLE, "David cannot pick"),
            ("bob", Navigate(target="table_0"), OutcomeCode.NOT_CAPABLE, "Bob cannot navigate"),
        ]
        for robot, action, code, text in cases:
            out = sim.execute(robot, action)
            assert not out.succeeded and out.code == code and text in out.feedback, (action, out)
        assert sim.execute("david", Wait()).succeeded
        with pytest.raises(ValueError, match="unknown task"):
            check_episode(task="juggle", scene="house", n_objects=3)


def test_drawer_opens_for_real_and_contents_must_wait_for_it() -> None:
    with Sim(seed=0) as sim:
        inside = next(o for o in sim.objects.values() if o.inside)
        sim.known["alice"].add(inside.name)
        before = sim._pos(inside)
        _ok(sim.execute("alice", Navigate(target="drawer_unit", stand_pose=0)))
        assert sim.execute("alice", Pick(obj=inside.name)).code == OutcomeCode.NOT_REACHABLE_CONTAINER
        _ok(sim.execute("alice", Open(target="drawer_unit")))
        after = sim._pos(inside)
        assert sim.drawer_open["drawer_unit"] == pytest.approx(0.45)
        assert math.dist(before, after) == pytest.approx(0.45, abs=1e-6)  # moved with the drawer
        assert sim.execute("alice", Open(target="drawer_unit")).code == OutcomeCode.ALREADY_OPEN
        _ok(sim.execute("alice", Pick(obj=inside.name)))
        assert sim.execute("alice", Pick(obj=inside.name)).code == OutcomeCode.GRIPPER_FULL
        assert sim.execute("alice", Place(obj="apple", location="table_0")).code == OutcomeCode.WRONG_OBJECT
        assert sim.execute("alice", Place(obj=inside.name, location="attic")).code == OutcomeCode.LOCATION_UNKNOWN


def test_a_far_grasp_reports_the_offsets_that_fix_it() -> None:
    with Sim(seed=0) as sim:
        far = next(t for t in sim.targets if sim.objects[t].on == "table_0" and not sim.execute("bob", Pick(obj=t)).succeeded)
        sim.known["alice"].add(far)
        _ok(sim.execute("alice", Navigate(target="table_0", stand_pose=0)))  # the stand pose at Bob's end
        out = sim.execute("alice", Pick(obj=far))
        assert out.code == OutcomeCode.TOO_FAR and out.details["distance"] > 0.01
        _ok(sim.execute("alice", Move(dx=float(out.details["dx"]), dy=float(out.details["dy"]))))
        _ok(sim.execute("alice", Pick(obj=far)))


def test_no_observation_leaks_an_unseen_object() -> None:
    with Sim(seed=2, n_objects=6) as sim:
        table_0 = {o.name for o in sim.objects.values() if o.on == "table_0"}
        assert {o.name for o in sim.observe("bob", 0).objects} == table_0
        assert sim.observe("alice", 0).objects == [] and sim.observe("david", 0).objects == []
        assert sim.observe("bob", 0).targets and sim.observe("alice", 0).targets == []
        # David looks at a surface: he learns what is on it, nobody else does
        far = next(o for o in sim.objects.values() if o.on not in ("table_0", "drawer_unit"))
        _ok(sim.execute("david", Navigate(target=far.on or "", stand_pose=0)))
        assert far.name in {o.name for o in sim.observe("david", 1).objects}
        assert far.name not in {o.name for o in sim.observe("alice", 1).objects}
        # a closed container hides its contents even from a robot standing at it
        _ok(sim.execute("alice", Navigate(target="drawer_unit", stand_pose=0)))
        hidden = {o.name for o in sim.objects.values() if o.inside}
        assert not hidden & {o.name for o in sim.observe("alice", 2).objects}
        # told by David, Alice learns only what David knows
        sim.tell("alice", "david", f"On {far.on} I found {far.name}; maybe {', '.join(hidden)} too.")
        seen = {o.name for o in sim.observe("alice", 3).objects}
        assert far.name in seen and not hidden & seen
