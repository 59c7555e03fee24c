"""The paper's Table III feedback and its rule that only Bob finishes the task, in real PyBullet:
too-far picks report offsets (the solved move is an aid), opening says what is inside and
where, navigation and placing fail by real behaviour (seeded base noise, released objects
settling under physics) and never in the exact_motion aid, a failed action's feedback states
its cause and numbers and tells the robot nothing to do (what to do next is the feedback_advice
aid), and the advice that aid gives is advice the robot can follow. The heuristic team is driven
tick by tick as the world service does.
"""

from __future__ import annotations

import asyncio
import inspect
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pybullet as p
import pytest

from mhrc.agents.heuristic import heuristic_policy
from mhrc.core.protocol import (
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
    Wait,
)
from mhrc.world import feedback as fb
from mhrc.world.kinds import KINDS
from mhrc.world.sim import Sim
from mhrc.world.skills import navigation

NAVIGATE_TO = re.compile(r"\b[Nn]avigate to (?:a stand pose of |stand pose \d+ of )?([A-Za-z0-9_]+)")
# episodes (task, scene, n_objects, seed) tried in order until both real failures have been seen:
# the first two show both today (bathroom/5/1 moved up: it was the 14th tried, the first with a failed
# placement); the rest keep the test meaningful if scenes or policies change
EPISODES = [
    ("make_sandwich", "kitchen", 4, 5),
    ("make_sandwich", "bathroom", 5, 1),
    ("make_sandwich", "kitchen", 6, 7),
    *[
        ("make_sandwich", scene, n, seed)
        for seed in range(10)
        for n in (6, 5)
        for scene in ("kitchen", "bedroom", "bathroom")
    ],
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
                policies[r].record(
                    ActionResult(
                        goal_id=f"{r}-{tick}", robot=r, tick=tick, action=a, outcome=out, observation=o, done=success
                    )
                )
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
    """Navigate until the base stops on target (a slip is followed by another try)."""
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
        assert (
            f"x={ox:+.2f} m, y={oy:+.2f} m" in out.feedback
            and f"{float(out.details['distance']):.2f} m" in out.feedback
        )
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
            assert out.feedback == f"Only Bob places objects on {fixture}.", out.feedback  # the constraint, no advice
        assert sim.bots["alice"].holding == other.name and other.held_by == "alice"  # nothing happened

        assert sim.execute("bob", Pick(obj=near)).succeeded
        # the released object settles under physics alone: nothing else in the world moves
        before = {o.name: (sim.position(o), sim.yaw(o)) for o in sim.objects.values() if o.name != near}
        bots = {r.name: (r.base, tuple(r.q)) for r in sim.bots.values() if r.name != "bob"}
        joints = {
            n: p.getJointState(sim.scene.bodies[n], sim.scene.joints[n], physicsClientId=sim.cid)[0]
            for n in sim.opening
        }
        out = sim.execute("bob", Place(obj=near, location=goal))
        assert out.succeeded and sim.objects[near].on == goal, out.feedback
        assert {o.name: (sim.position(o), sim.yaw(o)) for o in sim.objects.values() if o.name != near} == before
        assert {r.name: (r.base, tuple(r.q)) for r in sim.bots.values() if r.name != "bob"} == bots
        assert {
            n: p.getJointState(sim.scene.bodies[n], sim.scene.joints[n], physicsClientId=sim.cid)[0]
            for n in sim.opening
        } == joints


# --------------------------------------------------------------------------- advice a robot can follow


@pytest.mark.parametrize("aids", [(), ("feedback_advice",)])
def test_no_sentence_tells_bob_to_navigate_or_anyone_to_navigate_to_a_fixture(aids: tuple[str, ...]) -> None:
    with Sim(seed=1, n_objects=4, aids=aids) as sim:
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
        # with the feedback_advice aid the others are pointed at table_0, never at the tray or at what lies in it
        sim.learn("alice", [near])
        for target in ("tray", near):
            out = run("alice", Navigate(target=target))
            assert out.code == OutcomeCode.NOT_NAVIGABLE and ("Navigate to table_0 instead" in out.feedback) == bool(
                aids
            ), out.feedback
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
            assert instruction(s.outcome.feedback) is None, (
                ep.key,
                s.tick,
                s.robot,
                s.outcome.feedback,
            )  # the paper's fidelity: no advice at all


# --------------------------------------------------------------------------- real failures


def test_navigation_slips_and_placements_fail_in_real_episodes_and_the_team_recovers(
    paper_episodes: list[Episode],
) -> None:
    steps = [s for ep in paper_episodes for s in ep.steps]
    off = [s for s in steps if s.outcome.code == OutcomeCode.OFF_TARGET]
    dropped = [s for s in steps if s.outcome.code == OutcomeCode.PLACE_FAILED and "came to rest" in s.outcome.feedback]
    assert off and dropped, [ep.key for ep in paper_episodes]
    assert all(ep.success for ep in paper_episodes), [ep.key for ep in paper_episodes if not ep.success]
    for s in off:  # stopped where it stopped, on free floor, the distance in the sentence
        assert s.base is not None and s.free
        assert (s.base[0], s.base[1]) == pytest.approx((s.outcome.details["x"], s.outcome.details["y"]), abs=1e-3)
        assert (
            float(s.outcome.details["distance"]) > 0.1
            and f"{float(s.outcome.details['distance']):.2f} m" in s.outcome.feedback
        )
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

    def stops(
        aids: tuple[str, ...],
    ) -> list[tuple[OutcomeCode, tuple[float, float, float] | None, tuple[float, float, float]]]:
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


# --------------------------------------------------------------------------- causes, not advice

# an instruction: a sentence (or a clause after ':' or ';') that starts with a verb a robot could
# be told to do ("Move failed" and "Move ended off target" are nouns, the skill that failed), or
# the words of advice
INSTRUCTION = re.compile(
    r"(?:^|[.;:!?]\s+)(?:please\s+)?(?:navigate|open|place|put|move|pick|try|go|use|ask|tell|communicate|wait|take|bring|find|explore|check)\b"
    r"(?!\s+(?:failed|ended)\b)",
    re.IGNORECASE,
)
ADVICE_WORDS = re.compile(
    r"\b(?:first|instead(?! of)|again|before|should|must|please|make sure|need to)\b", re.IGNORECASE
)


def instruction(text: str) -> str | None:
    """The first instruction or word of advice in `text`, or None."""
    m = INSTRUCTION.search(text) or ADVICE_WORDS.search(text)
    return m.group(0) if m else None


def test_the_instruction_check_catches_the_old_advice() -> None:
    """The check itself can fail: every sentence of advice the feedback used to give is caught."""
    old = [
        "tray has no stand pose: it is not something you can navigate to. Navigate to table_0 instead.",
        "You reached stand pose 0 of drawer_unit. drawer_unit is closed: open it to see what is inside.",
        "Navigation ended off target: your base stopped 0.21 m from stand pose 0 of sofa, at x=1.00, y=2.00. Navigate to stand pose 0 of sofa again.",
        "Your gripper holds apple; place it before opening drawer_unit.",
        "The handle of drawer_unit is out of your arm's reach: it is 1.20 m from your arm base. Navigate to a stand pose of drawer_unit first.",
        "Your gripper already holds apple; place it first.",
        "soap is inside drawer_unit, which is closed: open it first.",
        "No free spot on table_1 is within your arm's reach (the nearest is 1.50 m from your arm base). Navigate to a stand pose of table_1 first.",
        "Only Bob places objects on tray: place apple on table_0 within Bob's reach for Bob to finish the task.",
    ]
    assert all(instruction(t) for t in old), [t for t in old if not instruction(t)]
    assert instruction("Move failed: 3.00 m is more than the 1.0 m one move may cover.") is None
    assert (
        instruction("Move ended off target: your base moved by dx=0.10 m, dy=0.00 m instead of dx=0.30, dy=0.00.")
        is None
    )


# every function of world/feedback.py with sample arguments, and the advice each adds with the
# feedback_advice aid (None: it has no advice)
SAMPLES: dict[str, tuple[tuple[Any, ...], dict[str, Any], str | None]] = {
    "not_capable": (("bob", "navigate", ("pick", "place", "wait")), {}, None),
    "no_such_robot": (("carol", ("alice", "bob", "david")), {}, None),
    "waited": ((), {}, None),
    "broken_down": (("navigate", 2), {}, None),
    "unknown_furniture": (("garage", ["sofa", "table_0"]), {}, "; furniture: sofa, table_0."),
    "not_navigable": (("tray", "table_0"), {}, " Navigate to table_0 instead."),
    "stand_pose_invalid": (("table_0", 3, 7), {}, None),
    "start_invalid": ((), {}, None),
    "goal_invalid": (("table_1", 0), {}, None),
    "no_path": (("table_1", 2), {}, None),
    "occupied": (("sofa", 0, "david"), {}, " Try another stand pose of sofa, or wait until David leaves."),
    "reached": (("drawer_unit", 0, None), {"container": True}, "open it to see what is inside."),
    "off_target": (("sofa", 0, 0.21, (1.0, 2.0)), {}, " Navigate to stand pose 0 of sofa again."),
    "move_off_target": ((0.3, 0.0, 0.2, (0.1, 0.0)), {}, None),
    "move_too_long": ((3.0, 1.0), {}, None),
    "move_blocked": ((0.0, 0.5), {}, None),
    "moved": ((0.1, 0.0), {}, None),
    "not_openable": (("table_1",), {}, None),
    "already_open": (("drawer_unit",), {}, None),
    "hands_full_to_open": (("drawer_unit", "apple"), {}, " Place apple before opening drawer_unit."),
    "handle_out_of_reach": (("drawer_unit", 1.2), {}, " Navigate to a stand pose of drawer_unit first."),
    "no_grip": (("toy_chest", 0.5), {}, None),
    "pull_failed": (("toy_chest",), {}, None),
    "opened": (("drawer_unit", [("soap", (1.0, 2.0, 0.5))]), {}, None),
    "gripper_full": (("apple",), {}, "; place it first."),
    "object_unknown": (("applle", ["apple", "soap"]), {}, "; objects you know: apple, soap."),
    "held_by_other": (("apple", "bob"), {}, None),
    "in_closed_container": (("soap", "drawer_unit"), {}, ": open it first."),
    "too_far": (("apple", 0.31, (0.9, -0.2)), {}, None),
    "config_invalid": (("apple", "goal"), {}, None),
    "no_goal_configuration": (("apple", 0.004), {}, None),
    "plan_failed": (("apple",), {}, None),
    "picked": (("apple",), {}, None),
    "gripper_empty": (("apple",), {}, None),
    "wrong_object": (("apple", "soap"), {}, None),
    "location_unknown": (("attic", ["table_0", "table_1"]), {}, "; places: table_0, table_1."),
    "not_a_surface": (("drawer_unit", ["table_0", "table_1"]), {}, " Places: table_0, table_1."),
    "no_free_spot": (("tray",), {}, None),
    "place_out_of_reach": (("table_1", 1.5), {}, " Navigate to a stand pose of table_1 first."),
    "not_a_finisher": (
        ("apple", "tray", "table_0", "bob"),
        {},
        ": place apple on table_0 within Bob's reach for Bob to finish the task.",
    ),
    "place_failed": (("apple", "tray", "table_0", (1.0, 2.0, 0.8)), {}, None),
    "placed": (("apple", "tray"), {}, None),
}


def test_every_feedback_sentence_states_a_cause_and_gives_advice_only_with_the_aid() -> None:
    functions: dict[str, Callable[..., str]] = {
        n: f
        for n, f in inspect.getmembers(fb, inspect.isfunction)
        if not n.startswith("_") and f.__module__ == fb.__name__
    }
    assert set(functions) == set(SAMPLES), "give every feedback function a sample: " + ", ".join(
        set(functions) ^ set(SAMPLES)
    )
    for name, (args, kwargs, advice) in SAMPLES.items():
        f = functions[name]
        text = f(*args, **kwargs)
        assert instruction(text) is None, (name, text)
        takes_advice = "advice" in inspect.signature(f).parameters
        assert takes_advice == (advice is not None), name
        if advice is None:
            continue
        helped = f(*args, **kwargs, advice=True)
        assert advice in helped and advice not in text, (name, helped)
    # a fixed arm is never told to navigate, even with the aid; it is told why instead
    fixed = fb.place_out_of_reach("table_1", 1.5, mobile=False, advice=True)
    assert "Navigate" not in fixed and fixed == fb.place_out_of_reach("table_1", 1.5, mobile=False)
    assert "Navigate" not in fb.handle_out_of_reach("drawer_unit", 1.2, mobile=False, advice=True)
    # a robot that cannot open is never told to open, even with the aid
    assert "open it" not in fb.reached("drawer_unit", 0, None, container=True, can_open=False, advice=True)
    assert "open it" not in fb.in_closed_container("soap", "drawer_unit", can_open=False, advice=True)


@dataclass
class Case:
    label: str
    robot: str
    outcome: SkillOutcome
    advice: str | None  # what the feedback_advice aid adds, None: nothing


def table3_cases(aids: tuple[str, ...]) -> tuple[list[Case], set[str], set[str]]:
    """Every Table III case the skills can reach in one kitchen episode (exact motion, so the two
    runs with and without the aid take the same course), in order; the fixtures and the furniture
    with stand poses."""
    cases: list[Case] = []
    # one_per_stand_pose: the rule of teams other than the paper's, on here so that its sentence is sampled too
    with Sim(seed=1, n_objects=4, aids=("exact_motion", *aids), one_per_stand_pose=True) as sim:
        fixtures, stand = set(sim.fixtures), {f.name for f in sim.layout.furniture if f.stand_poses}

        def case(label: str, robot: str, action: Action, code: OutcomeCode, advice: str | None = None) -> SkillOutcome:
            out = sim.execute(robot, action)
            assert out.code == code, (label, out)
            cases.append(Case(label, robot, out, advice))
            return out

        near, far = _near_target(sim), _far_target(sim)
        # an object in a closed drawer (one is put there if the episode hid none in one)
        container = next(f.name for f in sim.layout.furniture if f.drawer is not None)
        inside = [o for o in sim.objects.values() if o.inside and o.on == container]
        if not inside:
            spec = sim.layout.get(container)
            assert spec is not None and spec.drawer is not None
            obj = next(o for o in sim.objects.values() if not o.inside and o.name not in (near, far))
            obj.on, obj.inside, obj.local = container, True, spec.drawer.slots[0]
            sim.world.follow_container(obj)
            inside = [obj]
        hidden = inside[0].name
        # any skill
        case("not capable", "bob", Navigate(target="table_0"), OutcomeCode.NOT_CAPABLE)
        case("no such robot", "carol", Wait(), OutcomeCode.NOT_CAPABLE)
        # navigate (and move: the same causes)
        case(
            "navigate: not in the scene graph",
            "alice",
            Navigate(target="garage"),
            OutcomeCode.TARGET_UNKNOWN,
            "; furniture: ",
        )
        case(
            "navigate: a fixture",
            "alice",
            Navigate(target="tray"),
            OutcomeCode.NOT_NAVIGABLE,
            "Navigate to table_0 instead.",
        )
        sim.learn("alice", [near])
        case(
            "navigate: an object",
            "alice",
            Navigate(target=near),
            OutcomeCode.NOT_NAVIGABLE,
            "Navigate to table_0 instead.",
        )
        case(
            "navigate: no such stand pose",
            "alice",
            Navigate(target="table_0", stand_pose=7),
            OutcomeCode.STAND_POSE_INVALID,
        )
        sofa, david = sim.layout.get("sofa"), sim.bots["david"].base
        assert sofa is not None and david is not None
        sim.bots["david"].set_base(sofa.stand_poses[0])  # one robot per stand pose
        case(
            "navigate: stand pose occupied",
            "alice",
            Navigate(target="sofa", stand_pose=0),
            OutcomeCode.OCCUPIED,
            "Try another stand pose of sofa",
        )
        sim.bots["david"].set_base(david)
        case("move: too long", "alice", Move(dx=3.0, dy=0.0), OutcomeCode.GOAL_INVALID)
        base = sim.bots["alice"].base
        assert base is not None
        table_1 = sim.layout.get("table_1")
        assert table_1 is not None
        sim.bots["alice"].set_base((table_1.center[0], table_1.center[1], 0.0))  # dropped onto a table
        case("navigate: start on an obstacle", "alice", Navigate(target="sofa"), OutcomeCode.START_INVALID)
        case("move: start on an obstacle", "alice", Move(dx=0.1, dy=0.0), OutcomeCode.START_INVALID)
        sim.bots["alice"].set_base(base)
        # open
        case(
            "open: not in the scene graph",
            "alice",
            Open(target="wardrobe"),
            OutcomeCode.TARGET_UNKNOWN,
            "; furniture: ",
        )
        case("open: not openable", "alice", Open(target="table_1"), OutcomeCode.NOT_OPENABLE)
        case(
            "open: out of reach",
            "alice",
            Open(target=container),
            OutcomeCode.OUT_OF_REACH,
            f"Navigate to a stand pose of {container} first.",
        )
        sim.learn("alice", [hidden])
        case(
            "pick: in a closed container",
            "alice",
            Pick(obj=hidden),
            OutcomeCode.NOT_REACHABLE_CONTAINER,
            ": open it first.",
        )
        case(
            "navigate: reached a closed container",
            "alice",
            Navigate(target=container),
            OutcomeCode.OK,
            "open it to see what is inside.",
        )
        assert sim.execute("alice", Open(target=container)).succeeded
        case("open: already open", "alice", Open(target=container), OutcomeCode.ALREADY_OPEN)
        assert sim.execute("alice", Pick(obj=hidden)).succeeded
        case("pick: gripper full", "alice", Pick(obj=near), OutcomeCode.GRIPPER_FULL, "; place it first.")
        shut = next(f.name for f in sim.layout.furniture if f.container is not None and not sim.is_open(f.name))
        case(
            "open: gripper full",
            "alice",
            Open(target=shut),
            OutcomeCode.GRIPPER_FULL,
            f"Place {hidden} before opening {shut}.",
        )
        # place
        case("place: not the object held", "alice", Place(obj=near, location="table_0"), OutcomeCode.WRONG_OBJECT)
        case(
            "place: no such place",
            "alice",
            Place(obj=hidden, location="attic"),
            OutcomeCode.LOCATION_UNKNOWN,
            "; places: ",
        )
        out = case(
            "place: not a surface",
            "alice",
            Place(obj=hidden, location=container),
            OutcomeCode.LOCATION_UNKNOWN,
            " Places: ",
        )
        assert "no place pose" in out.feedback, out.feedback
        case(
            "place: only Bob finishes",
            "alice",
            Place(obj=hidden, location="tray"),
            OutcomeCode.NOT_CAPABLE,
            f"place {hidden} on table_0 within Bob's reach",
        )
        case(
            "place: out of a mobile arm's reach",
            "alice",
            Place(obj=hidden, location="table_1"),
            OutcomeCode.TOO_FAR,
            "Navigate to a stand pose of table_1 first.",
        )
        # pick
        case(
            "pick: not in the scene graph",
            "bob",
            Pick(obj="applle"),
            OutcomeCode.OBJECT_UNKNOWN,
            "; objects you know: ",
        )
        sim.learn("bob", [hidden])
        case("pick: held by another robot", "bob", Pick(obj=hidden), OutcomeCode.OBJECT_UNKNOWN)
        case("pick: too far for a fixed arm", "bob", Pick(obj=far), OutcomeCode.TOO_FAR)
        q = sim.bots["bob"].q.copy()
        sim.bots["bob"].set_arm(np.array([0.0, 1.2, 0.0, -1.0, 0.0, 2.0, 0.785]))  # the hand pushed into the table top
        case("pick: start configuration invalid", "bob", Pick(obj=near), OutcomeCode.CONFIG_INVALID)
        sim.bots["bob"].set_arm(q)
        case("place: gripper empty", "bob", Place(obj=near, location="tray"), OutcomeCode.GRIPPER_EMPTY)
        assert sim.execute("bob", Pick(obj=near)).succeeded
        case("place: out of a fixed arm's reach", "bob", Place(obj=near, location="table_1"), OutcomeCode.TOO_FAR)
    # navigation off target: the first noise draw a slip (the seeded noise of a real episode, chosen)
    with Sim(seed=1, n_objects=4, aids=aids) as sim:
        slips = [
            k
            for k in range(2000)
            if (d := np.random.default_rng(k).random(3))[0] < navigation.NAV_SLIP_P and d[1] > 0.5
        ]
        for k in slips:
            sim.rng = np.random.default_rng(k)
            out = sim.execute("david", Navigate(target="sofa"))
            if out.code == OutcomeCode.OFF_TARGET:
                cases.append(Case("navigate: off target", "david", out, "Navigate to stand pose 0 of sofa again."))
                break
        else:
            raise AssertionError("no seeded slip took David off target")
    return cases, fixtures, stand


# the details each failure reports as numbers in its sentence too
MEASURED = {
    OutcomeCode.TOO_FAR: ("distance", "offset_x", "offset_y"),
    OutcomeCode.OFF_TARGET: ("distance",),
    OutcomeCode.OUT_OF_REACH: ("horizontal_distance",),
}


def test_table3_failures_state_cause_and_numbers_and_advice_only_with_the_aid() -> None:
    (paper, fixtures, stand), (aided, _, _) = table3_cases(()), table3_cases(("feedback_advice",))
    assert [c.label for c in paper] == [c.label for c in aided]
    for c, a in zip(paper, aided):
        text = c.outcome.feedback
        assert instruction(text) is None, (c.label, text)
        assert c.outcome.code == a.outcome.code, c.label
        if c.advice is None:
            assert a.outcome.feedback == text, (c.label, a.outcome.feedback)  # the aid adds nothing here
        else:
            assert c.advice not in text and c.advice in a.outcome.feedback, (c.label, text, a.outcome.feedback)
        for key in MEASURED.get(
            c.outcome.code, ()
        ):  # the measured numbers are in the sentence as they are in the details
            if key in c.outcome.details:
                assert f"{abs(float(c.outcome.details[key])):.2f}" in text, (c.label, key, text)
    for c in paper + aided:
        _no_bad_advice(c.robot, c.outcome.feedback, fixtures, stand)
    by_label = {c.label: c.outcome.feedback for c in paper}
    assert "not in your scene graph" not in by_label["pick: not in the scene graph"]  # the sentence, below, is exact
    assert by_label["pick: not in the scene graph"] == "There is no 'applle' in your scene graph."
    assert by_label["navigate: not in the scene graph"] == "There is no 'garage' in your scene graph."
    assert "cannot be seen until it is opened" in by_label["navigate: reached a closed container"]


# --------------------------------------------------------------------------- Bob never told "0.00 m away"


@pytest.mark.parametrize("scene", ["kitchen", "bathroom"])
def test_bob_is_never_too_far_from_what_lies_within_his_reach(scene: str) -> None:
    """Bob was told "cannot reach bacon: it is 0.00 m away" for bacon 0.37 m from his arm base,
    well within his 0.62 m reach: the randomised IK had missed the low point by a few millimetres
    and the miss was reported as the distance. Over a sweep of Bob's band of table_0, no pick is
    too far, and a too-far pick never says 0.00 m."""
    with Sim(task="make_sandwich", scene=scene, seed=0, n_objects=6, aids=("exact_motion",)) as sim:
        bob = sim.bots["bob"]
        ab = bob.arm_base()
        table = sim.layout.get("table_0")
        assert ab is not None and table is not None
        obj = next(o for o in sim.objects.values() if o.name in sim.targets and not o.inside)
        top = sim.table_top()
        tried, too_far = 0, []
        for d in np.arange(0.30, 0.60, 0.04):
            for ang in np.linspace(-math.pi, math.pi, 16, endpoint=False):
                x, y = ab[0] + d * math.cos(ang), ab[1] + d * math.sin(ang)
                if not table.contains_xy(x, y) or sim.fixture_at(x, y) is not None or not sim.within_handover((x, y)):
                    continue
                sim.world.rest(obj, x, y, top)
                obj.on, obj.held_by = "table_0", None
                sim.learn("bob", [obj.name])
                out = sim.execute("bob", Pick(obj=obj.name))
                tried += 1
                if out.succeeded:
                    sim.release(bob, obj, (x, y, top), 0.0, "table_0")
                elif out.code == OutcomeCode.TOO_FAR:
                    too_far.append((round(d, 2), round(float(ang), 2), out.feedback))
                assert "0.00 m away" not in out.feedback, out.feedback
        assert tried > 20 and not too_far, too_far
