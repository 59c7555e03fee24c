"""Our CPU per model call (issue 46 item 3): the LLM grid of `bench_llm_grid.py` (36 episodes at
once against a loopback model of fixed latency that answers wait) run on two source trees,
alternating, in the same session: a baseline (`--baseline`, e.g. a worktree of main) and this
one. Each run is a child process with PYTHONPATH set to its tree, so the worker it starts imports
that tree's mhrc.

For each run: the worker process's CPU (user and sys, from the OS's accounting of the waited
child), the coordinator's (this child: the driver and scoring; the fake model server runs in a
process of its own, its CPU reported apart), both per model call, the wall time over the ideal, and where the worker's CPU went by thread, read from
/proc/<pid>/task/*/stat every `--every` seconds (real CPU, not samples): the main thread (the
asyncio loop: the world, the agents, the bus's Python side, the trace), Zenoh's runtime threads
by pool (`rx-*`, `tx-*`, `net-*`, `acc-*`, `app-*`: native Rust, no GIL), and the other
Python threads (Zenoh's callback threads and the executor's: scene builds, session open and
close). A thread that ended between two reads loses its last interval: `unattributed`.

    python bench/bench_llm_client.py --baseline /tmp/old-client [--rounds 2] [--latency 1.0]
                                     [--horizon 50] [--concurrency 36] [--out bench/results/llm_client.json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from report import emit

HERE = Path(__file__).resolve().parent
TICK = os.sysconf("SC_CLK_TCK")
ZENOH_POOLS = ("rx-", "tx-", "net-", "acc-", "app-")


def _threads(pid: int) -> dict[int, tuple[str, float]]:
    """tid -> (name, CPU seconds) of every thread of `pid` now."""
    out: dict[int, tuple[str, float]] = {}
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1 : stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2 :].split()
        out[int(tid)] = (name, (int(fields[11]) + int(fields[12])) / TICK)  # utime, stime
    return out


class ThreadClock:
    """Reads the CPU of every thread of this process's `mhrc.eval.pool` children while they run."""

    def __init__(self, every: float) -> None:
        self.every = every
        self.seen: dict[tuple[int, int], tuple[str, float]] = {}  # (pid, tid) -> latest (name, cpu)
        self.pids: set[int] = set()
        self.own_cpu = 0.0  # CPU seconds of these reads (this process's, not the coordinator's: subtracted)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> ThreadClock:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _workers(self) -> list[int]:
        me = os.getpid()
        pids = []
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
                ppid = int(stat[stat.rindex(")") + 2 :].split()[1])
                if ppid == me and b"mhrc.eval.pool" in Path(f"/proc/{entry}/cmdline").read_bytes():
                    pids.append(int(entry))
            except (OSError, ValueError):
                continue
        return pids

    def _run(self) -> None:
        while not self._stop.wait(self.every):
            for pid in self._workers():
                self.pids.add(pid)
                for tid, (name, cpu) in _threads(pid).items():
                    self.seen[(pid, tid)] = (name, cpu)
            self.own_cpu = time.thread_time()  # a worker of ~900 threads cost these reads ~7 CPU-s a grid

    def shares(self) -> dict[str, float]:
        """CPU seconds by thread group."""
        groups: dict[str, float] = {}
        for (pid, tid), (name, cpu) in self.seen.items():
            if tid == pid:
                group = "main thread (asyncio loop)"
            elif name.startswith(ZENOH_POOLS):
                group = f"zenoh runtime {name.split('-')[0]}"
            else:
                group = "other Python threads (zenoh callbacks, executor)"
            groups[group] = groups.get(group, 0.0) + cpu
        return groups


class ModelProcess:
    """bench_llm_grid's FixedLatencyModel in a process of its own, so that the CPU of this one
    is the coordinator's alone (the fake model's is not ours)."""

    def __init__(self, latency: float) -> None:
        code = (
            f"import sys; sys.path.insert(0, {str(HERE)!r}); from bench_llm_grid import FixedLatencyModel; "
            f"m = FixedLatencyModel({latency!r}); print(m.url, flush=True); sys.stdin.read(); m.close()"
        )
        self.proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        assert self.proc.stdout is not None
        self.url = self.proc.stdout.readline().decode().strip()

    def cpu(self) -> float:
        """CPU seconds the model server used so far."""
        fields = Path(f"/proc/{self.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / TICK

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait(30)


def one(args: argparse.Namespace) -> dict[str, Any]:
    """One run of the grid in this process (the child of `main`)."""
    from bench_llm_grid import lockstep_grid

    import mhrc
    from mhrc.eval.engine import evaluate

    model = ModelProcess(args.latency)
    spec = lockstep_grid(args.horizon, model.url)
    try:
        with tempfile.TemporaryDirectory() as tmp, ThreadClock(args.every) as clock:
            cpu0, t0 = os.times(), time.perf_counter()
            rows = asyncio.run(evaluate(spec, Path(tmp) / "ev", workers=1, concurrency=args.concurrency))
            wall, cpu = time.perf_counter() - t0, os.times()  # the worker was waited; the model server was not
        model_cpu = model.cpu()
    finally:
        model.close()
    calls = sum(r.metrics.llm_calls for r in rows)
    ticks = max(r.metrics.temporal_steps for r in rows)
    worker = (cpu.children_user - cpu0.children_user) + (cpu.children_system - cpu0.children_system)
    coordinator = (cpu.user - cpu0.user) + (cpu.system - cpu0.system) - clock.own_cpu
    by_thread = clock.shares()
    by_thread["unattributed (threads ended between reads)"] = worker - sum(by_thread.values())
    return {
        "mhrc": str(Path(mhrc.__file__).parent.parent),
        "episodes": len(rows),
        "valid": sum(1 for r in rows if r.metrics.valid),
        "llm_calls": calls,
        "wall_s": round(wall, 2),
        "ideal_s": round(ticks * args.latency, 2),
        "ratio_to_ideal": round(wall / (ticks * args.latency), 2),
        "worker_cpu_s": {
            "user": round(cpu.children_user - cpu0.children_user, 2),
            "sys": round(cpu.children_system - cpu0.children_system, 2),
        },
        "coordinator_cpu_s": round(coordinator, 2),
        "model_server_cpu_s": round(model_cpu, 2),
        "thread_reads_cpu_s": round(clock.own_cpu, 2),  # this bench's own reads of /proc, left out of the coordinator's
        "worker_cpu_ms_per_call": round(1000 * worker / calls, 2),
        "total_cpu_ms_per_call": round(1000 * (worker + coordinator) / calls, 2),
        "worker_cpu_by_thread_s": {k: round(v, 2) for k, v in sorted(by_thread.items(), key=lambda kv: -kv[1])},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", type=Path, help="the source tree to compare with (a worktree of main)")
    ap.add_argument("--rounds", type=int, default=2, help="baseline, this tree: alternated this many times")
    ap.add_argument("--latency", type=float, default=1.0)
    ap.add_argument("--horizon", type=int, default=50)
    ap.add_argument("--concurrency", type=int, default=36)
    ap.add_argument(
        "--short-horizon",
        type=int,
        default=5,
        help="a second run per tree at this horizon: the CPU that does not grow with the calls (scene builds, "
        "start-up, scoring) is told apart from each call's (0: none)",
    )
    ap.add_argument("--every", type=float, default=0.5, help="seconds between reads of the threads' CPU")
    ap.add_argument("--shared", action="store_true", help="note that the machine was shared with other work")
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a child: one run, JSON on stdout
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(args)))
        return
    trees = {"this": HERE.parent} | ({"baseline": args.baseline.resolve()} if args.baseline else {})
    horizons = [args.horizon] + ([args.short_horizon] if args.short_horizon else [])
    order = [(name, h) for _ in range(args.rounds) for h in horizons for name in sorted(trees)]  # baseline first
    runs: dict[str, list[dict[str, Any]]] = {f"{name}_h{h}": [] for name in trees for h in horizons}
    for name, horizon in order:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--one"]
        cmd += ["--latency", str(args.latency), "--horizon", str(horizon)]
        cmd += ["--concurrency", str(args.concurrency), "--every", str(args.every)]
        env = dict(os.environ, PYTHONPATH=str(trees[name]))
        done = subprocess.run(cmd, env=env, check=True, stdout=subprocess.PIPE, cwd=trees[name])
        runs[f"{name}_h{horizon}"].append(json.loads(done.stdout.decode().strip().splitlines()[-1]))
        print(name, horizon, json.dumps(runs[f"{name}_h{horizon}"][-1]), file=sys.stderr)

    def mean(key: str, field: str) -> float:
        return sum(r[field] for r in runs[key]) / len(runs[key])

    def cpu(key: str, with_coordinator: bool) -> float:  # CPU seconds of a run, the mean over the rounds
        total = mean(key, "worker_cpu_ms_per_call") * mean(key, "llm_calls") / 1000
        return total + (mean(key, "coordinator_cpu_s") if with_coordinator else 0.0)

    summary: dict[str, dict[str, float]] = {}
    for name in trees:
        long = f"{name}_h{args.horizon}"
        summary[name] = {
            f: round(mean(long, f), 2) for f in ("worker_cpu_ms_per_call", "total_cpu_ms_per_call", "ratio_to_ideal")
        }
        if args.short_horizon:  # what each further call costs: the difference of the two horizons' CPU
            short = f"{name}_h{args.short_horizon}"
            calls = mean(long, "llm_calls") - mean(short, "llm_calls")
            for label, coord in (("worker", False), ("total", True)):
                marginal = (cpu(long, coord) - cpu(short, coord)) / calls
                summary[name][f"{label}_cpu_ms_per_further_call"] = round(1000 * marginal, 2)
                fixed = cpu(short, coord) - marginal * mean(short, "llm_calls")
                summary[name][f"{label}_cpu_s_per_episode_besides_calls"] = round(fixed / mean(short, "episodes"), 3)
    emit(
        {
            "bench": "llm_client",
            "config": {
                "grid": "3 tasks x 3 scenes x objects 3,4,5,6 = 36 episodes, seed 0, lockstep",
                "latency_s": args.latency,
                "horizon": args.horizon,
                "concurrency": args.concurrency,
                "workers": 1,
                "short_horizon": args.short_horizon,
                "order": [f"{name}_h{h}" for name, h in order],
                "cpus": os.cpu_count(),
                "machine_shared": args.shared,
            },
            "summary": summary,
            "runs": runs,
            "note": "worker_cpu_ms_per_call: the episode worker's CPU (user + sys) over the grid / model calls; "
            "total adds the coordinator (the driver, scoring; not the fake model server, a process of its own, "
            "model_server_cpu_s); both include each episode's "
            "scene build and start-up; *_per_further_call: the difference of the two horizons' CPU over the difference "
            "of their calls; *_per_episode_besides_calls: the rest, per episode (scene build, sessions, scoring); "
            "ideal_s = longest episode's ticks x latency. "
            + (
                "The machine was shared with another session's episodes: regenerate on a quiet one. "
                if args.shared
                else ""
            ),
        },
        args.out,
    )


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
