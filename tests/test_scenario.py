"""Dynamic episodes (issue 25): the scenario file, its validation, and the world applying its
events at their tick (real PyBullet; the CLI and the bus through real `mhrc` processes)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from mhrc.core.protocol import Navigate, OutcomeCode, Wait
from mhrc.world.dynamics import episode_facts
from mhrc.world.scenario import ScenarioError, check_scenario, load_scenario
from mhrc.world.sim import Sim


def _write(tmp_path: Path, events: Any, name: str = "scenario") -> Path:
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(events), encoding="utf-8")
    return path


def _facts(task: str = "pack_objects", horizon: int = 50, robots: tuple[str, ...] = ("alice", "bob", "david")) -> Any:
    return episode_facts(task=task, scene="kitchen", horizon=horizon, robots=robots)


# --------------------------------------------------------------------------- validation


@pytest.mark.parametrize(
    ("events", "where"),
    [
        ({"tick": 1, "kind": "close"}, "a scenario is a JSON list"),
        (
            [{"tick": 1, "kind": "close"}, {"tick": 2, "kind": "explode"}],
            "events[1].kind: must be one of relocate, breakdown, new_target, close",
        ),
        ([{"tick": 3, "kind": "breakdown", "robot": "bob"}], "events[0].ticks: Field required"),
        ([{"tick": 0, "kind": "close"}], "events[0].tick:"),
        ([{"tick": 2, "kind": "close", "when": "later"}], "events[0].when:"),
        ([{"kind": "close"}], "events[0].tick: Field required"),
    ],
)
def test_a_malformed_file_names_the_event_and_field(tmp_path: Path, events: Any, where: str) -> None:
    with pytest.raises(ScenarioError) as err:
        load_scenario(_write(tmp_path, events))
    assert where in str(err.value)


@pytest.mark.parametrize(
    ("event", "where"),
    [
        (
            {"tick": 2, "kind": "breakdown", "robot": "eve", "ticks": 2},
            "events[1].robot: 'eve' is not a robot of this episode",
        ),
        ({"tick": 50, "kind": "close"}, "events[1].tick: 50 is past the horizon"),
        ({"tick": 2, "kind": "relocate", "to": "moon"}, "events[1].to: 'moon' is not a surface of this scene"),
        ({"tick": 2, "kind": "new_target", "on": "moon"}, "events[1].on: 'moon' is not a surface of this scene"),
        (
            {"tick": 2, "kind": "new_target", "object": "red_cube"},
            "events[1].object: 'red_cube' is not an object this task can have",
        ),
        (
            {"tick": 2, "kind": "close", "target": "table_0"},
            "events[1].target: 'table_0' is not a container of this scene",
        ),
    ],
)
def test_an_event_the_episode_cannot_honour_names_its_index_and_field(
    tmp_path: Path, event: dict[str, Any], where: str
) -> None:
    scenario = load_scenario(_write(tmp_path, [{"tick": 1, "kind": "close"}, event]))
    with pytest.raises(ScenarioError) as err:
        check_scenario(scenario, _facts())
    assert where in str(err.value)


def test_a_good_file_loads_with_its_name_and_hash(tmp_path: Path) -> None:
    path = _write(
        tmp_path,
        [{"tick": 1, "kind": "relocate"}, {"tick": 2, "kind": "breakdown", "robot": "david", "ticks": 3}],
        "mixed",
    )
    scenario = load_scenario(path)
    check_scenario(scenario, _facts())
    assert (
        scenario.name == "mixed"
        and len(scenario.sha256) == 64
        and [e.kind for e in scenario.events] == ["relocate", "breakdown"]
    )


# --------------------------------------------------------------------------- the events, on the simulator


def _sim(tmp_path: Path, events: list[dict[str, Any]], task: str = "pack_objects", seed: int = 0) -> Sim:
    return Sim(task=task, scene="kitchen", seed=seed, n_objects=4, scenario=load_scenario(_write(tmp_path, events)))


def _changed(before: dict[str, Any], after: dict[str, Any]) -> set[str]:
    return {k for k in before.keys() | after.keys() if before.get(k) != after.get(k)}


def test_relocate_fires_at_its_tick_and_moves_only_its_object(tmp_path: Path) -> None:
    with _sim(tmp_path, [{"tick": 3, "kind": "relocate"}]) as sim:
        robots0, objects0, open0 = sim.poses()
        assert sim.fire_events(1) == [] and sim.fire_events(2) == []
        assert sim.poses()[1] == objects0
        (event,) = sim.fire_events(3)
        robots1, objects1, open1 = sim.poses()
        assert event.applied and event.event == "relocate" and event.tick == 3 and event.index == 0
        moved = event.changed["object"]
        assert _changed(objects0, objects1) == {moved}
        assert (robots1, open1) == (robots0, open0)
        assert objects1[moved].on == event.changed["to"] != event.changed["from"] == objects0[moved].on
        assert moved in sim.targets
        assert sim.fire_events(4) == []  # fired once


def test_relocate_is_not_seen_until_the_robot_looks(tmp_path: Path) -> None:
    with Sim(task="pack_objects", scene="kitchen", seed=0, n_objects=4) as probe:
        bob_table = probe.layout.bob_table
        name = next(t for t in probe.targets if probe.objects[t].on != bob_table and not probe.objects[t].inside)
        old = probe.objects[name].on
        assert old is not None
        to = next(
            f.name for f in probe.layout.furniture if f.slots and f.container is None and f.name not in (old, bob_table)
        )
    with _sim(tmp_path, [{"tick": 2, "kind": "relocate", "object": name, "to": to}]) as sim:
        sim.learn("alice", [name])
        (event,) = sim.fire_events(2)
        assert event.applied and sim.objects[name].on == to
        seen = {o.name: o for o in sim.observe("alice", 2).objects}
        assert seen[name].on == old  # her scene graph keeps the old place
        sim.knowledge.look_at("alice", old)  # she looks where it was: gone from there
        seen = {o.name: o for o in sim.observe("alice", 2).objects}
        assert seen[name].on is None and seen[name].last_seen_on == old
        sim.knowledge.look_at("alice", to)  # and where it is now
        assert {o.name: o for o in sim.observe("alice", 2).objects}[name].on == to
        assert name not in {o.name for o in sim.observe("david", 2).objects}  # nobody else was told


def test_breakdown_fails_every_action_but_wait_for_its_ticks(tmp_path: Path) -> None:
    with _sim(tmp_path, [{"tick": 2, "kind": "breakdown", "robot": "david", "ticks": 3}]) as sim:
        poses0 = sim.poses()
        sim.fire_events(1)
        assert sim.execute("david", Wait()).succeeded
        (event,) = sim.fire_events(2)
        assert event.applied and event.changed == {"robot": "david", "until": "5"}
        assert sim.poses() == poses0  # a breakdown moves nothing
        out = sim.execute("david", Navigate(target=sim.layout.bob_table))
        assert out.code == OutcomeCode.BROKEN_DOWN and "broken down for 3 more steps" in out.feedback
        assert sim.execute("david", Wait()).succeeded
        assert sim.execute("alice", Navigate(target=sim.layout.bob_table)).code != OutcomeCode.BROKEN_DOWN  # only david
        sim.fire_events(4)
        assert "for 1 more step;" in sim.execute("david", Navigate(target=sim.layout.bob_table)).feedback
        sim.fire_events(5)
        assert sim.execute("david", Navigate(target=sim.layout.bob_table)).code != OutcomeCode.BROKEN_DOWN


@pytest.mark.parametrize("task", ["pack_objects", "sort_solids", "make_sandwich"])
def test_new_target_adds_one_object_to_the_task(tmp_path: Path, task: str) -> None:
    with _sim(tmp_path, [{"tick": 2, "kind": "new_target"}], task=task) as sim:
        _, objects0, open0 = sim.poses()
        total0 = sim.evaluate().total
        (event,) = sim.fire_events(2)
        _, objects1, open1 = sim.poses()
        new = event.changed["object"]
        assert event.applied and new not in objects0 and _changed(objects0, objects1) == {new} and open1 == open0
        assert sim.evaluate().total == total0 + 1 == int(event.changed["total"])
        assert objects1[new].on == event.changed["on"] and sim.targets[-1] == new
        bob = sim.observe("bob", 2)
        assert new in bob.targets and new in bob.task_detail
        assert new not in {o.name for o in sim.observe("alice", 2).objects}  # the others learn it from Bob


def test_close_shuts_the_last_opened_container_and_hides_its_contents(tmp_path: Path) -> None:
    with _sim(tmp_path, [{"tick": 2, "kind": "close"}]) as sim:
        containers = sorted(sim.scene.joints)
        first, last = containers[0], containers[1]
        sim.set_container(first, 0.2)
        sim.dynamics.note_containers()
        sim.set_container(last, 0.2)
        sim.dynamics.note_containers()
        inside = [n for n, o in sim.objects.items() if o.on == last and o.inside]
        robots0, objects0, open0 = sim.poses()
        (event,) = sim.fire_events(2)
        robots1, objects1, open1 = sim.poses()
        assert event.applied and event.changed == {"container": last}
        assert _changed(open0, open1) == {last} and open1[last] is False and open1[first] is True
        assert (
            _changed(objects0, objects1) <= set(inside) and robots1 == robots0
        )  # only what lies in it moves (with it)
        sim.knowledge.look_at("alice", last)
        assert sim.knowledge.beliefs["alice"].is_open(last) is False
        assert not {o.name for o in sim.observe("alice", 2).objects} & set(inside)


def test_an_event_that_cannot_apply_is_skipped_and_recorded(tmp_path: Path) -> None:
    with Sim(task="pack_objects", scene="kitchen", seed=0, n_objects=4) as probe:
        distractor = next(n for n, o in probe.objects.items() if not o.target)
    events = [
        {"tick": 1, "kind": "close"},  # nothing open
        {"tick": 1, "kind": "relocate", "object": distractor},  # not a target
        {"tick": 2, "kind": "new_target", "object": distractor},  # already in the scene
    ]
    with _sim(tmp_path, events) as sim:
        poses0 = sim.poses()
        fired = sim.fire_events(1) + sim.fire_events(2)
        assert [(e.index, e.applied) for e in fired] == [(0, False), (1, False), (2, False)]
        assert [e.skipped for e in fired] == [
            "no container is open",
            f"{distractor} is not a target of this episode",
            f"{distractor} is already in the scene",
        ]
        assert all("skipped" in e.text and e.changed == {} for e in fired)
        assert sim.poses() == poses0 and sim.evaluate().total == 4


# --------------------------------------------------------------------------- the bus and the CLI


def _mhrc(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mhrc", *args], cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("schedule", ["lockstep", "sequential", "async"])
def test_the_world_publishes_each_event_and_observations_follow_its_tick(tmp_path: Path, schedule: str) -> None:
    """Bob's task grows by a new target at tick 3: observations of ticks before it do not have it,
    those of tick 3 on do (async: actions that start at 3 x step_seconds or later)."""
    events = _write(tmp_path, [{"tick": 3, "kind": "new_target"}])
    trace = tmp_path / "trace.jsonl"
    done = _mhrc(
        "up",
        "--events",
        str(events),
        "--horizon",
        "25",
        "--schedule",
        schedule,
        "--quiet",
        "--json",
        "--trace",
        str(trace),
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    lines = [r for r in map(json.loads, trace.read_text().splitlines()) if isinstance(r.get("msg"), dict)]
    (event,) = [r["msg"] for r in lines if r["msg"].get("kind") == "scenario_event"]
    assert event["applied"] and event["tick"] == 3 and event["scenario"] == "scenario" and len(event["sha256"]) == 64
    new = event["changed"]["object"]
    results = [r["msg"] for r in lines if r["key"].endswith("/robot/bob/action/result")]
    assert results
    for r in results:
        has = new in r["observation"]["targets"]
        if schedule == "async":
            assert has == (r["started"] >= 3 * 8.0), r["started"]
        else:
            assert has == (r["observation"]["tick"] >= 3), r["observation"]["tick"]
    assert json.loads(done.stdout.strip().splitlines()[-1])["total"] == 5


@pytest.mark.parametrize(
    ("args", "where"),
    [
        (["up", "--quiet"], "events[0].robot: 'eve' is not a robot of this episode"),
        (["eval", "--dry-run"], "events[0].robot: 'eve' is not a robot of this episode"),
    ],
)
def test_a_bad_scenario_is_refused_before_anything_starts(tmp_path: Path, args: list[str], where: str) -> None:
    events = _write(tmp_path, [{"tick": 2, "kind": "breakdown", "robot": "eve", "ticks": 2}], "bad")
    before = set(tmp_path.iterdir())
    done = _mhrc(*args, "--events", str(events), cwd=tmp_path)
    assert done.returncode == 2
    errors = [line for line in done.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and "--events" in errors[0] and where in errors[0], done.stderr
    assert set(tmp_path.iterdir()) == before  # nothing left behind (no runs/, no trace)
