"""The paper's Table III feedback and its rule that only Bob finishes the task, in real PyBullet:
too-far picks report offsets (the solved move is an aid), opening says what is inside and
where, navigation and placing fail by real behaviour (seeded base noise, released objects
settling under physics) and never in the exact_motion aid, and no sentence gives advice the
robot cannot follow. The heuristic team is driven tick by tick as the world service does.
"""

from __future__ import annotations

import asyncio
import math
import re
from dataclasses import dataclass

import pybullet as p
import pytest
from mhrc.agents.heuristic import heuristic_policy
from mhrc.world.robots import KINDS
from mhrc.world.sim import Sim

from mhrc.protocol import (
    Action,
    ActionResult,
    Communicate,
    Move,
    Navigate,
    Open,
    OutcomeCode,
    Pick,
    Place,
    RobotMessage,
    SkillOutcome,
)

NAVIGATE_TO = re.compile(r"\b[Nn]avigate to (?:a stand pose of |stand pose \d+ of )?([A-Za-z0-9_]+)")
# episodes (task, scene, n_objects, seed) tried in order until both real failures have been seen:
# the first two show both today; the rest keep the test meaningful if scenes or policies change
EPISODES = [
    ("make_sandwich", "kitchen", 4, 5),
    ("make_sandwich", "kitchen", 6, 7),
    *[("make_sandwich", scene, n, seed) for seed in range(10) for n in (6, 5) for scene in ("kitchen", "bedroom", "bathroom")],
]
MAX_EPISODES = 24


@dataclass
class Step:
    tick: int
    robot: str
    action: Action
    outcome: SkillOutcome
    base: tuple[float, float, float] | None  # the robot's base after the action
    free: bool  # whether that base stands on a free grid cell


@dataclass
class Episode:
    key: tuple[str, str, int, int]
    success: bool
    steps: list[Step]
    fixtures: set[str]
    stand_furniture: set[str]  # furniture with stand poses


def play(sim: Sim, horizon: int = 60) -> tuple[bool, list[Step]]:
    """The heuristic team on `sim`, as the world service runs it: every robot decides on its
    observation, the actions execute in robot order, messages arrive with the next observation."""
    loop = asyncio.new_event_loop()
    policies = {r: heuristic_policy(r) for r in sim.robots}
    obs = {r: sim.observe(r, 0) for r in sim.robots}
    steps: list[Step] = []
    try:
        for tick in range(horizon):
            inbox: dict[str, list[RobotMessage]] = {r: [] for r in sim.robots}
            batch = [(r, loop.run_until_complete(policies[r].decide(obs[r])).action) for r in sim.robots]
            outcomes = []
            for r, a in batch:
                if isinstance(a, Communicate):
                    inbox[a.to].append(RobotMessage(sender=r, to=a.to, content=a.content, tick=tick))
                    sim.tell(a.to, r, a.content)
                    out = SkillOutcome.ok(f"Your message to {a.to} was sent.")
                else:
                    out = sim.execute(r, a)
                outcomes.append(out)
                base = sim.bots[r].base
                steps.append(Step(tick, r, a, out, base, base is None or sim.grid.free(base[0], base[1])))
            success = sim.evaluate().success
            for (r, a), out in zip(batch, outcomes):
                o = sim.observe(r, tick + 1).model_copy(update={"new_messages": inbox[r]})
                policies[r].record(ActionResult(goal_id=f"{r}-{tick}", robot=r, tick=tick, action=a, outcome=out, observation=o, done=success))
                obs[r] = o
            if success:
                return True, steps
        return False, steps
    finally:
        loop.close()


def run_episode(key: tuple[str, str, int, int], aids: tuple[str, ...] = ()) -> Episode:
    task, scene, n, seed = key
    with Sim(task=task, scene=scene, seed=seed, n_objects=n, aids=aids) as sim:
        ok, steps = play(sim)
        return Episode(key, ok, steps, set(sim.fixtures), {f.name for f in sim.layout.furniture if f.stand_poses})


@pytest.fixture(scope="module")
def paper_episodes() -> list[Episode]:
    """Heuristic episodes at the paper's fidelity, until OFF_TARGET and PLACE_FAILED have both occurred."""
    out: list[Episode] = []
    seen: set[OutcomeCode] = set()
    for key in EPISODES[:MAX_EPISODES]:
        ep = run_episode(key)
        out.append(ep)
        seen |= {s.outcome.code for s in ep.steps}
        if {OutcomeCode.OFF_TARGET, OutcomeCode.PLACE_FAILED} <= seen:
            break
    return out


def _table_target(sim: Sim, far: bool) -> str:
    """A target on table_0 within Bob's reach, or (far) more than 10 cm beyond it."""
    bob = sim.bots["bob"]
    ab = bob.arm_base()
    assert ab is not None and bob.kind.reach is not None
    reach = bob.kind.reach

    def fits(t: str) -> bool:
        d = math.dist(sim.position(sim.objects[t])[:2], ab[:2])
        return d > reach + 0.1 if far else d <= reach

    return next(t for t in sim.targets if sim.objects[t].on == "table_0" and fits(t))


def _near_target(sim: Sim) -> str:
    return _table_target(sim, far=False)


def _far_target(sim: Sim) -> str:
    return _table_target(sim, far=True)


def _arrive(sim: Sim, robot: str, target: str, stand_pose: int = 0) -> SkillOutcome:
    """Navigate until the base stops on target (a slip is followed by another try, as the feedback says)."""
    for _ in range(4):
        out = sim.execute(robot, Navigate(target=target, stand_pose=stand_pose))
        if out.code != OutcomeCode.OFF_TARGET:
            assert out.succeeded, out.feedback
            return out
    raise AssertionError(f"{robot} never reached {target}")


def _no_bad_advice(robot: str, text: str, fixtures: set[str], stand_furniture: set[str]) -> None:
    """Table III feedback never advises what the robot cannot do."""
    if robot == "bob":
        assert not re.search(r"(?<!cannot )\b[Nn]avigat|\b[Mm]ov(e|ing) your base|\bopen it\b", text), text
    for name in NAVIGATE_TO.findall(text):
        assert name not in fixtures and name in stand_furniture, (name, text)


# --------------------------------------------------------------------------- pick too far


@pytest.mark.parametrize("aids", [(), ("solved_move",)])
def test_a_too_far_pick_reports_distance_and_offsets_and_the_solved_move_only_as_an_aid(aids: tuple[str, ...]) -> None:
    with Sim(seed=1, n_objects=4, aids=aids) as sim:
        far = _far_target(sim)
        out = sim.execute("bob", Pick(obj=far))  # Bob, a fixed arm: the distance, no offsets, no advice
        assert out.code == OutcomeCode.TOO_FAR and far in out.feedback
        assert set(out.details) == {"distance"} and float(out.details["distance"]) > 0.01
        assert f"{float(out.details['distance']):.2f} m" in out.feedback
        _no_bad_advice("bob", out.feedback, set(sim.fixtures), set())
        assert "offset" not in out.feedback and "dx=" not in out.feedback

        sim.learn("alice", [far])
        _arrive(sim, "alice", "table_0", 0)  # the stand pose at Bob's end: the object is far from it
        out = sim.execute("alice", Pick(obj=far))
        assert out.code == OutcomeCode.TOO_FAR, out.feedback
        base = sim.bots["alice"].base
        assert base is not None
        x, y, _ = sim.position(sim.objects[far])
        ox, oy = float(out.details["offset_x"]), float(out.details["offset_y"])
        assert (ox, oy) == pytest.approx((x - base[0], y - base[1]), abs=6e-3)  # object minus base centre, to the cm
        assert f"x={ox:+.2f} m, y={oy:+.2f} m" in out.feedback and f"{float(out.details['distance']):.2f} m" in out.feedback
        if "solved_move" not in aids:
            assert "dx" not in out.details and "dx=" not in out.feedback and "Moving your base" not in out.feedback
            return
        assert {"dx", "dy"} <= set(out.details) and "Moving your base by dx=" in out.feedback
        moved = sim.execute("alice", Move(dx=float(out.details["dx"]), dy=float(out.details["dy"])))
        assert moved.succeeded, moved.feedback
        assert sim.execute("alice", Pick(obj=far)).succeeded


# --------------------------------------------------------------------------- open


def test_opening_says_what_is_inside_and_where() -> None:
    with Sim(seed=1, n_objects=6, aids=("exact_motion",)) as sim:
        container = next(o.on for o in sim.objects.values() if o.inside)
        assert container is not None
        inside = [o for o in sim.objects.values() if o.inside and o.on == container]
        _arrive(sim, "alice", container, 0)
        out = sim.execute("alice", Open(target=container))
        assert out.succeeded, out.feedback
        for o in inside:
            x, y, z = sim.position(o)
            assert f"{o.name} at ({x:.2f}, {y:.2f}, {z:.2f})" in out.feedback, out.feedback


# --------------------------------------------------------------------------- only Bob finishes the task


def test_only_the_tabletop_arm_finishes_the_task() -> None:
    assert [k.id for k in KINDS.values() if k.finishes_task] == ["tabletop_arm"]


@pytest.mark.parametrize("task", ["pack_objects", "sort_solids", "make_sandwich"])
def test_alice_may_not_place_on_a_goal_fixture_and_bob_may(task: str) -> None:
    with Sim(task=task, seed=1, n_objects=4) as sim:
        near = _near_target(sim)
        goal = sim.goals[near]
        other = next(o for o in sim.objects.values() if o.name != near and not o.inside)
        sim.grasp(sim.bots["alice"], other)  # as if she had picked it up
        for fixture in sim.fixtures:
            out = sim.execute("alice", Place(obj=other.name, location=fixture))
            assert out.code == OutcomeCode.NOT_CAPABLE and not out.succeeded
            assert f"place {other.name} on table_0" in out.feedback and "Bob" in out.feedback, out.feedback
        assert sim.bots["alice"].holding == other.name and other.held_by == "alice"  # nothing happened

        assert sim.execute("bob", Pick(obj=near)).succeeded
        # the released object settles under physics alone: nothing else in the world moves
        before = {o.name: (sim.position(o), sim.yaw(o)) for o in sim.objects.values() if o.name != near}
        bots = {r.name: (r.base, tuple(r.q)) for r in sim.bots.values() if r.name != "bob"}
        joints = {n: p.getJointState(sim.scene.bodies[n], sim.scene.joints[n], physicsClientId=sim.cid)[0] for n in sim.opening}
        out = sim.execute("bob", Place(obj=near, location=goal))
        assert out.succeeded and sim.objects[near].on == goal, out.feedback
        assert {o.name: (sim.position(o), sim.yaw(o)) for o in sim.objects.values() if o.name != near} == before
        assert {r.name: (r.base, tuple(r.q)) for r in sim.bots.values() if r.name != "bob"} == bots
        assert {n: p.getJointState(sim.scene.bodies[n], sim.scene.joints[n], physicsClientId=sim.cid)[0] for n in sim.opening} == joints


# --------------------------------------------------------------------------- advice a robot can follow


def test_no_sentence_tells_bob_to_navigate_or_anyone_to_navigate_to_a_fixture() -> None:
    with Sim(seed=1, n_objects=4) as sim:
        fixtures = set(sim.fixtures)
        stand = {f.name for f in sim.layout.furniture if f.stand_poses}
        outs: list[tuple[str, SkillOutcome]] = []

        def run(robot: str, action: Action) -> SkillOutcome:
            out = sim.execute(robot, action)
            outs.append((robot, out))
            return out

        hidden = next(o.name for o in sim.objects.values() if o.inside)
        container = sim.objects[hidden].on or ""
        sim.learn("bob", [hidden])
        assert run("bob", Pick(obj=hidden)).code == OutcomeCode.NOT_REACHABLE_CONTAINER
        assert run("bob", Pick(obj=_far_target(sim))).code == OutcomeCode.TOO_FAR
        assert run("bob", Navigate(target="table_0")).code == OutcomeCode.NOT_CAPABLE
        near = _near_target(sim)
        assert run("bob", Pick(obj=near)).succeeded
        assert run("bob", Place(obj=near, location="table_1")).code == OutcomeCode.TOO_FAR  # beyond a fixed arm
        assert run("bob", Place(obj=near, location=container)).code == OutcomeCode.LOCATION_UNKNOWN
        assert run("bob", Place(obj=near, location="tray")).succeeded
        # the others are pointed at table_0, never at the tray or at what lies in it
        sim.learn("alice", [near])
        for target in ("tray", near):
            out = run("alice", Navigate(target=target))
            assert out.code == OutcomeCode.NOT_NAVIGABLE and "Navigate to table_0 instead" in out.feedback, out.feedback
        assert run("david", Navigate(target="tray")).code == OutcomeCode.NOT_NAVIGABLE
        out = run("david", Navigate(target=container))  # David cannot open it: he is not told to
        assert out.code in (OutcomeCode.OK, OutcomeCode.OFF_TARGET)
        if out.succeeded:
            assert "closed" in out.feedback and "open it" not in out.feedback
        for robot, out in outs:
            _no_bad_advice(robot, out.feedback, fixtures, stand)


def test_heuristic_episodes_get_no_advice_they_cannot_follow(paper_episodes: list[Episode]) -> None:
    for ep in paper_episodes:
        for s in ep.steps:
            _no_bad_advice(s.robot, s.outcome.feedback, ep.fixtures, ep.stand_furniture)


# --------------------------------------------------------------------------- real failures


def test_navigation_slips_and_placements_fail_in_real_episodes_and_the_team_recovers(paper_episodes: list[Episode]) -> None:
    steps = [s for ep in paper_episodes for s in ep.steps]
    off = [s for s in steps if s.outcome.code == OutcomeCode.OFF_TARGET]
    dropped = [s for s in steps if s.outcome.code == OutcomeCode.PLACE_FAILED and "came to rest" in s.outcome.feedback]
    assert off and dropped, [ep.key for ep in paper_episodes]
    assert all(ep.success for ep in paper_episodes), [ep.key for ep in paper_episodes if not ep.success]
    for s in off:  # stopped where it stopped, on free floor, the distance in the sentence
        assert s.base is not None and s.free
        assert (s.base[0], s.base[1]) == pytest.approx((s.outcome.details["x"], s.outcome.details["y"]), abs=1e-3)
        assert float(s.outcome.details["distance"]) > 0.1 and f"{float(s.outcome.details['distance']):.2f} m" in s.outcome.feedback
    for s in dropped:  # left where the team can pick it up again: on a table, not the floor
        assert isinstance(s.action, Place) and s.outcome.details["on"] not in ("floor", s.action.location), s.outcome
        assert f"came to rest on {s.outcome.details['on']} at" in s.outcome.feedback


def test_with_exact_motion_nothing_slips(paper_episodes: list[Episode]) -> None:
    for ep in paper_episodes:
        if not any(s.outcome.code in (OutcomeCode.OFF_TARGET, OutcomeCode.PLACE_FAILED) for s in ep.steps):
            continue
        exact = run_episode(ep.key, aids=("exact_motion",))
        assert exact.success, ep.key
        codes = {s.outcome.code for s in exact.steps}
        assert OutcomeCode.OFF_TARGET not in codes and OutcomeCode.PLACE_FAILED not in codes, ep.key


def test_noise_is_deterministic_and_exact_motion_stops_on_the_pose() -> None:
    targets = ("sofa", "table_1", "counter", "table_2", "table_0")

    def stops(aids: tuple[str, ...]) -> list[tuple[OutcomeCode, tuple[float, float, float] | None, tuple[float, float, float]]]:
        out = []
        with Sim(seed=3, n_objects=3, aids=aids) as sim:
            for target in targets:
                f = sim.layout.get(target)
                if f is not None and f.stand_poses:
                    code = sim.execute("david", Navigate(target=target)).code
                    out.append((code, sim.bots["david"].base, f.stand_poses[0]))
        return out

    noisy = stops(())
    assert noisy == stops(())  # same seed, same actions: the same stops
    exact = stops(("exact_motion",))
    assert exact and all(code == OutcomeCode.OK and base == pose for code, base, pose in exact)
    assert all(base != pose for _, base, pose in noisy)
