"""The PettingZoo environment (mhrc.env) beside the bus: the same heuristic episodes through
`parallel_env` in this process and through `mhrc up`'s machinery over a loopback Zenoh bus
(in-process, lockstep), measured in one run.

Per mode: resets per second (env: `reset()`, building the world; bus: everything before the
episode starts: the world built, the bus opened, the agents attached) and steps per second
(a step is a lockstep tick: every robot acts; env: the time inside `step()`, the expert's
commands given as strings; bus: ticks over the episode's wall time). The simulator's own skill
time (`Sim.execute`: planners, collision checks, motion) is timed in both, and its share of a
step is reported; so is whether both modes gave the same metrics for every episode.

    python bench/bench_env.py [--tasks pack_objects,sort_solids,make_sandwich] [--seeds 0-3] [--objects 4]
                              [--baseline DIR] [--out FILE]

With --baseline (a tree of an earlier commit: `git worktree add /tmp/mhrc-base <commit>`) the same
measurement runs with that tree's mhrc and with this tree's, each in a fresh interpreter, the trees
taking turns `--rounds` times (the first of each round alternating), and the report sets this tree's
steps a second beside the baseline's, the means over the rounds (issue 46 item 6). Run in one
process after the other, this tree had been 7-18% faster than the same tree as a baseline.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from report import commit_of, emit, int_range, percentile

import mhrc.env as mhrc_env
from mhrc.core import logs
from mhrc.core.protocol import Action, Metrics, SkillOutcome
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.world.sim import Sim

SKILL_SECONDS: list[float] = [0.0]  # Sim.execute's time, summed; reset per episode


def _time_skills() -> None:
    """Wrap Sim.execute, in this process, to add each call's wall time to SKILL_SECONDS."""
    execute: Callable[[Sim, str, Action], SkillOutcome] = Sim.execute

    def timed(self: Sim, robot: str, action: Action) -> SkillOutcome:
        t = time.perf_counter()
        try:
            return execute(self, robot, action)
        finally:
            SKILL_SECONDS[0] += time.perf_counter() - t

    Sim.execute = timed  # type: ignore[method-assign]


def env_episode(task: str, seed: int, objects: int) -> dict[str, Any]:
    env = mhrc_env.parallel_env(task=task, objects=objects, expert=True)
    t = time.perf_counter()
    _, infos = env.reset(seed=seed)
    reset_s = time.perf_counter() - t
    SKILL_SECONDS[0] = 0.0
    stepping, ticks = 0.0, 0
    while env.agents:
        commands = {a: infos[a]["expert_action"] for a in env.agents}
        t = time.perf_counter()
        _, _, _, _, infos = env.step(commands)
        stepping += time.perf_counter() - t
        ticks += 1
    assert env.core.done is not None
    metrics = env.core.done.metrics
    env.close()
    return {"reset_s": reset_s, "step_s": stepping, "ticks": ticks, "skill_s": SKILL_SECONDS[0], "metrics": metrics}


def bus_episode(task: str, seed: int, objects: int, tmp: Path) -> dict[str, Any]:
    cfg = EpisodeConfig.build(
        task=task, seed=seed, n_objects=objects, schedule="lockstep", trace=tmp / f"{task}-{seed}.jsonl"
    ).resolved()
    SKILL_SECONDS[0] = 0.0
    t = time.perf_counter()
    done = asyncio.run(up_in_process(cfg))
    total = time.perf_counter() - t
    m = done.metrics
    return {
        "reset_s": total - m.wall_time,  # building, opening the bus, attaching, closing: all but the episode
        "step_s": m.wall_time,
        "ticks": m.temporal_steps,
        "skill_s": SKILL_SECONDS[0],
        "metrics": m,
    }


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    resets = [r["reset_s"] for r in rows]
    step_s, ticks, skill_s = (sum(r[k] for r in rows) for k in ("step_s", "ticks", "skill_s"))
    return {
        "episodes": len(rows),
        "succ": round(sum(r["metrics"].success for r in rows) / len(rows), 4),
        "ticks": ticks,
        "reset_s_p50": round(statistics.median(resets), 4),
        "resets_per_s": round(len(resets) / sum(resets), 3),
        "steps_per_s": round(ticks / step_s, 2),
        "step_ms_p50": round(1000 * statistics.median(r["step_s"] / r["ticks"] for r in rows), 2),
        "step_ms_p90": round(1000 * percentile([r["step_s"] / r["ticks"] for r in rows], 0.9), 2),
        "skill_ms_per_step": round(1000 * skill_s / ticks, 2),
        "skill_share_of_step": round(skill_s / step_s, 4),
    }


def _same(a: Metrics, b: Metrics) -> bool:
    return a.model_dump(exclude={"wall_time"}) == b.model_dump(exclude={"wall_time"})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", default="pack_objects,sort_solids,make_sandwich")
    ap.add_argument("--seeds", default="0-3")
    ap.add_argument("--objects", type=int, default=4)
    ap.add_argument("--baseline", type=Path, default=None, help="a tree to measure beside this one, for comparison")
    ap.add_argument("--rounds", type=int, default=1, help="with --baseline: times the two trees take turns")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    if args.baseline is not None:
        emit(_beside_baseline(args), args.out)
        return
    logs.configure()  # warnings only: no debug line per skill in either mode
    _time_skills()
    tasks, seeds = args.tasks.split(","), int_range(args.seeds)
    rows: dict[str, list[dict[str, Any]]] = {"env": [], "bus": []}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for n, (task, seed) in enumerate((t, s) for t in tasks for s in seeds):
            if n % 2:  # each mode goes first in half the episodes: what the first run warms, the second finds warm
                bus_row = bus_episode(task, seed, args.objects, Path(tmp))
                env_row = env_episode(task, seed, args.objects)
            else:
                env_row = env_episode(task, seed, args.objects)
                bus_row = bus_episode(task, seed, args.objects, Path(tmp))
            rows["env"].append(env_row)
            rows["bus"].append(bus_row)
            print(
                f"{task} seed={seed}: TS={env_row['ticks']} env step {env_row['step_s']:.2f}s "
                f"bus {bus_row['step_s']:.2f}s same={_same(env_row['metrics'], bus_row['metrics'])}",
                file=sys.stderr,
            )
    env_s, bus_s = summarize(rows["env"]), summarize(rows["bus"])
    same = sum(_same(e["metrics"], b["metrics"]) for e, b in zip(rows["env"], rows["bus"]))
    step_over_skill = env_s["skill_share_of_step"] and round(1 / env_s["skill_share_of_step"], 3)
    report: dict[str, Any] = {
        "bench": "env",
        "config": {"tasks": args.tasks, "seeds": args.seeds, "objects": args.objects, "schedule": "lockstep"},
        "total_wall_s": round(time.perf_counter() - t0, 1),
        "runs": [{"mode": "env (parallel_env, in-process)"} | env_s, {"mode": "bus (mhrc up, in-process)"} | bus_s],
        "env_steps_per_s_over_bus": round(env_s["steps_per_s"] / bus_s["steps_per_s"], 3),
        "env_resets_per_s_over_bus": round(env_s["resets_per_s"] / bus_s["resets_per_s"], 3),
        "env_step_over_skill_time": step_over_skill,
        "same_metrics": f"{same} of {len(rows['env'])}",
        "note": (
            f"The env's step takes {step_over_skill}x the simulator's own skill time (the rest: observing, "
            "rendering the prompts, the expert's decision, admission and scheduling); the same episodes over the "
            f"bus step at {bus_s['steps_per_s']} ticks/s against the env's {env_s['steps_per_s']}. Same metrics "
            f"in both modes in {same} of {len(rows['env'])} episodes (the arm planner's budget is counted in "
            "collision checks, world/arm.py, so a plan does not depend on the machine's load)."
        ),
    }
    emit(report, args.out)


def _measured(tree: Path, args: argparse.Namespace) -> dict[str, Any]:
    """This benchmark run with `tree`'s mhrc in a fresh interpreter: its report."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "report.json"
        cmd = [sys.executable, __file__, "--tasks", args.tasks, "--seeds", args.seeds, "--objects", str(args.objects)]
        env = {**os.environ, "PYTHONPATH": f"{tree}{os.pathsep}{Path(__file__).parent}"}
        subprocess.run([*cmd, "--out", str(out)], env=env, cwd=tree, check=True, stdout=subprocess.DEVNULL)
        return dict(json.loads(out.read_text()))


def _beside_baseline(args: argparse.Namespace) -> dict[str, Any]:
    """Both trees measured `args.rounds` times in turn: this tree's last report, the baseline's
    figures, each round's steps a second and the ratios of their means."""
    here, base = Path(__file__).resolve().parents[1], args.baseline
    rounds: list[dict[str, dict[str, Any]]] = []
    for r in range(args.rounds):
        order = [("baseline", base), ("this", here)] if r % 2 == 0 else [("this", here), ("baseline", base)]
        got = {name: _measured(tree, args) for name, tree in order}
        rounds.append(got)
        print(
            f"round {r + 1}: " + ", ".join(f"{n} env {g['runs'][0]['steps_per_s']} steps/s" for n, g in got.items()),
            file=sys.stderr,
        )

    def mean(tree: str, mode: int, key: str = "steps_per_s") -> float:
        return statistics.fmean(float(r[tree]["runs"][mode][key]) for r in rounds)

    report = rounds[-1]["this"]
    report["baseline"] = {
        "tree": str(base),
        "commit": commit_of(base),
        "env_steps_per_s": round(mean("baseline", 0), 2),
        "env_resets_per_s": round(mean("baseline", 0, "resets_per_s"), 3),
        "bus_steps_per_s": round(mean("baseline", 1), 2),
        "same_metrics": rounds[-1]["baseline"]["same_metrics"],
    }
    report["rounds"] = [
        {
            tree: {
                "env_steps_per_s": r[tree]["runs"][0]["steps_per_s"],
                "bus_steps_per_s": r[tree]["runs"][1]["steps_per_s"],
            }
            for tree in ("baseline", "this")
        }
        for r in rounds
    ]
    report["env_steps_per_s_over_baseline"] = round(mean("this", 0) / mean("baseline", 0), 3)
    report["bus_steps_per_s_over_baseline"] = round(mean("this", 1) / mean("baseline", 1), 3)
    return report


if __name__ == "__main__":
    main()
