"""Each robot's scene graph is its own memory: objects and containers as the robot last saw them
or was told, never the live truth (unless the live_state aid is on). Real PyBullet worlds, and
the belief store on its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mhrc.agents.observation import furniture_line, object_line
from mhrc.core.protocol import Move, Navigate, ObjectView, Observation, Open, OutcomeCode, Pick, Place, SkillOutcome
from mhrc.world.beliefs import Beliefs
from mhrc.world.sim import Sim

EXACT = ("exact_motion",)  # bases stop on their poses, placed objects stay put: the story stays the story


def _ok(out: SkillOutcome) -> SkillOutcome:
    assert out.succeeded, out.feedback
    return out


def _obj(obs: Observation, name: str) -> ObjectView | None:
    return next((o for o in obs.objects if o.name == name), None)


def _is_open(obs: Observation, furniture: str) -> bool | None:
    return next(f.is_open for f in obs.furniture if f.name == furniture)


def _pose_near(sim: Sim, furniture: str, name: str) -> int:
    f = sim.layout.get(furniture)
    assert f is not None
    x, y, _ = sim.position(sim.objects[name])
    return min(range(len(f.stand_poses)), key=lambda i: math.hypot(f.stand_poses[i][0] - x, f.stand_poses[i][1] - y))


def _pick(sim: Sim, robot: str, name: str) -> None:
    out = sim.execute(robot, Pick(obj=name))
    if out.code == OutcomeCode.TOO_FAR and "dx" in out.details:
        _ok(sim.execute(robot, Move(dx=float(out.details["dx"]), dy=float(out.details["dy"]))))
        out = sim.execute(robot, Pick(obj=name))
    _ok(out)


def _far_on_table_0(sim: Sim) -> str:
    bob = sim.observe("bob", 0)
    ab, reach = bob.status.arm_base, bob.status.reach
    assert ab is not None and reach is not None
    return next(
        o.name
        for o in bob.objects
        if o.on == "table_0" and math.hypot(o.position[0] - ab[0], o.position[1] - ab[1]) > reach
    )


@dataclass(frozen=True)
class Cast:
    """Who and what a scenario uses, read off the generated episode: `item` lies on the surface
    `shelf`, `hidden` in the closed container `box`, `other` is a surface elsewhere."""

    item: str
    shelf: str
    hidden: str
    box: str
    other: str


def _cast(sim: Sim) -> Cast:
    lay = sim.layout
    item = next(
        o
        for o in sim.objects.values()
        if o.on not in (lay.bob_table, None) and not o.inside and lay.get(o.on).stand_poses
    )  # type: ignore[union-attr]
    hidden = next(o for o in sim.objects.values() if o.inside)
    assert item.on is not None and hidden.on is not None
    other = next(
        f.name
        for f in lay.furniture
        if f.container is None
        and f.stand_poses
        and f.name not in (lay.bob_table, item.on)
        and not sim.objects_on(f.name)
    )
    return Cast(item.name, item.on, hidden.name, hidden.on, other)


def _carry_to_table_0_unseen_by_david(sim: Sim, c: Cast) -> ObjectView:
    """David sees the item on its shelf and tells Alice; she takes it to table_0 while he looks
    elsewhere. Returns David's view of the item from when he saw it."""
    _ok(sim.execute("david", Navigate(target=c.shelf, stand_pose=_pose_near(sim, c.shelf, c.item))))
    seen = _obj(sim.observe("david", 1), c.item)
    assert seen is not None and seen.on == c.shelf and seen.told_by is None and seen.last_seen_on is None
    sim.tell("alice", "david", f"On {c.shelf} I found: {c.item}.")
    told = _obj(sim.observe("alice", 1), c.item)
    assert told == (
        seen if "live_state" in sim.aids else seen.model_copy(update={"told_by": "david"})
    )  # David's belief, who said so
    _ok(sim.execute("david", Navigate(target=c.other, stand_pose=0)))
    _ok(sim.execute("alice", Navigate(target=c.shelf, stand_pose=_pose_near(sim, c.shelf, c.item))))
    _pick(sim, "alice", c.item)
    _ok(sim.execute("alice", Navigate(target="table_0", stand_pose=0)))
    _ok(sim.execute("alice", Place(obj=c.item, location="table_0")))
    return seen


def test_a_robot_does_not_see_what_happens_where_it_is_not() -> None:
    with Sim(seed=1, n_objects=6, aids=EXACT) as sim:
        c = _cast(sim)
        seen = _carry_to_table_0_unseen_by_david(sim, c)
        assert sim.objects[c.item].on == "table_0"
        for tick in (2, 3):
            assert _obj(sim.observe("david", tick), c.item) == seen  # still where he saw it
        # asked to drive to the object, the world never gives away where it is now (with feedback_advice it
        # would point him where he believes it lies: tests/test_table3.py)
        out = sim.execute("david", Navigate(target=c.item, stand_pose=0))
        assert out.code == OutcomeCode.NOT_NAVIGABLE and "table_0" not in out.feedback
        for robot in ("alice", "bob"):  # Alice put it there; Bob sees his table
            view = _obj(sim.observe(robot, 2), c.item)
            assert view is not None and view.on == "table_0" and view.last_seen_on is None
        # back at the shelf, David sees it is gone, and says so in his prompt
        _ok(sim.execute("david", Navigate(target=c.shelf, stand_pose=0)))
        david = sim.observe("david", 4)
        gone = _obj(david, c.item)
        assert gone == seen.model_copy(update={"on": None, "last_seen_on": c.shelf})
        x, y, z = seen.position
        where = f"where it was last seen at ({x:.2f}, {y:.2f}, {z:.2f}); where it is now is unknown"
        assert (
            object_line(gone, david) == f"- {c.item}: position unknown"
        )  # the paper's field: where it is he does not know
        assert (
            object_line(gone, david, hints=True) == f"- {c.item}: no longer on {c.shelf}, {where}"
        )  # the prompt_hints aid says more
        # Alice tells him where it went: her newer belief replaces his
        sim.tell("david", "alice", f"I put the {c.item} on table_0.")
        view = _obj(sim.observe("david", 5), c.item)
        assert view is not None and view.on == "table_0" and view.told_by == "alice" and view.last_seen_on is None
        assert f"{c.item}: on table_0 (Alice told you), at " in object_line(view, david, hints=True)
        assert view.yaw is not None and object_line(view, david) == (
            f"- {c.item}: position ({view.position[0]:.2f}, {view.position[1]:.2f}, {view.position[2]:.2f}), yaw {round(math.degrees(view.yaw)) or 0} deg"
        )  # the appendix's fields: where it was and its orientation, as Alice saw them


def test_the_live_state_aid_shows_the_truth() -> None:
    with Sim(seed=1, n_objects=6, aids=(*EXACT, "live_state")) as sim:
        c = _cast(sim)
        _carry_to_table_0_unseen_by_david(sim, c)
        view = _obj(sim.observe("david", 2), c.item)
        x, y, z = sim.position(sim.objects[c.item])
        assert view is not None and view.on == "table_0" and view.position == (round(x, 3), round(y, 3), round(z, 3))
        _ok(sim.execute("alice", Navigate(target=c.box, stand_pose=0)))
        _ok(sim.execute("alice", Open(target=c.box)))
        assert _is_open(sim.observe("david", 3), c.box) is True
        assert _obj(sim.observe("david", 3), c.hidden) is None  # live, but still only what he knows of


def test_a_container_is_open_only_for_those_who_saw_it_open() -> None:
    with Sim(seed=1, n_objects=6, aids=EXACT) as sim:
        c = _cast(sim)
        for robot in ("alice", "bob", "david"):
            assert _is_open(sim.observe(robot, 0), c.box) is False
        _ok(sim.execute("alice", Navigate(target=c.box, stand_pose=0)))
        _ok(sim.execute("alice", Open(target=c.box)))
        alice = sim.observe("alice", 1)
        assert _is_open(alice, c.box) is True and (hidden := _obj(alice, c.hidden)) is not None and hidden.inside
        david = sim.observe("david", 1)
        assert _is_open(david, c.box) is False and _obj(david, c.hidden) is None
        box = next(f for f in david.furniture if f.name == c.box)
        assert "; closed;" in furniture_line(box) and "closed (open it to see inside)" in furniture_line(
            box, hints=True
        )
        _ok(sim.execute("david", Navigate(target=c.other, stand_pose=0)))
        assert _is_open(sim.observe("david", 2), c.box) is False  # elsewhere: still as he last knew it
        _ok(sim.execute("alice", Navigate(target="table_0", stand_pose=0)))  # one robot per stand pose: she leaves
        _ok(sim.execute("david", Navigate(target=c.box, stand_pose=0)))
        david = sim.observe("david", 3)
        assert _is_open(david, c.box) is True and _obj(david, c.hidden) == hidden  # he sees it open, and what is in it
        # a message names the hidden object: Bob gets Alice's belief of it, told by her
        sim.tell("bob", "alice", f"The {c.hidden} is in the {c.box}.")
        assert _obj(sim.observe("bob", 3), c.hidden) == hidden.model_copy(update={"told_by": "alice"})
        assert _is_open(sim.observe("bob", 3), c.box) is False  # a message carries objects, not furniture


def test_a_message_carries_the_senders_belief_and_newer_news_wins() -> None:
    with Sim(seed=1, n_objects=6, aids=EXACT) as sim:
        c = _cast(sim)
        _ok(sim.execute("david", Navigate(target=c.shelf, stand_pose=_pose_near(sim, c.shelf, c.item))))
        seen = _obj(sim.observe("david", 1), c.item)
        _ok(sim.execute("david", Navigate(target=c.other, stand_pose=0)))
        sim.learn("alice", [c.item])
        _ok(sim.execute("alice", Navigate(target=c.shelf, stand_pose=_pose_near(sim, c.shelf, c.item))))
        _pick(sim, "alice", c.item)
        sim.tell("bob", "david", f"{c.item} is on {c.shelf}, {c.hidden} maybe, and a unicorn somewhere")
        bob = sim.observe("bob", 2)
        assert seen is not None and _obj(bob, c.item) == seen.model_copy(
            update={"told_by": "david"}
        )  # not the truth: Alice holds it
        assert _obj(bob, c.hidden) is None  # nobody has seen it
        assert {o.name for o in bob.objects} == {c.item} | set(sim.objects_on("table_0"))
        sim.tell("bob", "alice", f"I have the {c.item}.")
        held = _obj(sim.observe("bob", 3), c.item)
        assert held is not None and held.held_by == "alice" and held.on is None and held.told_by == "alice"
        sim.tell("bob", "david", f"Remember the {c.item} on {c.shelf}?")  # older news does not overwrite newer
        assert _obj(sim.observe("bob", 4), c.item) == held


def test_bob_sees_his_table_and_a_robot_sees_where_it_stands() -> None:
    with Sim(seed=1, n_objects=6, aids=EXACT) as sim:
        c = _cast(sim)
        far = _far_on_table_0(sim)
        before = _obj(sim.observe("bob", 0), far)
        assert before is not None and before.on == "table_0"
        sim.tell("alice", "bob", f"Please bring the {far} within my reach.")
        _ok(sim.execute("alice", Navigate(target="table_0", stand_pose=_pose_near(sim, "table_0", far))))
        _pick(sim, "alice", far)
        gone = _obj(sim.observe("bob", 1), far)  # it left his table: he saw that, not who took it
        assert (
            gone is not None and gone.on is None and gone.last_seen_on == "table_0" and gone.position == before.position
        )
        held = _obj(sim.observe("alice", 1), far)
        assert held is not None and held.held_by == "alice"  # a robot knows what it holds
        _ok(sim.execute("alice", Navigate(target="table_0", stand_pose=0)))
        _ok(sim.execute("alice", Place(obj=far, location="table_0")))
        back = _obj(sim.observe("bob", 2), far)
        assert (
            back is not None and back.on == "table_0" and back.last_seen_on is None and back.position != before.position
        )
        assert _obj(sim.observe("alice", 2), far) == back  # Alice sees her own place
        # Bob packs it while Alice still stands at table_0: she sees it land on its goal
        goal = sim.goals[far]
        _ok(sim.execute("bob", Pick(obj=far)))
        _ok(sim.execute("bob", Place(obj=far, location=goal)))
        assert (bob := _obj(sim.observe("bob", 3), far)) is not None and bob.on == goal
        assert _obj(sim.observe("alice", 3), far) == bob
        _ok(sim.execute("alice", Navigate(target=c.other, stand_pose=0)))  # elsewhere: no longer watching table_0
        _ok(sim.execute("bob", Pick(obj=far)))
        assert _obj(sim.observe("alice", 4), far) == bob


def test_same_actions_same_observations() -> None:
    def run() -> list[Observation]:
        with Sim(seed=1, n_objects=6, aids=EXACT) as sim:
            c = _cast(sim)
            _carry_to_table_0_unseen_by_david(sim, c)
            _ok(sim.execute("david", Navigate(target=c.shelf, stand_pose=0)))
            return [sim.observe(r, 9) for r in sim.robots]

    assert run() == run()


def test_the_belief_store_on_its_own() -> None:
    def view(name: str, on: str | None, x: float = 0.0, **kw: object) -> ObjectView:
        return ObjectView(name=name, position=(x, 0.0, 0.5), on=on, **kw)  # type: ignore[arg-type]

    a, b = Beliefs(), Beliefs()
    a.see("shelf", {"shelf"}, None, [view("cup", "shelf"), view("pen", "shelf")], stamp=1)
    b.see("box", {"box"}, False, [view("key", "box", inside=True)], stamp=2)  # closed: nothing seen inside
    assert not b.objects and b.opened == {"box": False}
    b.see("box", {"box"}, True, [view("key", "box", inside=True)], stamp=3)
    assert b.is_open("box") and b.objects["key"].view.inside
    a.see("shelf", {"shelf"}, None, [view("pen", "shelf", x=1.0)], stamp=4)
    assert a.objects["cup"].view == view("cup", None, last_seen_on="shelf") and a.objects["pen"].view.position[0] == 1.0
    b.see(
        "desk", {"desk"}, None, [view("cup", "desk", x=2.0)], stamp=3
    )  # seen on the desk before Alice missed it on the shelf
    assert b.told("a", a, ["cup", "pen", "ghost"]) == ["pen"]  # "gone from the shelf" does not beat "on the desk"
    assert b.objects["pen"].view.told_by == "a" and "ghost" not in b.objects
    assert a.told("b", b, ["pen", "key"]) == ["key"] and a.objects["pen"].view.told_by is None
