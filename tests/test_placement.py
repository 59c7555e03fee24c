"""Start poses for any team (world/placement.py) and one robot per stand pose (issue 33: a world
for several robots). Real PyBullet, no mocks."""

from __future__ import annotations

import dataclasses
import itertools
import math

import pytest

from mhrc.core.protocol import Navigate, OutcomeCode
from mhrc.core.team import RobotSpec, TeamError, TeamProblem, TeamSpec
from mhrc.world.bound import lower_bound, symbolic_episode
from mhrc.world.kinds import KINDS
from mhrc.world.layout_schema import LayoutFile
from mhrc.world.occupancy import occupancy
from mhrc.world.placement import STAND_CLEARANCE, START_GAP, place_team, reachable
from mhrc.world.scene import LAYOUTS, Layout
from mhrc.world.sim import Sim
from mhrc.world.skills.navigation import OFF_TARGET
from mhrc.world.teams import SHIPPED

TEAMS = ("drone_scout", "large", "full_house")


def _starts(sim: Sim) -> dict[str, tuple[float, float, float]]:
    return {name: b.base for name, b in sim.bots.items() if b.base is not None}


@pytest.mark.parametrize(("scene", "team"), list(itertools.product(sorted(LAYOUTS), TEAMS)))
def test_the_shipped_teams_start_apart_on_free_floor_and_the_seed_decides(scene: str, team: str) -> None:
    spec = SHIPPED[team]
    with Sim(scene=scene, team=spec, seed=4) as sim, Sim(scene=scene, team=spec, seed=4, task="sort_solids") as again:
        starts = _starts(sim)
        assert starts == _starts(again)  # the same seed, the same poses (whatever the task)
        assert set(starts) == {r.name for r in spec.robots if KINDS[r.kind].mobile}
        lay = sim.layout
        home = [(x, y) for x, y, _ in (lay.get(lay.bob_table) or lay.furniture[0]).stand_poses]
        floor = reachable(sim.grid, home)
        stands = [(x, y) for f in lay.furniture for x, y, _ in f.stand_poses]
        for name, (x, y, _) in starts.items():
            assert sim.grid.free(x, y), (name, x, y)
            if name not in lay.starts:  # chosen: on the floor that reaches Bob's table, off every stand pose
                assert floor[sim.grid.cell(x, y)], (name, x, y)
                assert all(math.hypot(x - sx, y - sy) >= STAND_CLEARANCE for sx, sy in stands), name
        for (a, pa), (b, pb) in itertools.combinations(starts.items(), 2):
            gap = KINDS[spec.robot(a).kind].footprint + KINDS[spec.robot(b).kind].footprint + START_GAP
            assert math.hypot(pa[0] - pb[0], pa[1] - pb[1]) >= gap - 1e-9, (a, b)
        for name in set(lay.starts) & set(starts):  # the layout's starts are kept
            assert starts[name] == lay.starts[name]
    with Sim(scene=scene, team=spec, seed=5) as other:
        assert _starts(other) != starts  # another seed, other chosen poses


def test_a_layout_may_name_any_robots_start(monkeypatch: pytest.MonkeyPatch) -> None:
    path = LAYOUTS["kitchen"].source
    data = LayoutFile.model_validate_json(open(path, encoding="utf-8").read()).model_dump()
    data["starts"]["lucy"] = (0.0, -1.0, 0.0)
    layout = LayoutFile.model_validate(data).build()
    assert layout.starts["lucy"] == (0.0, -1.0, 0.0)
    monkeypatch.setitem(LAYOUTS, "kitchen", layout)
    with Sim(team=SHIPPED["drone_scout"], seed=0) as sim:
        assert sim.bots["lucy"].base == (0.0, -1.0, 0.0)


def _closet() -> Layout:
    """The kitchen walled in around Bob's table: a closet of about 3.2 x 3.2 m; the rest of the
    house lies beyond the walls, out of reach."""
    k = LAYOUTS["kitchen"]
    walls = ((-2.9, 2.8, 10.0, 2.4), (-2.9, -2.8, 10.0, 2.4), (-0.7, 0.0, 1.4, 3.2), (-4.7, 0.0, 0.6, 3.2))
    return dataclasses.replace(k, name="closet", walls=k.walls + walls, starts={})


def test_a_team_the_layout_cannot_place_is_refused_in_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    closet = _closet()
    monkeypatch.setitem(LAYOUTS, "closet", closet)
    with Sim(scene="closet", team=SHIPPED["large"], seed=0) as sim:  # six fit: none beyond the walls
        floor = reachable(sim.grid, [(x, y) for x, y, _ in sim.layout.furniture[0].stand_poses])
        assert all(floor[sim.grid.cell(x, y)] for x, y, _ in _starts(sim).values())
    with pytest.raises(TeamError) as err:
        Sim(scene="closet", team=SHIPPED["full_house"], seed=0)
    assert err.value.code is TeamProblem.NO_ROOM and "no free floor left to start" in str(err.value)
    assert "\n" not in str(err.value)


def test_starts_the_team_forces_onto_one_spot_are_refused() -> None:
    robots = [RobotSpec(name="bob", kind="tabletop_arm")]
    robots += [RobotSpec(name=f"r{i}", kind="mobile_manipulator", start=(-1.5, 1.2, 0.0)) for i in range(7)]
    team = TeamSpec(name="crowd", robots=tuple(robots))
    lay = LAYOUTS["kitchen"]
    with pytest.raises(TeamError) as err:
        place_team(lay, team, 0, occupancy(lay, 0.3))
    assert err.value.code is TeamProblem.NO_ROOM and "r1's start (-1.5, 1.2) from the team is too close to r0's" in str(
        err.value
    )
    on_table = TeamSpec(
        name="t", robots=(robots[0], RobotSpec(name="al", kind="mobile_manipulator", start=(-2.9, 0, 0)))
    )
    with pytest.raises(TeamError, match="al's start .* is on an obstacle"):
        place_team(lay, on_table, 0, occupancy(lay, 0.3))


# --------------------------------------------------------------------------- one robot per stand pose


def _one_lockstep_tick(sim: Sim, actions: dict[str, Navigate]) -> dict[str, object]:
    """What the lockstep schedule does with one tick's actions: execute them in the team's order."""
    return {r: sim.execute(r, actions[r]) for r in sim.robots if r in actions}


def test_two_robots_sent_to_one_stand_pose_in_one_tick_one_arrives() -> None:
    with Sim(team=SHIPPED["two_fetchers"], seed=0, noise="off") as sim:
        goal = Navigate(target="table_1", stand_pose=0)
        out = _one_lockstep_tick(sim, {"carol": goal, "alice": goal, "david": goal})
        alice, carol, david = out["alice"], out["carol"], out["david"]
        assert alice.succeeded  # first in the team's order
        for late in (carol, david):
            assert late.code is OutcomeCode.OCCUPIED and not late.succeeded
            assert late.details["occupant"] == "alice" and "occupied by Alice" in late.feedback
        table_1 = sim.layout.get("table_1")
        assert table_1 is not None
        x, y, _ = table_1.stand_poses[0]
        assert math.hypot(sim.bots["carol"].base[0] - x, sim.bots["carol"].base[1] - y) > OFF_TARGET  # stayed put
        assert sim.execute("carol", Navigate(target="table_1", stand_pose=1)).succeeded  # another pose is free
        assert sim.execute("alice", Navigate(target="sofa", stand_pose=0)).succeeded  # Alice leaves ...
        assert sim.execute("david", goal).succeeded  # ... and the pose is free again
        assert sim.execute("alice", goal).details["occupant"] == "david"


def test_a_drone_hovers_above_a_ground_robot_but_not_beside_another_drone() -> None:
    with Sim(team=SHIPPED["full_house"], seed=0, noise="off") as sim:
        goal = Navigate(target="table_1", stand_pose=0)
        out = _one_lockstep_tick(sim, {"alice": goal, "lucy": goal, "mia": goal})
        assert out["alice"].succeeded and out["lucy"].succeeded  # the floor and the air above it
        assert out["mia"].code is OutcomeCode.OCCUPIED and out["mia"].details["occupant"] == "lucy"


def test_the_lower_bound_shares_the_fetching_among_fetchers() -> None:
    """world/bound.py: a second fetcher can only lower the bound; the paper's team keeps its own."""
    for seed in range(3):
        with Sim(seed=seed, n_objects=6) as paper, Sim(seed=seed, n_objects=6, team=SHIPPED["two_fetchers"]) as two:
            ep = symbolic_episode(paper.world, paper.targets)
            assert (ep.fetchers, ep.finishers) == (1, 1) and paper.lower_bound() == lower_bound(ep)
            assert 0 < two.lower_bound() <= paper.lower_bound()
            assert symbolic_episode(two.world, two.targets).fetchers == 2
