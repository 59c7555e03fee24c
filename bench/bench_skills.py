"""Scene build time and the wall time of each skill (navigate, move, open, pick, place), per scene.

For every scene, builds one episode per task and seed, times the build, then plays mhrc.world.team_plan against the
simulator directly (no bus) and times every call. Seconds; p50/p99 over all calls of a
skill. Prints JSON (and writes it with --out).

    python bench/bench_skills.py [--seeds 0-9] [--objects 6] [--scenes kitchen,...] [--tasks ...] [--out bench/results/skills.json]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from collections import defaultdict
from pathlib import Path

from report import emit, percentile

from mhrc.core.protocol import Action, SkillOutcome
from mhrc.world.scene import LAYOUTS
from mhrc.world.sim import Sim
from mhrc.world.tasks import TASKS
from mhrc.world.team_plan import play_team_plan


def _stats(xs: list[float]) -> dict[str, float]:
    return {
        "n": len(xs),
        "p50": round(statistics.median(xs), 5),
        "p99": round(percentile(xs, 0.99), 5),
        "max": round(max(xs), 5),
    }


def bench_scene(scene: str, tasks: list[str], seeds: range, objects: int) -> dict[str, object]:
    """Build every (task, seed) episode of `scene`, play the team plan, time builds and skills."""
    times: dict[str, list[float]] = defaultdict(list)
    failed: dict[str, int] = defaultdict(int)
    build: list[float] = []
    solved = 0
    for task in tasks:
        for seed in seeds:
            t0 = time.perf_counter()
            sim = Sim(task=task, scene=scene, seed=seed, n_objects=objects)
            build.append(time.perf_counter() - t0)

            def run(robot: str, action: Action, sim: Sim = sim) -> SkillOutcome:
                t = time.perf_counter()
                out = sim.execute(robot, action)
                times[action.skill].append(time.perf_counter() - t)
                failed[action.skill] += not out.succeeded
                return out

            try:
                play_team_plan(sim, run)
                solved += sim.evaluate().success
            finally:
                sim.close()
    return {
        "episodes_solved": f"{solved}/{len(tasks) * len(seeds)}",
        "scene_build_s": _stats(build),
        "skills": {k: {**_stats(v), "failed": failed[k]} for k, v in sorted(times.items())},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0-9", help="a seed or an inclusive range, e.g. 0-9")
    ap.add_argument("--objects", type=int, default=6, help="target objects per episode (3-6)")
    ap.add_argument("--scenes", default=",".join(LAYOUTS), help="comma-separated layouts (default: all)")
    ap.add_argument("--tasks", default=",".join(TASKS), help="comma-separated tasks (default: all)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    lo, _, hi = args.seeds.partition("-")
    seeds = range(int(lo), int(hi or lo) + 1)
    tasks = args.tasks.split(",")
    report = {
        "bench": "skills",
        "units": "seconds (wall time)",
        "machine": f"{platform.machine()}, {platform.python_implementation()} {platform.python_version()}",
        "seeds": args.seeds,
        "objects": args.objects,
        "tasks": tasks,
        "scenes": {scene: bench_scene(scene, tasks, seeds, args.objects) for scene in args.scenes.split(",")},
        "note": (
            "build includes writing URDFs, loading them in the world and the planner's shadow client; "
            "pick/place/open include IK, BIT* to the pre-grasp (first solution), the descent and the planned retract; "
            "a chest's open also checks the whole lid arc; pick failures are the plan trying Bob first on objects "
            "beyond his reach and Alice grasps fixed by a move"
        ),
    }
    emit(report, args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
