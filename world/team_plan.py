"""The intended division of labour for every task, played straight against the simulator.

An omniscient script (it reads the simulator's ground truth), target by target in the task's
order: Bob puts each on its goal if he can reach it;
for the rest Alice opens the drawer if needed, fetches from the nearest stand pose (fixing a
too-far grasp with the move the feedback suggests) and hands over on table_0. Tests use it
to show every generated episode is solvable; benchmarks use it to time the skills.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from mhrc.core.protocol import Action, Move, Navigate, Open, OutcomeCode, Pick, Place, SkillOutcome

from .sim import Sim

Execute = Callable[[str, Action], SkillOutcome]


def play_team_plan(sim: Sim, execute: Execute | None = None) -> None:
    """Run the plan; `execute(robot, action)` defaults to `sim.execute` (wrap it to check or time)."""
    run = execute or sim.execute
    for name in list(sim.targets):
        obj = sim.objects[name]
        goal = sim.goals[name]
        if obj.on == sim.layout.bob_table and run("bob", Pick(obj=name)).succeeded:
            run("bob", Place(obj=name, location=goal))
            continue
        sim.known["alice"].add(name)  # stands for Bob's request and David's reports
        f = sim.layout.get(obj.on or "")
        assert f is not None, f"{name} lies on nothing"
        if f.container is not None and not sim.is_open(f.name):
            run("alice", Navigate(target=f.name, stand_pose=0))
            run("alice", Open(target=f.name))
        x, y, _ = sim._pos(obj)
        pose = min(range(len(f.stand_poses)), key=lambda i: math.hypot(f.stand_poses[i][0] - x, f.stand_poses[i][1] - y))
        run("alice", Navigate(target=f.name, stand_pose=pose))
        out = run("alice", Pick(obj=name))
        if out.code == OutcomeCode.TOO_FAR and "dx" in out.details:
            run("alice", Move(dx=float(out.details["dx"]), dy=float(out.details["dy"])))
            run("alice", Pick(obj=name))
        run("alice", Navigate(target=sim.layout.bob_table, stand_pose=0))
        run("alice", Place(obj=name, location=sim.layout.bob_table))
        run("bob", Pick(obj=name))
        run("bob", Place(obj=name, location=goal))
