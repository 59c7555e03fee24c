"""The simulator's CPU per episode, this tree beside a baseline tree, on the default grid's episodes.

Two workers, one per tree (each a process importing mhrc from its tree, as an `mhrc eval` worker
does), run the same episodes one at a time, alternating which tree goes first, so that both see
the same machine load. Each episode runs as `mhrc eval` runs it (mhrc.eval.episode.run_job: the
world and the heuristic agents on a loopback bus, a trace). Per episode and tree: the CPU seconds
of the thread that ran each skill (time.thread_time around Sim.execute, by skill) and built the
scene (Sim.__init__), the process's CPU, and a digest of the episode's end (its metrics but the
wall time, and every action result in the trace: outcome, observation, simulated times), so that
the report says whether the two trees played every episode identically.

    python bench/bench_skill_speed.py --baseline /tmp/old [--tasks ...] [--scenes ...] [--objects 3,4,5,6] [--repeats 1] [--out bench/results/skill_speed.json]

Make the baseline with `git worktree add /tmp/old main` (or any commit to compare with).
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import zlib
from collections import defaultdict
from pathlib import Path
from typing import Any

from report import check_tree, commit_of, emit

SENTINEL = "@@bench_skill_speed@@"


# ---------------------------------------------------------------------------------------- worker
def _instrument(cpu: dict[str, float]) -> None:
    """Count the thread CPU of every skill (by name), of every scene build and of all the world's
    thread work into `cpu`."""
    from mhrc.world.sim import Sim

    execute, init = Sim.execute, Sim.__init__

    def timed_execute(self: Any, robot: str, action: Any) -> Any:
        t = time.thread_time()
        try:
            return execute(self, robot, action)
        finally:
            cpu[f"skill:{action.skill}"] += time.thread_time() - t

    def timed_init(self: Any, *args: Any, **kwargs: Any) -> None:
        t = time.thread_time()
        try:
            init(self, *args, **kwargs)
        finally:
            cpu["build"] += time.thread_time() - t

    Sim.execute = timed_execute  # type: ignore[method-assign]
    Sim.__init__ = timed_init  # type: ignore[method-assign]

    # everything the world runs in its simulator's thread (the skills, the evaluation, the observations
    # and snapshots, closing it): with the build, the simulator's own time, against which the episode's
    # CPU is set
    real_to_thread = asyncio.to_thread

    async def timed_to_thread(func: Any, /, *args: Any, **kwargs: Any) -> Any:
        if not getattr(func, "__module__", "").startswith("mhrc.world"):  # a bus, the trace: not the simulator's
            return await real_to_thread(func, *args, **kwargs)

        def run() -> Any:
            t = time.thread_time()
            try:
                return func(*args, **kwargs)
            finally:
                cpu["world_threads"] += time.thread_time() - t

        return await real_to_thread(run)

    asyncio.to_thread = timed_to_thread  # type: ignore[assignment]


def _digest(trace_z: bytes) -> tuple[str, dict[str, Any], list[str]]:
    """The episode's end as a digest, its metrics (wall time left out), and one digest per action result."""
    from mhrc.core.protocol import ActionResult, EpisodeDone
    from mhrc.core.records import messages, read_records

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trace.jsonl"
        path.write_bytes(zlib.decompress(trace_z))
        lines = read_records(path)
    done = messages(lines, EpisodeDone)
    metrics = done[-1].metrics.model_dump(mode="json", exclude={"wall_time"}) if done else {}
    results = [
        json.dumps(r.model_dump(mode="json", exclude={"goal_id"}), sort_keys=True)
        for r in messages(lines, ActionResult)
    ]
    per = [hashlib.sha256(r.encode()).hexdigest()[:16] for r in results]
    whole = hashlib.sha256(json.dumps([metrics, per], sort_keys=True).encode()).hexdigest()[:16]
    return whole, metrics, per


def worker(tasks: str, scenes: str, objects: str, repeats: int) -> None:
    """Read episode keys on stdin; run each, write its figures as one JSON line after SENTINEL."""
    from mhrc.core import logs
    from mhrc.eval.episode import run_job
    from mhrc.eval.spec import EvalSpec

    logs.configure(level="warning")
    spec = EvalSpec(
        tasks=tuple(tasks.split(",")),
        scenes=tuple(scenes.split(",")),
        objects=tuple(int(n) for n in objects.split(",")),
        repeats=repeats,
    )
    jobs = {j.key: j for j in spec.jobs()}
    cpu: dict[str, float] = defaultdict(float)
    _instrument(cpu)
    for line in sys.stdin:
        key = line.strip()
        if not key:
            continue
        cpu.clear()
        t0, w0 = time.process_time(), time.perf_counter()
        res = asyncio.run(run_job(jobs[key], "bench"))
        proc, wall = time.process_time() - t0, time.perf_counter() - w0
        out: dict[str, Any] = {"key": key, "error": res.error, "process_cpu": proc, "wall": wall, "cpu": dict(cpu)}
        if res.error is None:
            out["digest"], out["metrics"], out["results"] = _digest(res.trace_z)
        print(SENTINEL + json.dumps(out), flush=True)


# ---------------------------------------------------------------------------------------- driver
class Tree:
    """A worker process importing mhrc from `root`."""

    def __init__(self, name: str, root: Path, argv: list[str]) -> None:
        env = {**os.environ, "PYTHONPATH": str(root)}
        self.name = name
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--worker", *argv],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            env=env,
            text=True,
            cwd=root,
        )
        self.check(root)

    def check(self, root: Path) -> None:
        """The worker must import this tree's mhrc, not the installed one."""
        check_tree(root, "mhrc.world.sim", self.name)

    def run(self, key: str) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(key + "\n")
        self.proc.stdin.flush()
        for line in self.proc.stdout:
            if line.startswith(SENTINEL):
                return dict(json.loads(line[len(SENTINEL) :]))
        raise SystemExit(f"{self.name}: the worker ended (exit {self.proc.wait()}) during {key}")

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(timeout=60)


def _skill_cpu(r: dict[str, Any]) -> float:
    return sum(v for k, v in r["cpu"].items() if k.startswith("skill:"))


def _mean(xs: list[float]) -> float:
    return round(statistics.mean(xs), 4) if xs else 0.0


def summarize(pairs: list[tuple[dict[str, Any], dict[str, Any]]]) -> dict[str, Any]:
    """Per tree: mean CPU seconds per episode (skills in all, by skill, the build, the process)."""
    out: dict[str, Any] = {}
    for i, tree in enumerate(("baseline", "this")):
        rs = [pair[i] for pair in pairs]
        skills = sorted({k for r in rs for k in r["cpu"] if k.startswith("skill:")})
        out[tree] = {
            "skills_cpu": _mean([_skill_cpu(r) for r in rs]),
            "by_skill_cpu": {k.removeprefix("skill:"): _mean([r["cpu"].get(k, 0.0) for r in rs]) for k in skills},
            "build_cpu": _mean([r["cpu"].get("build", 0.0) for r in rs]),
            "world_threads_cpu": _mean([r["cpu"].get("world_threads", 0.0) for r in rs]),
            "process_cpu": _mean([r["process_cpu"] for r in rs]),
            "wall": _mean([r["wall"] for r in rs]),
        }
    base, this = out["baseline"], out["this"]
    out["skills_cpu_ratio"] = round(this["skills_cpu"] / base["skills_cpu"], 3) if base["skills_cpu"] else None
    out["build_cpu_ratio"] = round(this["build_cpu"] / base["build_cpu"], 3) if base["build_cpu"] else None
    out["process_cpu_ratio"] = round(this["process_cpu"] / base["process_cpu"], 3) if base["process_cpu"] else None
    for tree in (base, this):  # the episode's CPU over the simulator's own (issue 46 item 2: at most 1.3)
        sim = tree["world_threads_cpu"] + tree["build_cpu"]
        tree["process_over_simulator"] = round(tree["process_cpu"] / sim, 3) if sim else None
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", type=Path, help="the tree to compare with (a git worktree of main)")
    ap.add_argument("--tasks", default="pack_objects,sort_solids,make_sandwich")
    ap.add_argument("--scenes", default="bathroom,bedroom,kitchen")
    ap.add_argument("--objects", default="3,4,5,6")
    ap.add_argument("--repeats", type=int, default=1, help="the grid this many times, with seeds 0..N-1")
    ap.add_argument("--rounds", type=int, default=1, help="play every episode this many times on each tree")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    grid = ["--tasks", args.tasks, "--scenes", args.scenes, "--objects", args.objects, "--repeats", str(args.repeats)]
    if args.worker:
        worker(args.tasks, args.scenes, args.objects, args.repeats)
        return
    if args.baseline is None:
        ap.error("--baseline: the tree to compare with is required")
    this_root = Path(__file__).resolve().parent.parent
    trees = [Tree("baseline", args.baseline, grid), Tree("this", this_root, grid)]
    keys = [
        f"{task}/{scene}/{n}/{seed}"
        for seed in range(args.repeats)
        for task in args.tasks.split(",")
        for scene in args.scenes.split(",")
        for n in args.objects.split(",")
    ]
    episodes: list[dict[str, Any]] = []
    pairs: list[tuple[dict[str, Any], dict[str, Any]]] = []
    try:
        k = 0
        for rnd in range(args.rounds):
            for key in keys:
                order = trees if k % 2 == 0 else trees[::-1]  # alternate which tree runs first
                k += 1
                got = {t.name: t.run(key) for t in order}
                base, this = got["baseline"], got["this"]
                same = base.get("digest") is not None and base.get("digest") == this.get("digest")
                first = next(
                    (i for i, (a, b) in enumerate(zip(base.get("results", []), this.get("results", []))) if a != b),
                    None,
                )
                episodes.append(
                    {
                        "key": key,
                        "round": rnd,
                        "identical": same,
                        "first_different_result": first,
                        "metrics": {"baseline": base.get("metrics"), "this": this.get("metrics")} if not same else None,
                        "errors": [base["error"], this["error"]] if base["error"] or this["error"] else None,
                        "TS": this.get("metrics", {}).get("temporal_steps"),
                        "skills_cpu": {"baseline": round(_skill_cpu(base), 4), "this": round(_skill_cpu(this), 4)},
                        "build_cpu": {
                            "baseline": round(base["cpu"].get("build", 0.0), 4),
                            "this": round(this["cpu"].get("build", 0.0), 4),
                        },
                    }
                )
                pairs.append((base, this))
                print(
                    f"{key} r{rnd}: {'same' if same else 'DIFFERENT'} skills "
                    f"{_skill_cpu(base):.3f} -> {_skill_cpu(this):.3f} CPU-s",
                    file=sys.stderr,
                )
    finally:
        for t in trees:
            t.close()
    report = {
        "bench": "skill_speed",
        "units": "CPU seconds per episode (thread CPU of the skills, the build and all the world's simulator-thread "
        "work; process CPU of the whole episode)",
        "machine": f"{platform.machine()}, {platform.python_implementation()} {platform.python_version()}, "
        f"{os.cpu_count()} cores",
        "baseline": str(args.baseline),
        "baseline_commit": commit_of(args.baseline),
        "this_commit": commit_of(this_root),
        "grid": {"tasks": args.tasks, "scenes": args.scenes, "objects": args.objects, "repeats": args.repeats},
        "rounds": args.rounds,
        "episodes_identical": f"{sum(e['identical'] for e in episodes)}/{len(episodes)}",
        "summary": summarize(pairs),
        "episodes": episodes,
        "note": "each episode as mhrc eval runs it (run_job: world and heuristic agents on a loopback bus); "
        "the two trees alternate which runs an episode first; identical: the same metrics (wall time aside) "
        "and the same action results in the trace (outcome, observation, simulated times)",
    }
    emit(report, args.out)


if __name__ == "__main__":
    main()
