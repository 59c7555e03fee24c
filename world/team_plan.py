"""The intended division of labour for every task, played straight against the simulator.

An omniscient script (it reads the simulator's ground truth), target by target in the task's
order: Bob (the robot that finishes the task) puts each on its goal if he can reach it; for
the rest Alice (the one that navigates, opens, picks and places) opens the drawer if needed,
fetches from the nearest stand pose (fixing a too-far grasp with the move the feedback
suggests) and hands over on table_0. Robots are found by what they can do. Tests use it to
show every generated episode is solvable; benchmarks use it to time the skills.
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
    finisher = min(sim.finishers())  # the paper's Bob: places on the goal fixtures
    fetcher = next(r for r in sim.robots if {"navigate", "open", "pick", "place"} <= sim.capabilities(r))  # Alice
    for name in list(sim.targets):
        obj = sim.objects[name]
        goal = sim.goals[name]
        if obj.on == sim.layout.bob_table and run(finisher, Pick(obj=name)).succeeded:
            run(finisher, Place(obj=name, location=goal))
            continue
        sim.known[fetcher].add(name)  # stands for Bob's request and David's reports
        f = sim.layout.get(obj.on or "")
        assert f is not None, f"{name} lies on nothing"
        if f.container is not None and not sim.is_open(f.name):
            run(fetcher, Navigate(target=f.name, stand_pose=0))
            run(fetcher, Open(target=f.name))
        x, y, _ = sim.position(obj)
        pose = min(
            range(len(f.stand_poses)), key=lambda i: math.hypot(f.stand_poses[i][0] - x, f.stand_poses[i][1] - y)
        )
        run(fetcher, Navigate(target=f.name, stand_pose=pose))
        out = run(fetcher, Pick(obj=name))
        if out.code == OutcomeCode.TOO_FAR and "dx" in out.details:
            run(fetcher, Move(dx=float(out.details["dx"]), dy=float(out.details["dy"])))
            run(fetcher, Pick(obj=name))
        run(fetcher, Navigate(target=sim.layout.bob_table, stand_pose=0))
        run(fetcher, Place(obj=name, location=sim.layout.bob_table))
        run(finisher, Pick(obj=name))
        run(finisher, Place(obj=name, location=goal))
