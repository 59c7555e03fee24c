"""Arm IK (FK-verified) and OMPL BIT* planning in the shadow client, against real PyBullet."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import numpy as np
import pytest

from mhrc.core.protocol import Action, SkillOutcome
from mhrc.world.arm import HOME, LOWER, UPPER, ArmPlanner, straight
from mhrc.world.assets import AssetDir
from mhrc.world.scene import LAYOUTS, StaticBody, scene_statics
from mhrc.world.sim import Sim

BASE = (0.0, 0.0, 0.7)


@pytest.fixture
def planner() -> Iterator[ArmPlanner]:
    pl = ArmPlanner([], seed=0, budget=12_000)
    pl.set_base(BASE, 0.0)
    yield pl
    pl.close()


def test_ik_solutions_are_verified_by_forward_kinematics(planner: ArmPlanner) -> None:
    for target in [(0.45, 0.1, 0.75), (0.35, -0.3, 0.85), (0.6, 0.0, 0.72)]:
        q = planner.ik(target, 0.0, HOME)
        assert q is not None, target
        assert np.all(q >= LOWER - 1e-9) and np.all(q <= UPPER + 1e-9)
        pos, orn = planner.fk(q)
        assert np.linalg.norm(pos - np.array(target)) < 0.002
        z_axis = np.array(
            [
                2 * (orn[0] * orn[2] + orn[3] * orn[1]),
                2 * (orn[1] * orn[2] - orn[3] * orn[0]),
                1 - 2 * (orn[0] ** 2 + orn[1] ** 2),
            ]
        )
        assert z_axis[2] < -0.99  # the tool points down


def test_ik_reports_how_far_an_unreachable_target_stays(planner: ArmPlanner) -> None:
    res = planner.solve((1.6, 0.0, 0.8), 0.0, HOME, restarts=3)
    assert res.q is None and not res.collided and res.error > 0.4


def test_validity_sees_obstacles(planner: ArmPlanner) -> None:
    q = planner.ik((0.5, 0.0, 0.8), 0.0, HOME)
    assert q is not None and planner.valid(q)
    planner.set_box("block", (0.5, 0.0, 0.8), (0.05, 0.05, 0.05))
    assert not planner.valid(q)
    res = planner.solve((0.5, 0.0, 0.8), 0.0, HOME, restarts=3)
    assert res.q is None and res.collided  # reachable, but only through the block


def test_invalid_start_or_goal_is_reported_before_planning(planner: ArmPlanner) -> None:
    goal = planner.ik((0.5, 0.2, 0.9), 0.0, HOME)
    assert goal is not None
    planner.set_box("block", (0.5, 0.2, 0.9), (0.04, 0.04, 0.04))
    res = planner.plan(HOME, goal)
    assert res.path is None and res.reason == "goal_invalid" and res.checks <= 2
    res = planner.plan(goal, HOME)
    assert res.path is None and res.reason == "start_invalid" and res.checks == 1


def test_plans_avoid_a_wall_and_end_where_asked(planner: ArmPlanner) -> None:
    start = planner.ik((0.45, -0.35, 0.85), 0.0, HOME)
    goal = planner.ik((0.45, 0.35, 0.85), 0.0, HOME)
    assert start is not None and goal is not None
    planner.set_box("wall", (0.45, 0.0, 0.9), (0.2, 0.02, 0.2))  # between the two, not over them
    assert not all(planner.valid(q) for q in straight(start, goal, 60)), "the straight motion must collide"
    res = planner.plan(start, goal)
    assert res.path is not None, res.reason
    assert np.allclose(res.path[0], start) and np.allclose(res.path[-1], goal)
    for a, b in zip(res.path, res.path[1:]):  # densely re-checked
        n = max(2, int(np.max(np.abs(b - a)) / 0.01) + 1)
        assert all(planner.valid(q) for q in straight(a, b, n))


def test_plans_do_not_depend_on_earlier_plans(planner: ArmPlanner) -> None:
    goal = planner.ik((0.3, 0.4, 0.8), 0.0, HOME)
    other = planner.ik((0.5, -0.3, 0.9), 0.0, HOME)
    assert goal is not None and other is not None
    planner.set_box("pillar", (0.4, 0.15, 0.9), (0.03, 0.03, 0.3))
    first = planner.plan(HOME, goal).path
    planner.plan(HOME, other)  # a plan in between advances OMPL's random streams
    again = planner.plan(HOME, goal).path
    assert first is not None and again is not None
    assert len(first) == len(again) and all(np.array_equal(a, b) for a, b in zip(first, again))


def test_the_shadow_world_holds_the_scene() -> None:
    assets = AssetDir()
    try:
        statics = scene_statics(LAYOUTS["kitchen"], assets)
        pl = ArmPlanner(statics, seed=0)
        try:
            assert set(pl.bodies) == {s.name for s in statics}
            assert all(isinstance(s, StaticBody) for s in statics)
            # an arm standing in front of table_0 cannot push its hand into the table top
            pl.set_base((-3.0, -0.75, 0.65), math.pi / 2)
            assert pl.ik((-3.0, -0.2, 0.70 + 0.015), math.pi / 2, HOME) is not None
            assert pl.ik((-3.0, -0.2, 0.60), math.pi / 2, HOME) is None
        finally:
            pl.close()
    finally:
        assets.close()


def test_a_slow_machine_plans_what_a_fast_one_does(planner: ArmPlanner) -> None:
    """The budget is counted in collision checks, not seconds: the same plan on a machine made
    slow (every check takes longer, as on two cores shared by an eval, a bench and tests) is the
    same path, where a budget in seconds ran out and failed it."""
    start = planner.ik((0.45, -0.35, 0.85), 0.0, HOME)
    goal = planner.ik((0.45, 0.35, 0.85), 0.0, HOME)
    assert start is not None and goal is not None
    planner.set_box("wall", (0.45, 0.0, 0.9), (0.2, 0.02, 0.2))
    fast = planner.plan(start, goal)
    assert fast.path is not None and fast.checks > 50
    check = planner.valid
    pause = 2.0 / fast.checks  # the whole plan now takes over 2 s, above the old 1.5 s budget

    def slow(q: np.ndarray) -> bool:
        time.sleep(pause)
        return check(q)

    planner.valid = slow  # type: ignore[method-assign]
    try:
        slowed = planner.plan(start, goal)
    finally:
        del planner.valid
    assert slowed.path is not None and slowed.checks == fast.checks
    assert all(np.array_equal(a, b) for a, b in zip(fast.path, slowed.path))


def test_the_shadow_panda_collides_as_pybullet_datas_does() -> None:
    """The planning client loads panda.urdf without its visual meshes (7x faster): the same
    collision shapes, so the same contacts in every configuration, and the same kinematics;
    set_joints (one call for the seven joints) leaves the state a reset per joint left: the same
    links, joints and contacts (listed in another order now and then; `valid` asks only whether
    there is one)."""
    import pybullet_data

    from mhrc.world.arm import ARM_JOINTS, set_joints
    from mhrc.world.quiet import pybullet as p

    pl = ArmPlanner([], seed=0)
    clients = [p.connect(p.DIRECT), p.connect(p.DIRECT)]
    try:
        urdfs = [pl.panda, pybullet_data.getDataPath() + "/franka_panda/panda.urdf"]
        arms = [p.loadURDF(u, useFixedBase=True, physicsClientId=c) for u, c in zip(urdfs, clients)]
        for c in clients:
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=(0.2, 0.2, 0.2), physicsClientId=c)
            p.createMultiBody(0, shape, -1, (0.45, -0.3, 0.3), physicsClientId=c)
        rng = np.random.default_rng(0)
        touching = 0
        for _ in range(300):
            q = rng.uniform(LOWER, UPPER)
            set_joints(clients[0], arms[0], q)
            for j in ARM_JOINTS:  # one joint at a time, as before set_joints
                p.resetJointState(arms[1], j, float(q[j]), physicsClientId=clients[1])
            seen = []
            for c, body in zip(clients, arms):
                p.performCollisionDetection(physicsClientId=c)
                contacts = sorted(p.getContactPoints(bodyA=body, physicsClientId=c))  # in another order, now and then
                links = [p.getLinkState(body, k, computeForwardKinematics=True, physicsClientId=c) for k in range(12)]
                seen.append((contacts, links, p.getJointStates(body, list(ARM_JOINTS), physicsClientId=c)))
            assert seen[0] == seen[1]
            touching += bool(seen[0][0])
        assert 30 < touching < 270  # both kinds of configuration were compared
    finally:
        for c in clients:
            p.disconnect(c)
        pl.close()


def _world_state(sim: Sim) -> list[object]:
    """Every body's pose and every joint's position and velocity, as PyBullet holds them."""
    from mhrc.world.quiet import pybullet as p

    out: list[object] = []
    for k in range(p.getNumBodies(physicsClientId=sim.cid)):
        body = p.getBodyUniqueId(k, physicsClientId=sim.cid)
        out.append(p.getBasePositionAndOrientation(body, physicsClientId=sim.cid))
        joints = list(range(p.getNumJoints(body, physicsClientId=sim.cid)))
        out.append([s[:2] for s in p.getJointStates(body, joints, physicsClientId=sim.cid)] if joints else [])
    return out


def _play(monkeypatch: pytest.MonkeyPatch, every_waypoint: bool) -> list[tuple[str, list[object]]]:
    """An episode of the team plan (motion noise on: releases slip and settle), the world after each skill."""
    from itertools import pairwise

    from mhrc.world.quiet import pybullet as p
    from mhrc.world.robots import RobotBody
    from mhrc.world.team_plan import play_team_plan

    if every_waypoint:  # as RobotBody.run was: every waypoint, a reset per joint

        def set_arm(self: RobotBody, q: np.ndarray) -> None:
            self.q = np.array(q, dtype=float)
            for j in range(7):
                p.resetJointState(self.arm, j, float(self.q[j]), physicsClientId=self.cid)
            self._carry()

        def run(self: RobotBody, path: list[np.ndarray], joint_speed: float = 1.0) -> float:
            for q in path:
                self.set_arm(q)
            return sum(float(np.max(np.abs(b - a))) for a, b in pairwise(path)) / joint_speed

        monkeypatch.setattr(RobotBody, "set_arm", set_arm)
        monkeypatch.setattr(RobotBody, "run", run)
    sim = Sim(task="make_sandwich", scene="kitchen", seed=3, n_objects=4)
    seen: list[tuple[str, list[object]]] = []
    try:

        def act(robot: str, action: Action) -> SkillOutcome:
            out = sim.execute(robot, action)
            seen.append((out.model_dump_json(), _world_state(sim)))
            return out

        play_team_plan(sim, act)
    finally:
        sim.close()
        monkeypatch.undo()
    return seen


@pytest.mark.slow
def test_an_arm_set_to_its_paths_end_leaves_the_world_every_waypoint_left(monkeypatch: pytest.MonkeyPatch) -> None:
    """RobotBody.run sets only a path's end, its seven joints in one call: after every skill of an
    episode (releases that slip and settle under physics included) every body and joint of the
    live world is where, and moves as, setting each waypoint a joint at a time left it."""
    before = _play(monkeypatch, every_waypoint=True)
    now = _play(monkeypatch, every_waypoint=False)
    assert len(before) > 20
    assert now == before


def _validity(sim: Sim, robot: str, n: int = 1500) -> list[bool]:
    """Whether each of n random configurations (the same n every time) of `robot`'s arm, where it
    stands, touches nothing, in its world's planning client."""
    from mhrc.world.skills.reaching import planner_for

    pl = planner_for(sim.skill_context, sim.bots[robot])
    rng = np.random.default_rng(7)
    return [pl.valid(q) for q in rng.uniform(LOWER, UPPER, size=(n, 7))]


def test_a_planning_client_handed_back_plays_the_next_world_as_a_new_one_would() -> None:
    """A closed world's shadow client goes back to the pool (world/shadow.py) and the next world of
    the same layout and task takes it. One episode in it opened a drawer (a furniture joint the
    planner mirrors), moved both arms and left Alice's chassis box by the table: in the next world
    every arm configuration is valid or not as in a world on a client of its own, and the same
    actions give the same outcomes and end. The closed world's planner has let go: a call on it
    fails as on a disconnected client."""
    from mhrc.core.protocol import Navigate, Open, Pick, Place
    from mhrc.world import shadow
    from mhrc.world.quiet import pybullet as p

    shadow.POOL.close()
    with Sim(seed=2, n_objects=4) as first:
        for robot, action in [
            ("alice", Navigate(target="drawer_unit", stand_pose=0)),
            ("alice", Open(target="drawer_unit")),
            ("alice", Navigate(target="table_0", stand_pose=0)),
        ]:
            assert first.execute(robot, action).succeeded, action
        far = next(t for t in first.targets if first.objects[t].on == "table_0")
        first.execute("alice", Pick(obj=far))
        first.execute("bob", Pick(obj=far))
        handed_back, planner = first.world.planner.cid, first.world.planner
    assert len(shadow.POOL) == 1 and planner.cid == -1
    with pytest.raises(p.error):
        planner.valid(HOME)
    with Sim(seed=2, n_objects=4) as a, Sim(seed=2, n_objects=4) as b:
        assert a.world.planner.cid == handed_back and b.world.planner.cid != handed_back  # b: a new client
        bob = _validity(a, "bob")
        assert bob == _validity(b, "bob") and 0 < sum(bob) < len(bob)
        play: list[tuple[str, Action]] = [("alice", Navigate(target="drawer_unit", stand_pose=0))]
        assert [a.execute(r, x) for r, x in play] == [b.execute(r, x) for r, x in play]
        alice = _validity(a, "alice")  # by the drawer the first world left open
        assert alice == _validity(b, "alice") and 0 < sum(alice) < len(alice)
        far = next(t for t in a.targets if a.objects[t].on == "table_0")
        play = [("alice", Open(target="drawer_unit")), ("alice", Navigate(target="table_0", stand_pose=0))]
        play += [("bob", Pick(obj=far)), ("alice", Pick(obj=far)), ("alice", Place(obj=far, location="table_0"))]
        play += [("bob", Pick(obj=far)), ("bob", Place(obj=far, location="tray"))]
        for robot, action in play:
            assert a.execute(robot, action) == b.execute(robot, action), action
        assert a.snapshot() == b.snapshot()
        assert a.world.planner.checks == b.world.planner.checks  # the plans checked the same states
