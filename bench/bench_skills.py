"""Scene build time and each skill's time (navigate, open, pick, place), over several seeds.

Plays mhrc.world.team_plan against the simulator directly (no bus) and times
every call. Prints JSON (or writes it with --out).

    python bench/bench_skills.py [--seeds 0-9] [--objects 6]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict
from pathlib import Path

from report import emit, percentile

from mhrc.protocol import Action, SkillOutcome
from mhrc.world.sim import Sim
from mhrc.world.team_plan import play_team_plan


def _stats(xs: list[float]) -> dict[str, float]:
    xs = sorted(xs)
    return {"n": len(xs), "p50_ms": round(statistics.median(xs) * 1e3, 3), "p99_ms": round(percentile(xs, 0.99) * 1e3, 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0-9")
    ap.add_argument("--objects", type=int, default=6)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    lo, _, hi = args.seeds.partition("-")
    times: dict[str, list[float]] = defaultdict(list)
    failures: dict[str, int] = defaultdict(int)
    build: list[float] = []
    for seed in range(int(lo), int(hi or lo) + 1):
        t0 = time.perf_counter()
        sim = Sim(seed=seed, n_objects=args.objects)
        build.append(time.perf_counter() - t0)

        def run(robot: str, action: Action, sim: Sim = sim) -> SkillOutcome:
            t = time.perf_counter()
            out = sim.execute(robot, action)
            times[action.skill].append(time.perf_counter() - t)
            failures[action.skill] += not out.succeeded
            return out

        try:
            play_team_plan(sim, run)
        finally:
            sim.close()
    report = {
        "bench": "skills",
        "seeds": args.seeds,
        "objects": args.objects,
        "scene_build": _stats(build),
        "skills": {k: _stats(v) for k, v in sorted(times.items())},
        "failures": dict(failures),
        "planner_note": "pick/place/open include IK, a BIT* plan (first solution), the descent and the retract plan",
        "failures_note": "pick failures are the plan trying Bob first on objects beyond his reach, and Alice grasps fixed by a move",
    }
    emit(report, args.out)


if __name__ == "__main__":
    main()
