"""The drone kind (issue 33): it flies over furniture (walls still block it), faster than a ground
base, hovering at flight altitude; it sees surfaces from above, never inside a closed
container; it cannot open, pick, place or move. Real PyBullet, no mocks."""

from __future__ import annotations

import dataclasses
import math
from itertools import pairwise

import pybullet as p
import pytest

from mhrc.core.protocol import Move, Navigate, Open, OutcomeCode, Pick, Place
from mhrc.world.furniture import inside
from mhrc.world.kinds import AIR_CLEARANCE, KINDS, flight_altitude
from mhrc.world.scene import LAYOUTS
from mhrc.world.sim import Sim
from mhrc.world.teams import SHIPPED

DRONE = KINDS["drone"]


def _crossed(sim: Sim, path: list[tuple[float, float]]) -> set[str]:
    """The furniture whose footprint a route passes over (sampled every 2 cm)."""
    hit = set()
    for a, b in pairwise(path):
        n = max(2, int(math.hypot(b[0] - a[0], b[1] - a[1]) / 0.02))
        for k in range(n + 1):
            xy = (a[0] + (b[0] - a[0]) * k / n, a[1] + (b[1] - a[1]) * k / n)
            hit |= {f.name for f in sim.layout.furniture if inside(f.center, f.size, xy, margin=0.0)}
    return hit


def test_the_drone_is_data_a_scout_that_flies_faster() -> None:
    assert DRONE.flies and DRONE.mobile and not DRONE.has_arm and not DRONE.finishes_task
    assert set(DRONE.skills) == {"navigate", "communicate", "wait"}
    assert DRONE.speed > KINDS["mobile_base"].speed == KINDS["mobile_manipulator"].speed
    for name, lay in LAYOUTS.items():  # it cruises above every piece of furniture of every layout
        assert (
            flight_altitude(DRONE, max(f.size[2] for f in lay.furniture))
            >= max(f.size[2] for f in lay.furniture) + AIR_CLEARANCE
        ), name


def test_a_drone_flies_over_furniture_a_ground_base_goes_round_and_arrives_sooner() -> None:
    with Sim(team=SHIPPED["scout_and_drone"], seed=0, noise="off") as sim:
        start = (2.5, 3.2, 0.0)  # north of table_1; its stand pose 0 is south of it
        out = {}
        for robot in ("lucy", "david"):  # a drone and a ground robot share a stand pose: air and floor
            sim.bots[robot].set_base(start)
            out[robot] = sim.execute(robot, Navigate(target="table_1", stand_pose=0))
            assert out[robot].succeeded, out[robot].feedback
        flight, drive = out["lucy"], out["david"]
        assert flight.path is not None and drive.path is not None
        assert flight.path[0] == drive.path[0] == (2.5, 3.2) and flight.path[-1] == drive.path[-1] == (2.2, 1.7)
        assert "table_1" in _crossed(sim, flight.path) and not _crossed(sim, drive.path)
        fl, dl = float(flight.details["path_length"]), float(drive.details["path_length"])
        assert (
            fl < dl
            and flight.sim_time == pytest.approx(fl / DRONE.speed, abs=1e-3)
            and flight.sim_time < drive.sim_time / 3
        )
        # the body hovers at flight altitude over the stand pose: its viewpoint
        lucy = sim.bots["lucy"]
        pos, _ = p.getBasePositionAndOrientation(lucy.body, physicsClientId=sim.cid)
        tallest = max(f.size[2] for f in sim.layout.furniture)
        assert pos == pytest.approx((2.2, 1.7, flight_altitude(DRONE, tallest)), abs=1e-6)
        assert lucy.altitude > tallest
        assert sim.observe("lucy", 0).status.kind == "drone"


def test_walls_still_block_a_drone(monkeypatch: pytest.MonkeyPatch) -> None:
    ring = ((3.0, 0.6, 1.6, 0.1), (3.0, 2.6, 1.6, 0.1), (2.2, 1.6, 0.1, 2.1), (3.8, 1.6, 0.1, 2.1))
    kitchen = LAYOUTS["kitchen"]
    table_1 = kitchen.get("table_1")
    assert table_1 is not None
    pocket = dataclasses.replace(table_1, stand_poses=table_1.stand_poses + ((3.0, 1.6, 0.0),))
    layout = dataclasses.replace(
        kitchen,
        name="pocket",
        walls=kitchen.walls + ring,
        furniture=tuple(pocket if f.name == "table_1" else f for f in kitchen.furniture),
    )
    monkeypatch.setitem(LAYOUTS, "pocket", layout)
    with Sim(scene="pocket", team=SHIPPED["drone_scout"], seed=0, noise="off") as sim:
        lucy = sim.bots["lucy"]
        lucy.set_base((-2.9, 0.0, 0.0))  # hovering over Bob's table is fine in the air
        out = sim.execute("lucy", Navigate(target="table_1", stand_pose=2))
        assert out.code is OutcomeCode.NO_PATH, out.feedback
        lucy.set_base((3.0, 0.6, 0.0))  # in a wall
        assert sim.execute("lucy", Navigate(target="sofa", stand_pose=0)).code is OutcomeCode.START_INVALID


def test_a_drone_cannot_open_pick_place_or_move() -> None:
    with Sim(team=SHIPPED["drone_scout"], seed=0, noise="off") as sim:
        obj = next(iter(sim.objects))
        for action in (
            Open(target="drawer_unit"),
            Pick(obj=obj),
            Place(obj=obj, location="table_0"),
            Move(dx=0.1, dy=0),
        ):
            out = sim.execute("lucy", action)
            assert out.code is OutcomeCode.NOT_CAPABLE and "navigate, communicate, wait" in out.feedback, action


def test_a_drone_sees_a_surface_from_above_not_inside_a_closed_container() -> None:
    with Sim(team=SHIPPED["drone_scout"], seed=0, n_objects=6, noise="off") as sim:
        lay = sim.layout
        on_top = next(o for o in sim.objects.values() if not o.inside and o.on not in (lay.bob_table, None))
        hidden = next(o for o in sim.objects.values() if o.inside)
        assert on_top.on is not None and hidden.on is not None and not sim.is_open(hidden.on)
        seen = sim.execute("lucy", Navigate(target=on_top.on, stand_pose=0))
        assert seen.succeeded and on_top.name in seen.feedback, seen.feedback
        assert on_top.name in {o.name for o in sim.observe("lucy", 1).objects}
        closed = sim.execute("lucy", Navigate(target=hidden.on, stand_pose=0))
        assert closed.succeeded and "cannot be seen until it is opened" in closed.feedback
        assert "open it" not in closed.feedback  # a drone is never told to open
        assert hidden.name not in closed.feedback and hidden.name not in sim.known_objects("lucy")
