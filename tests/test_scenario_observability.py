"""Partial observability holds in dynamic episodes (issue 25): an event changes the world, never
what a robot believes, unless the robot observes it: it stands at the furniture the event
touched (a robot keeps seeing where it stands), or it is Bob, who sees his table and its fixtures
and is told his task. Every kind, in every scene, on real PyBullet worlds.

Each test gives the robots memories first (Alice has looked at every piece of furniture, David
at one, Bob at his table), fires one event, and compares every robot's observation before and
after: what changed must be something that robot could see."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from mhrc.core.protocol import Observation, ScenarioEvent
from mhrc.world.layouts import LAYOUTS
from mhrc.world.scenario import load_scenario
from mhrc.world.sim import Sim

ROBOTS = ("alice", "bob", "david")
KINDS = ("relocate", "new_target", "close", "breakdown")


def _objects(obs: Observation) -> dict[str, Any]:
    return {o.name: o.model_dump() for o in obs.objects}


def _furniture(obs: Observation) -> dict[str, Any]:
    return {f.name: f.is_open for f in obs.furniture}


def _places(ev: ScenarioEvent) -> set[str]:
    """The furniture an event touched."""
    return {v for k, v in ev.changed.items() if k in ("from", "to", "on", "container")}


def _sim(tmp_path: Path, scene: str, kind: str) -> Sim:
    event: dict[str, Any] = {"tick": 2, "kind": kind}
    if kind == "breakdown":
        event |= {"robot": "david", "ticks": 3}
    path = tmp_path / f"{kind}.json"
    path.write_text(json.dumps([event]), encoding="utf-8")
    return Sim(task="pack_objects", scene=scene, seed=3, n_objects=5, scenario=load_scenario(path))


def _give_memories(sim: Sim) -> tuple[str, str]:
    """Open every container, let Alice look at every piece of furniture and David at one other
    than hers; return where each stands now."""
    furniture = [f.name for f in sim.layout.furniture if f.stand_poses]
    for name in sim.scene.joints:
        sim.set_container(name, 0.4)
        sim.dynamics.note_containers()
    for name in furniture:
        sim.knowledge.look_at("alice", name)
    alice_at = furniture[-1]
    david_at = next(f for f in furniture if f not in (alice_at, sim.layout.bob_table))
    sim.knowledge.look_at("david", david_at)
    return alice_at, david_at


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("scene", sorted(LAYOUTS))
def test_an_event_is_seen_only_by_robots_that_observe_it(tmp_path: Path, scene: str, kind: str) -> None:
    with _sim(tmp_path, scene, kind) as sim:
        stands = dict(zip(("alice", "david"), _give_memories(sim)))
        bob_sees = {sim.layout.bob_table, *sim.fixtures}
        before = {r: sim.observe(r, 1) for r in ROBOTS}
        (event,) = sim.fire_events(2)
        assert event.applied, event.skipped
        after = {r: sim.observe(r, 2) for r in ROBOTS}
        touched = _places(event)
        for robot in ROBOTS:
            sees = bob_sees if robot == "bob" else {stands[robot]}
            b, a = before[robot], after[robot]
            moved = {n for n in _objects(b).keys() | _objects(a).keys() if _objects(b).get(n) != _objects(a).get(n)}
            if not sees & touched:  # the event happened out of its sight: its scene graph is as it was
                assert moved == set(), (robot, event.text, moved)
                assert _furniture(a) == _furniture(b), (robot, event.text)
            else:
                assert moved <= {
                    event.changed.get("object"),
                    *(n for n, o in sim.objects.items() if o.on in touched),
                }, (robot, moved)
            if kind == "new_target" and robot == "bob":  # his task grows: he is told
                assert a.targets == [*b.targets, event.changed["object"]]
            else:
                assert (a.targets, a.task_detail, a.task_status) == (b.targets, b.task_detail, b.task_status), robot
        # and a robot that looks where it happened sees the change
        if kind in ("relocate", "new_target"):
            name, where = event.changed["object"], event.changed.get("to") or event.changed["on"]
            sim.knowledge.look_at("david", where)
            assert {o.name: o.on for o in sim.observe("david", 2).objects}.get(name) == where
        elif kind == "close":
            container = event.changed["container"]
            assert _furniture(after["alice"])[container] is (
                stands["alice"] != container
            )  # she believes it open until she looks
            sim.knowledge.look_at("alice", container)
            assert _furniture(sim.observe("alice", 2))[container] is False
