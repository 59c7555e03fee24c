"""The task and scene registries as data: every task's generator on every layout, the goal
fixtures, `evaluate()` on hand-built end states, and layout-file validation. No PyBullet
needed except where a Sim is built from a user's own layout file."""

from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path
from typing import Any

import pytest

from mhrc.run.config import ConfigError, EpisodeConfig
from mhrc.world.briefs import Briefing, brief, detail
from mhrc.world.colors import PANEL_COLORS as COLORS
from mhrc.world.layouts import SCENES_DIR, LayoutError, get_layout, load_layout, parse_layout
from mhrc.world.scene import LAYOUTS
from mhrc.world.tasks import MENUS, TASKS, ObjectKind, Placement, Seen, get_task

GRID = [(n, seed) for n in (3, 4, 5, 6) for seed in range(10)]


def _bob_dist(scene: str, xy: tuple[float, float]) -> float:
    b = LAYOUTS[scene].bob_base
    return math.hypot(xy[0] - b[0], xy[1] - b[1])


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
@pytest.mark.parametrize("task", sorted(TASKS))
def test_generation_is_deterministic_and_has_the_papers_shape(task: str, scene: str) -> None:
    t, lay = TASKS[task], LAYOUTS[scene]
    containers = {f.name: f.container for f in lay.furniture if f.container is not None}
    seen_layouts = set()
    for n, seed in GRID:
        pls = t.generate(lay, seed, n)
        assert pls == t.generate(lay, seed, n), "generation must be deterministic per seed"
        seen_layouts.add(tuple((p.kind.name, p.furniture, p.xy) for p in pls))
        targets = [p for p in pls if p.target]
        distractors = [p for p in pls if not p.target]
        assert len(targets) == n and 1 <= len(distractors) <= 2
        assert len({p.kind.name for p in pls}) == len(pls), "object names are unique"
        assert len({(p.furniture, p.xy) for p in pls}) == len(pls), "no two objects share a spot"
        on_table = [p for p in targets if p.furniture == lay.bob_table]
        assert any(p.xy in lay.near_slots for p in on_table), "one target within Bob's reach"
        assert any(p.xy in lay.far_slots for p in on_table), "one target on Bob's table beyond his reach"
        inside = [p for p in targets if p.inside]
        assert len(inside) == 1 and inside[0].furniture in containers, "one target to find in a closed container"
        for p in pls:
            if p.inside:
                spec = containers[p.furniture]
                assert spec is not None and p.kind.height <= spec.max_object_height and p.xy in spec.slots
            elif p.furniture != lay.bob_table:
                f = lay.get(p.furniture)
                assert f is not None and p.xy in f.slots and f.stand_poses, "reachable by a mobile robot"
        goals = {t.goal(p.kind) for p in targets}
        fixtures = {fx.name for fx in t.fixtures(lay)}
        assert goals <= fixtures, "every target has a fixture to go to"
        if task == "sort_solids":
            assert all(t.goal(p.kind) not in fixtures for p in distractors), "a distractor has no panel"
        if task == "make_sandwich":
            menu = [p.kind.group for p in targets]
            assert tuple(menu) in MENUS.values() and not {p.kind.group for p in distractors} & set(menu)
    assert len(seen_layouts) > len(GRID) // 2, "seeds must vary the episodes"


@pytest.mark.parametrize("scene", sorted(LAYOUTS))
@pytest.mark.parametrize("task", sorted(TASKS))
def test_fixtures_lie_in_bobs_reach_and_apart(task: str, scene: str) -> None:
    lay = LAYOUTS[scene]
    fixtures = TASKS[task].fixtures(lay)
    for fx in fixtures:
        x, y = fx.center
        assert lay.in_goal_area(x, y) and 0.3 <= _bob_dist(scene, fx.center) <= 0.62, fx
    for i, a in enumerate(fixtures):
        for b in fixtures[i + 1 :]:
            apart_x = abs(a.center[0] - b.center[0]) >= (a.size[0] + b.size[0]) / 2
            apart_y = abs(a.center[1] - b.center[1]) >= (a.size[1] + b.size[1]) / 2
            assert apart_x or apart_y, (a.name, b.name)


# --------------------------------------------------------------------------- evaluate on hand-built end states


def _kinds(task: str, n: int = 4, seed: int = 0) -> tuple[list[ObjectKind], list[ObjectKind]]:
    pls: list[Placement] = TASKS[task].generate(LAYOUTS["kitchen"], seed, n)
    return [p.kind for p in pls if p.target], [p.kind for p in pls if not p.target]


HINTS = frozenset({"status_hints"})


def test_bobs_status_says_what_the_paper_says_and_nothing_more() -> None:
    """Pack: what is in the tray; sort: which solid lies on which panel; sandwich: the stack,
    bottom to top. "Not yet", "next", "wrong" are the status_hints aid."""
    pack, sort, sandwich = get_task("pack_objects"), get_task("sort_solids"), get_task("make_sandwich")
    targets, extra = _kinds("pack_objects")
    names = [k.name for k in targets]
    seen = [Seen(targets[0].name, targets[0], "tray"), Seen(extra[0].name, extra[0], "tray")]
    assert pack.status(names, seen) == f"In the tray: {targets[0].name}, {extra[0].name}."
    solids, _ = _kinds("sort_solids", n=4)
    a, b = solids[0], solids[1]
    swapped = [Seen(a.name, a, f"{b.group}_panel"), Seen(b.name, b, f"{b.group}_panel")]
    assert (
        sort.status([k.name for k in solids], swapped)
        == f"On the panels: {a.name} on {b.group}_panel, {b.name} on {b.group}_panel."
    )
    layers, _ = _kinds("make_sandwich", n=4, seed=2)
    stack = [Seen(layers[1].name, layers[1], "cutting_board", z=0.72)]
    assert sandwich.status([k.name for k in layers], stack) == f"On the cutting board, bottom to top: {layers[1].name}."
    for text in (
        pack.status(names, seen),
        sort.status([k.name for k in solids], swapped),
        sandwich.status([k.name for k in layers], stack),
    ):
        assert not any(w in text.lower() for w in ("not yet", "next", "wrong", "take", "reach"))


def test_sort_task_text_lists_solids_and_panels_but_not_which_goes_where() -> None:
    sort = get_task("sort_solids")
    solids, _ = _kinds("sort_solids", n=5)
    names = [k.name for k in solids]
    goals = {k.name: sort.goal(k) for k in solids}
    text = sort.finisher_detail(CREW, names, goals)  # as the robot that finishes the task (Bob) is told it
    assert all(n in text for n in names) and all(f"{c}_panel" in text for c in COLORS)
    assert not any(f"{n} onto" in text or f"{n} on {goals[n]}" in text for n in names)
    assert f"{names[0]} onto {goals[names[0]]}" in sort.finisher_detail(CREW, names, goals, frozenset({"goal_map"}))


CREW = Briefing(finisher="Bob", fetcher="Alice", table="table_0")


@pytest.mark.parametrize("task_id", sorted(TASKS))
def test_each_role_is_told_its_own_task_as_the_appendix_gives_it(task_id: str) -> None:
    """Alice's, Bob's and David's brief and detail carry the appendix's content for their role,
    per task (the appendix: Alice fetches for Bob and moves table objects only when he asks;
    David explores, follows Alice's arrangements and reports finds; Bob finishes, asks Alice, and
    keeps everything off the list out of the goal), and nothing a role cannot do."""
    task = get_task(task_id)
    targets = ["a_thing", "b_thing", "c_thing"]
    text = {
        role: brief(task, role, CREW) + "\n" + detail(task, role, CREW, targets, {t: "red_panel" for t in targets})
        for role in ("finisher", "fetcher", "scout")
    }
    things = task.things
    assert f"hand Bob the {things}" in text["fetcher"] and "Explore the whole house" in text["fetcher"]
    assert (
        f"Ask Bob which {things} are needed" in text["fetcher"]
        and "put them on table_0 close to Bob" in text["fetcher"]
    )
    assert (
        "When Bob asks, move" in text["fetcher"]
        and "do not move anything on the table unless Bob asks" in text["fetcher"]
    )
    assert (
        "Search the whole house" in text["scout"]
        and "Do as Alice arranges" in text["scout"]
        and "tell Alice about each new find" in text["scout"]
    )
    for word in (
        "fetch",
        "pick",
        "bring",
        "hand them",
        "Bob",
    ):  # David cannot fetch and, in the appendix, answers to Alice only
        assert word not in text["scout"], word
    assert text["finisher"].count("a_thing, b_thing, c_thing") == 1
    assert (
        "ask Alice to move it for you" in text["finisher"]
        and "ask Alice to search for them and bring them" in text["finisher"]
    )
    assert re.search(
        r"Nothing that is not on the (list|menu) goes (into the tray|onto a panel|onto the board)\.$", text["finisher"]
    )
    for role in ("fetcher", "scout"):
        assert "a_thing" not in text[role]  # the list is Bob's: the others learn it by asking


def test_pack_evaluate() -> None:
    t = get_task("pack_objects")
    targets, extra = _kinds("pack_objects")
    names = [k.name for k in targets]
    done = [Seen(k.name, k, "tray") for k in targets] + [Seen(k.name, k, "table_0") for k in extra]
    r = t.evaluate(names, done)
    assert (r.success, r.placed, r.partial_success) == (True, 4, 1.0)
    spoiled = done[:-1] + [Seen(extra[-1].name, extra[-1], "tray")]
    assert not t.evaluate(names, spoiled).success and "not on the list" in t.status(names, spoiled, HINTS)
    half = [Seen(k.name, k, "tray" if i < 2 else "counter") for i, k in enumerate(targets)]
    r = t.evaluate(names, half)
    assert (r.success, r.placed, r.partial_success) == (False, 2, 0.5)
    held = [Seen(k.name, k, None) for k in targets]  # held objects lie on nothing
    assert t.evaluate(names, held).placed == 0


def test_sort_evaluate() -> None:
    t = get_task("sort_solids")
    targets, extra = _kinds("sort_solids", n=5)
    names = [k.name for k in targets]
    assert {k.group for k in targets} <= set(COLORS) and not {k.group for k in extra} & set(COLORS)
    done = [Seen(k.name, k, f"{k.group}_panel") for k in targets]
    assert t.evaluate(names, done).success and "Every listed solid is on its panel" in t.status(names, done, HINTS)
    a, b = targets[0], targets[1]
    swapped = [Seen(a.name, a, f"{b.group}_panel"), Seen(b.name, b, f"{a.group}_panel"), *done[2:]]
    r = t.evaluate(names, swapped)
    assert (r.success, r.placed) == (False, 3) and "On a wrong panel" in t.status(names, swapped, HINTS)
    stray = done + [Seen(extra[0].name, extra[0], "red_panel")]
    assert not t.evaluate(names, stray).success and t.evaluate(names, stray).placed == 5


def test_sandwich_evaluate_checks_the_order_bottom_to_top() -> None:
    t = get_task("make_sandwich")
    targets, extra = _kinds("make_sandwich", n=4, seed=2)
    names = [k.name for k in targets]
    stack = [Seen(k.name, k, "cutting_board", z=0.72 + 0.02 * i) for i, k in enumerate(targets)]
    assert t.evaluate(names, stack).success and "complete" in t.status(names, stack, HINTS)
    # the same pieces with the second and third swapped: only the first is right
    wrong = [
        stack[0],
        Seen(stack[1].name, stack[1].kind, "cutting_board", z=stack[2].z),
        Seen(stack[2].name, stack[2].kind, "cutting_board", z=stack[1].z),
        stack[3],
    ]
    r = t.evaluate(names, wrong)
    assert (r.success, r.placed) == (False, 1) and "Wrong from" in t.status(names, wrong, HINTS)
    # a correct prefix scores partially; something extra on top spoils success
    assert t.evaluate(names, stack[:2]).placed == 2 and "Next: " + names[2] in t.status(names, stack[:2], HINTS)
    extra_on_top = stack + [Seen(extra[0].name, extra[0], "cutting_board", z=0.9)]
    assert not t.evaluate(names, extra_on_top).success
    # identical ingredients may swap places: the menu names kinds, not pieces
    if targets[0].group == targets[-1].group:
        flipped = [
            Seen(stack[-1].name, stack[-1].kind, "cutting_board", z=stack[0].z),
            *stack[1:-1],
            Seen(stack[0].name, stack[0].kind, "cutting_board", z=stack[-1].z),
        ]
        assert t.evaluate(names, flipped).success


# --------------------------------------------------------------------------- layout files


def _kitchen() -> dict[str, Any]:
    data: dict[str, Any] = json.loads((SCENES_DIR / "kitchen.json").read_text())
    return data


def _error(data: dict[str, Any]) -> str:
    with pytest.raises(LayoutError) as exc:
        parse_layout(data, "mine.json")
    return str(exc.value)


def test_every_builtin_layout_loads_from_its_file() -> None:
    assert sorted(LAYOUTS) == ["bathroom", "bedroom", "kitchen"]
    for name, lay in LAYOUTS.items():
        assert Path(lay.source).name == f"{name}.json" and load_layout(lay.source) == lay


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (
            lambda d: d["furniture"][2].update(size=[1.4, -0.6, 0.75]),
            "mine.json: furniture.2.size.1: Input should be greater than 0",
        ),
        (
            lambda d: d["furniture"][2].update(colour="red"),
            "mine.json: furniture.2.colour: Extra inputs are not permitted",
        ),
        (
            lambda d: d["furniture"][2].update(style="castle"),
            "mine.json: furniture.2.style: Input should be 'table', 'block', 'sofa', 'drawer_unit', 'chest' or 'cupboard'",
        ),
        (
            lambda d: d["furniture"][2]["stand_poses"].append({"side": "up", "at": 0}),
            "mine.json: furniture.2.stand_poses.1",
        ),
        (
            lambda d: d["furniture"][2]["stand_poses"].append([-3.6, 3.65, 0.0]),
            "furniture.2.stand_poses.1 (cabinet_0): (-3.6, 3.65) is within 0.3 m of furniture.2 (cabinet_0)",
        ),
        (lambda d: d["starts"].update(alice=[0.5, 0.0, 0.0]), "starts.alice: (0.5, 0.0) is within 0.3 m of walls.5"),
        (lambda d: d["bob"].update(table="table_9"), "bob.table: no furniture named 'table_9'"),
        (
            lambda d: d["bob"].update(goal_area=[-3.3, 0.4, 0.5, 0.4]),
            "bob.goal_area: [-3.3, 0.4, 0.5, 0.4] does not lie on table_0",
        ),
        (
            lambda d: d["furniture"][8]["slots"].append([9.0, 9.0]),
            "furniture.8: Value error, slots.3: [9.0, 9.0] is not on top of table_1",
        ),
        (
            lambda d: d.update(
                furniture=[f for f in d["furniture"] if f["style"] not in ("drawer_unit", "chest", "cupboard")]
            ),
            "furniture: a layout needs at least 2 closed containers a target can hide in",
        ),
        (lambda d: d["furniture"][8].update(name="cabinet_0"), "furniture.8.name: 'cabinet_0' is used twice"),
        (lambda d: d["furniture"][1]["drawer"].update(axis=[0.7, 0.7]), "axis must be a unit vector along x or y"),
        (lambda d: d.pop("bob"), "mine.json: bob: Field required"),
    ],
)
def test_a_bad_layout_file_names_the_field(edit: Any, expected: str) -> None:
    data = copy.deepcopy(_kitchen())
    edit(data)
    assert expected.replace("Value error, ", "") in _error(data)


def test_a_users_own_layout_file_is_used_by_path(tmp_path: Path) -> None:
    data = _kitchen()
    data["name"] = "my_kitchen"
    path = tmp_path / "my_kitchen.json"
    path.write_text(json.dumps(data))
    assert get_layout(str(path)).name == "my_kitchen"
    cfg = EpisodeConfig.build(scene=str(path))
    assert cfg.scene == str(path)
    (tmp_path / "bad.json").write_text("{ not json")
    with pytest.raises(ConfigError, match="bad.json: not valid JSON"):
        EpisodeConfig.build(scene=str(tmp_path / "bad.json"))
    data["furniture"][0]["size"] = [1.8, 0.8]
    (tmp_path / "short.json").write_text(json.dumps(data))
    with pytest.raises(ConfigError, match=r"short.json: furniture.0.size"):
        EpisodeConfig.build(scene=str(tmp_path / "short.json"))
    with pytest.raises(ConfigError, match="no such layout file"):
        EpisodeConfig.build(scene=str(tmp_path / "missing.json"))
