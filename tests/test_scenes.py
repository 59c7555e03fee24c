"""The built-in scenes as houses: what each holds, how its containers open, how Bob's table
differs between them, and the layout checks that keep a scene solvable (Bob's reach, stand
poses clear of open drawers, every piece of furniture navigable). The data tests need no
physics; the last two build each scene and run the real skills."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from mhrc.agents.llm_policy import load_template
from mhrc.core.protocol import Navigate, Open, OutcomeCode, Pick
from mhrc.world import assets
from mhrc.world.arm import HOME
from mhrc.world.kinds import KINDS, TEAM
from mhrc.world.layouts import ARM_REACH, FAR_SLOT, SCENES_DIR, LayoutError, load_layout, parse_layout
from mhrc.world.occupancy import occupancy
from mhrc.world.scene import LAYOUTS
from mhrc.world.sim import Sim
from mhrc.world.tasks import TASKS

# the example house of the paper's appendix
APPENDIX = {
    "drawer_unit",
    "dishwasher",
    "microwave",
    "fridge",
    "table_0",
    "table_1",
    "table_2",
    "table_3",
    "table_4",
    "cabinet_0",
    "cabinet_1",
    "sofa",
    "bookcase",
    "tub",
    "washbasin",
}


def test_the_kitchen_is_the_appendix_house() -> None:
    kitchen = LAYOUTS["kitchen"]
    assert APPENDIX <= {f.name for f in kitchen.furniture}
    # the fridge and the dishwasher open by their pull-out drawers, as the drawer unit does
    assert {f.name for f in kitchen.furniture if f.drawer is not None} == {"fridge", "dishwasher", "drawer_unit"}
    fridge = kitchen.get("fridge")
    assert fridge is not None and fridge.top >= 1.6 and fridge.panels, (
        "a tall fridge with a door drawn above its freezer drawer"
    )
    # the microwave and the cabinets open by a side-hinged door, as the appendix opens them
    for name in ("microwave", "cabinet_0", "cabinet_1"):
        f = kitchen.get(name)
        assert f is not None and f.door is not None and f.container is f.door and f.panels, name
        assert f.place_pose is None and not f.slots, f"what lies in {name} is inside, behind its door"
    assert "not modelled" not in kitchen.description


def test_every_scene_has_more_tables_than_before() -> None:
    tables = {name: {f.name for f in lay.furniture if f.name.startswith("table_")} for name, lay in LAYOUTS.items()}
    assert tables["kitchen"] == {f"table_{i}" for i in range(5)}
    assert all(len(t) >= 4 for t in tables.values()), tables


def _bob_frame(scene: str, xy: tuple[float, float]) -> tuple[float, float]:
    """`xy` in Bob's frame: ahead of his arm base, and to his left."""
    lay = LAYOUTS[scene]
    bx, by, _ = lay.bob_base
    c, s = math.cos(lay.bob_yaw), math.sin(lay.bob_yaw)
    dx, dy = xy[0] - bx, xy[1] - by
    return round(c * dx + s * dy, 3), round(-s * dx + c * dy, 3)


def test_table_0_and_its_goal_area_differ_between_scenes() -> None:
    shapes = {}
    for name, lay in LAYOUTS.items():
        table = lay.get(lay.bob_table)
        assert table is not None
        gx, gy, sx, sy = lay.goal_area
        shapes[name] = (table.size, (sx, sy), _bob_frame(name, (gx, gy)), round(lay.bob_yaw, 3))
    assert len({s[0] for s in shapes.values()}) == len(shapes), "table_0 has a different size in every scene"
    assert len({s[1] for s in shapes.values()}) == len(shapes), "so has the goal area"
    assert len({s[2] for s in shapes.values()}) == len(shapes), "and it lies elsewhere relative to Bob"


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_bobs_slots_and_goal_fixtures_respect_his_reach(scene: str) -> None:
    assert ARM_REACH == KINDS[TEAM["bob"]].reach
    lay = LAYOUTS[scene]
    bx, by, _ = lay.bob_base
    for x, y in lay.near_slots:
        assert 0.3 <= math.hypot(x - bx, y - by) <= ARM_REACH
    for x, y in lay.far_slots:
        assert math.hypot(x - bx, y - by) > FAR_SLOT
    for task in TASKS.values():
        for fx in task.fixtures(lay):
            assert 0.3 <= math.hypot(fx.center[0] - bx, fx.center[1] - by) <= ARM_REACH, (task.id, fx.name)


@pytest.mark.parametrize("path", sorted(SCENES_DIR.glob("*.json")), ids=lambda p: p.stem)
def test_what_lies_out_of_bobs_reach_lies_beyond_the_pick_distance_his_prompt_gives(path: Path) -> None:
    """Bob's prompt (as the paper's appendix) says he picks best within 1 m of him, and where he
    is, in his prompt, is his arm base (the layout's bob.base; a physics test below checks that
    the world tells him so): every far slot of every shipped layout file lies beyond 1 m of it."""
    assert "no more than 1 m away from you" in load_template("bob", "system").template, (
        "the prompt's figure changed: so must FAR_SLOT"
    )
    assert FAR_SLOT == 1.0
    data = json.loads(path.read_text())
    bx, by, _ = data["bob"]["base"]
    for i, (x, y) in enumerate(data["bob"]["far_slots"]):
        assert math.hypot(x - bx, y - by) > FAR_SLOT, f"{path.name}: bob.far_slots.{i}"
    load_layout(path)  # and the file loads: the schema holds it to the same rule (next test)


@pytest.mark.parametrize(
    ("far", "distance"),
    [([-2.75, 0.0], "1.000"), ([-2.8, 0.3], "0.996"), ([-3.0, -0.3], "0.808")],
)
def test_a_far_slot_within_1_m_of_bob_is_refused_naming_the_file_and_field(
    tmp_path: Path, far: list[float], distance: str
) -> None:
    data = copy.deepcopy(_kitchen())
    data["bob"]["far_slots"] = [data["bob"]["far_slots"][0], far]
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(data))
    with pytest.raises(LayoutError) as exc:
        load_layout(path)
    assert str(exc.value).startswith(
        f"{path}: bob.far_slots.1: {far} is {distance} m from Bob's arm base; far slots lie beyond 1.0 m from it"
    ), exc.value


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_handovers_land_where_bob_can_pick_and_several_fit(scene: str) -> None:
    """Alice hands over on table_0 within place_radius of its place pose, in Bob's reach and off
    the goal area. Bob's arm cannot pick a flat object much closer ahead of its base than 0.2 m
    (beside it), so the spots stay in front of that; and an ordered task's waiting pieces
    (up to four of a six-layer sandwich) all fit."""
    lay = LAYOUTS[scene]
    table = lay.get(lay.bob_table)
    assert table is not None and table.place_pose is not None
    bx, by, _ = lay.bob_base
    gx, gy, gsx, gsy = lay.goal_area
    (px, py), half = table.place_pose, 0.05  # a bread slice
    spots = []
    for x in np.arange(
        table.center[0] - table.size[0] / 2 + 0.07, table.center[0] + table.size[0] / 2 - 0.07 + 1e-9, 0.02
    ):
        for y in np.arange(
            table.center[1] - table.size[1] / 2 + 0.07, table.center[1] + table.size[1] / 2 - 0.07 + 1e-9, 0.02
        ):
            off_goal = abs(x - gx) >= gsx / 2 + half or abs(y - gy) >= gsy / 2 + half
            if (
                off_goal
                and math.hypot(x - px, y - py) <= table.place_radius
                and 0.3 <= math.hypot(x - bx, y - by) <= ARM_REACH - 0.03
            ):
                spots.append((float(x), float(y)))
    assert min(_bob_frame(scene, xy)[0] for xy in spots) >= 0.2 - 1e-6
    spots.sort(key=lambda xy: math.hypot(xy[0] - px, xy[1] - py))
    taken: list[tuple[float, float]] = []
    for xy in spots:
        if all(abs(xy[0] - q[0]) >= 2 * half + 0.02 or abs(xy[1] - q[1]) >= 2 * half + 0.02 for q in taken):
            taken.append(xy)
    assert len(taken) >= 4, taken


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_every_stand_pose_and_start_is_free_floor(scene: str) -> None:
    """With every drawer's open footprint blocked, as the base planners see the floor."""
    lay = LAYOUTS[scene]
    grid = occupancy(lay, margin=max(k.footprint for k in KINDS.values()))
    for f in lay.furniture:
        assert f.stand_poses, f.name
        for i, (x, y, _) in enumerate(f.stand_poses):
            assert grid.free(x, y), f"stand pose {i} of {f.name}"
        footprint = f.open_drawer_footprint()
        if footprint is not None:
            assert not grid.free(*footprint[0]), f"the open drawer of {f.name} is free floor"
    for robot, (x, y, _) in lay.starts.items():
        assert grid.free(x, y), robot


def test_a_facade_is_looks_only() -> None:
    panels = (
        assets.Panel(0.0, 0.4, 0.5, 0.7, (1.0, 1.0, 1.0, 1.0), "top"),
        assets.Panel(0.1, 0.4, 0.2, 0.2, (0.0, 0.0, 0.0, 1.0), "left"),
    )
    boxes = assets.facade_boxes(0.6, panels)
    assert len(boxes) == 4 and not any(b.collide for b in boxes)
    assert all(b.center[1] < -0.3 for b in boxes), "on the front (-y) face"
    urdf = assets.link_urdf("m", assets.block_boxes((0.6, 0.5, 1.2), (1.0, 1.0, 1.0, 1.0)) + boxes)
    assert urdf.count("<collision>") == 1 and urdf.count("<visual>") == 5


# --------------------------------------------------------------------------- the checks that keep a layout solvable


def _kitchen() -> dict[str, Any]:
    data: dict[str, Any] = json.loads((SCENES_DIR / "kitchen.json").read_text())
    return data


def _named(data: dict[str, Any], name: str) -> dict[str, Any]:
    return next(f for f in data["furniture"] if f["name"] == name)


def _move(furniture: dict[str, Any], dx: float, dy: float) -> None:
    """Shift a piece of furniture with what lies on it (its stand poses are relative to it)."""
    furniture["center"] = [furniture["center"][0] + dx, furniture["center"][1] + dy]
    furniture["place_pose"] = [furniture["place_pose"][0] + dx, furniture["place_pose"][1] + dy]
    furniture["slots"] = [[x + dx, y + dy] for x, y in furniture["slots"]]
    furniture["stand_poses"] = [
        {**sp, "at": sp["at"] + (dx if sp["side"] in ("north", "south") else dy)} for sp in furniture["stand_poses"]
    ]


def _index(name: str) -> int:
    return next(i for i, f in enumerate(_kitchen()["furniture"]) if f["name"] == name)


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda d: d["bob"].update(base=[-4.2, 0.0, 0.7]), "bob.base: [-4.2, 0.0, 0.7] is not on table_0"),
        (
            lambda d: d["bob"].update(near_slots=[[-3.0, 0.4]]),
            "bob.near_slots.0: [-3.0, 0.4] is 0.85 m from Bob's arm base; near slots lie 0.3 to 0.59 m from it",
        ),
        (
            lambda d: d["bob"].update(far_slots=[[-3.0, -0.3]]),
            "bob.far_slots.0: [-3.0, -0.3] is 0.808 m from Bob's arm base; far slots lie beyond 1.0 m from it",
        ),
        (
            lambda d: d["bob"].update(goal_area=[-3.3, 0.0, 0.3, 0.3]),
            "bob.goal_area: [-3.3, 0.0, 0.3, 0.3] is too small",
        ),
        (
            lambda d: d["bob"].update(goal_area=[-3.1, 0.0, 0.5, 0.4]),
            "bob.goal_area: [-3.1, 0.0, 0.5, 0.4]: its corner [-2.85, -0.2] is beyond 0.8 m",
        ),
        (
            lambda d: _named(d, "microwave").update(stand_poses=[]),
            f"furniture.{_index('microwave')}.stand_poses: microwave has none",
        ),
        (
            lambda d: _named(d, "dishwasher").update(stand_poses=[[-2.8, 2.85, 1.57]]),
            f"furniture.{_index('dishwasher')}.stand_poses.0 (dishwasher): (-2.8, 2.85) is within 0.3 m of "
            f"furniture.{_index('dishwasher')} (dishwasher) with its drawer open",
        ),
        (
            lambda d: _named(d, "dishwasher")["drawer"].update(inner=[0.6, 0.48, 0.15]),
            "drawer.inner: a drawer [0.6, 0.48] inside does not fit in dishwasher (0.6 wide, 0.6 deep)",
        ),
        (
            lambda d: _named(d, "dishwasher")["drawer"].update(max_object_height=0.2),
            "drawer.max_object_height: objects that tall do not fit in the drawer of dishwasher",
        ),
        (
            lambda d: _named(d, "table_1").update(
                facade={"front": [0, -1], "panels": [{"at": [0, 0.3], "size": [0.2, 0.2]}]}
            ),
            "facade: only a block, a drawer_unit, a chest or a cupboard has one, not a table",
        ),
        (
            lambda d: _named(d, "bookcase")["facade"].pop("front"),
            "facade.front: a block's facade needs the side it faces",
        ),
        (
            lambda d: _named(d, "fridge")["facade"].update(front=[1, 0]),
            "facade.front: a container's front is its axis [0.0, -1.0]; omit front",
        ),
        (
            lambda d: _named(d, "microwave")["facade"]["panels"][0].update(size=[0.7, 0.2]),
            "facade.panels.0: [0.0, 0.24] size [0.7, 0.2] does not fit on the front (0.6 wide, 1.2 high)",
        ),
        # side-hinged doors: a chassis at a stand pose is clear of the swing; the swing hits nothing
        (
            lambda d: _named(d, "cabinet_0").update(stand_poses=[[-3.775, 2.75, 1.570796]]),
            f"furniture.{_index('cabinet_0')}.stand_poses.0 (cabinet_0): a chassis at (-3.775, 2.75) "
            f"would be within 0.03 m of furniture.{_index('cabinet_0')} (cabinet_0) with its door swinging open",
        ),
        (
            lambda d: _named(d, "microwave").update(stand_poses=[[-1.3, 2.8, 0.0]]),
            f"furniture.{_index('microwave')}.stand_poses.0 (microwave): a chassis at (-1.3, 2.8) "
            f"would be within 0.03 m of furniture.{_index('microwave')} (microwave) with its door swinging open",
        ),
        (
            lambda d: _named(d, "cabinet_0").update(stand_poses=[[-3.775, 2.6, 1.570796]]),
            f"furniture.{_index('cabinet_0')}.stand_poses.0 (cabinet_0): an arm in its carry posture at (-3.775, 2.6) would be within 0.03 m of the "
            f"open door of furniture.{_index('cabinet_0')} (cabinet_0)",
        ),
        (
            lambda d: _named(d, "cabinet_0")["door"].update(at=-0.5),
            f"furniture.{_index('cabinet_0')} (cabinet_0) with its door swinging open overlaps furniture.{_index('fridge')} (fridge) by 0.10 m",
        ),
        (
            lambda d: _named(d, "cabinet_1")["door"].update(at=-0.5),
            f"furniture.{_index('cabinet_1')} (cabinet_1) with its door swinging open overlaps furniture.{_index('dishwasher')} (dishwasher) open",
        ),
        (
            lambda d: _named(d, "microwave")["door"].update(at=0.0),
            "door: a door from 0.0 to 0.35 across does not fit on the front of microwave (0.6 wide)",
        ),
        (
            lambda d: _named(d, "microwave")["door"].update(ceiling=1.19),
            "door.ceiling: 1.19 m leaves no top on microwave",
        ),
        (lambda d: _named(d, "microwave")["door"].update(open_deg=120), "open_deg"),
        (
            lambda d: d.update(
                furniture=[f for f in d["furniture"] if f.get("style") not in ("drawer_unit", "cupboard")]
                + [_named(d, "fridge")]
            ),
            "furniture: a layout needs at least 2 closed containers a target can hide in (drawer_unit, chest or cupboard); it has 1: fridge",
        ),
        (lambda d: _named(d, "microwave")["facade"]["panels"][0].update(color="gold"), "color: unknown colour 'gold'"),
        # a pillar through table_0: table_2 moved into it (furniture may touch, never intersect)
        (
            lambda d: _move(_named(d, "table_2"), 0.0, 3.0),
            f"furniture.{_index('table_0')} (table_0) overlaps furniture.{_index('table_2')} (table_2) by 0.55 m: move it or shrink it",
        ),
        (
            lambda d: _move(_named(d, "table_4"), 0.0, -0.3),
            f"furniture.{_index('table_4')} (table_4) overlaps walls.0 by 0.",
        ),
    ],
)
def test_a_layout_that_would_not_be_solvable_is_refused(edit: Any, expected: str) -> None:
    data = copy.deepcopy(_kitchen())
    edit(data)
    with pytest.raises(LayoutError) as exc:
        parse_layout(data, "mine.json")
    assert expected in str(exc.value)


# --------------------------------------------------------------------------- with physics


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_alice_opens_every_container_and_empties_every_slot(scene: str) -> None:
    """Each drawer and lid opens from its stand pose 0, and whatever lies in any of its slots
    can be picked from there."""
    with Sim(task="pack_objects", scene=scene, seed=0, n_objects=6) as sim:
        alice = sim.bots["alice"]
        for f in (f for f in sim.layout.furniture if f.container is not None):
            spec = f.container
            assert spec is not None
            short = sorted(
                (o for o in sim.objects.values() if o.kind.height <= spec.max_object_height),
                key=lambda o: o.kind.height,
            )
            assert len(short) >= len(spec.slots)
            placed = short[-len(spec.slots) :]  # the tallest that fit
            for obj, slot in zip(placed, spec.slots):
                obj.on, obj.inside, obj.local, obj.held_by = f.name, True, slot, None
                sim.world.follow_container(obj)
                sim.known["alice"].add(obj.name)
            assert sim.execute("alice", Navigate(target=f.name, stand_pose=0)).succeeded, f.name
            out = sim.execute("alice", Open(target=f.name))
            assert out.succeeded and all(o.name in out.feedback for o in placed), (f.name, out.feedback)
            assert sim.opening[f.name] == pytest.approx(spec.travel)
            for obj in placed:
                out = sim.execute("alice", Pick(obj=obj.name))
                assert out.succeeded, (f.name, obj.local, out.feedback)
                alice.release()  # drop it out of the way
                obj.held_by, obj.on = None, "nowhere"
                sim.world.rest(obj, 50.0, 50.0, 0.0)
                alice.set_arm(HOME)


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_bob_picks_from_his_near_slots_and_not_from_his_far_ones(scene: str) -> None:
    with Sim(task="sort_solids", scene=scene, seed=0, n_objects=3) as sim:
        bob, lay = sim.bots["bob"], sim.layout
        table = lay.get(lay.bob_table)
        assert table is not None
        arm_base = sim.observe("bob", 0).status.arm_base  # where Bob's prompt says he is ("your base is fixed at ...")
        assert arm_base is not None and arm_base[:2] == pytest.approx(lay.bob_base[:2])
        obj = next(o for o in sim.objects.values() if o.on == lay.bob_table)
        for slots, can in ((lay.near_slots, True), (lay.far_slots, False)):
            for x, y in slots:
                for other in sim.objects.values():  # nothing else in the way
                    if other is not obj and other.on == lay.bob_table:
                        other.on = "nowhere"
                        sim.world.rest(other, 50.0, 50.0, 0.0)
                obj.on, obj.inside = lay.bob_table, False
                sim.world.rest(obj, x, y, table.top)
                out = sim.execute("bob", Pick(obj=obj.name))
                assert out.succeeded == can, ((x, y), out.feedback)
                if can:
                    bob.release()
                    obj.held_by = None
                else:
                    assert out.code == OutcomeCode.TOO_FAR
                bob.set_arm(HOME)


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_alice_fetches_from_every_far_slot(scene: str) -> None:
    """What lies out of Bob's reach is Alice's to fetch: from the stand pose of his table nearest
    to it (the heuristic's choice), her pick succeeds at every far slot. Bases stop exactly
    (exact_motion): the test is about reach, not noise."""
    with Sim(task="pack_objects", scene=scene, seed=0, n_objects=6, aids=("exact_motion",)) as sim:
        alice, lay = sim.bots["alice"], sim.layout
        table = lay.get(lay.bob_table)
        assert table is not None
        obj = next(o for o in sim.objects.values() if o.on == lay.bob_table)
        sim.known["alice"].add(obj.name)
        for x, y in lay.far_slots:
            for other in sim.objects.values():  # nothing else on the table in the way
                if other is not obj and other.on == lay.bob_table:
                    other.on = "nowhere"
                    sim.world.rest(other, 50.0, 50.0, 0.0)
            obj.on, obj.inside, obj.held_by = lay.bob_table, False, None
            sim.world.rest(obj, x, y, table.top)
            pose = min(
                range(len(table.stand_poses)),
                key=lambda i: math.hypot(table.stand_poses[i][0] - x, table.stand_poses[i][1] - y),
            )
            assert sim.execute("alice", Navigate(target=lay.bob_table, stand_pose=pose)).succeeded
            out = sim.execute("alice", Pick(obj=obj.name))
            assert out.succeeded, ((x, y), out.feedback)
            alice.release()
            obj.held_by = None
            alice.set_arm(HOME)
