"""Resident memory of one long-lived process running episode after episode, as an `mhrc eval`
worker does (heuristic team, sequential schedule, every task x scene in turn, 4 objects).

Four configurations, each in a fresh process, measured in the same run, with the wall time of
its episodes:
- `before`: zenoh's shared-memory transport on (zenoh's default, which mhrc used until this
  benchmark found it: each session maps a 16 MB pool for messages over 3 KB and never unmaps
  it), no trim between episodes;
- `shm_off`: shared memory off (mhrc.core.bus's configuration now), no trim;
- `trim_every`: shared memory off and malloc_trim after every episode (what a worker did until
  issue 46 measured its price: the next episode faults the same pages in again);
- `now`: shared memory off, `mhrc.run.malloc.limit_arenas()` before the first episode and
  `release()` after each, which trims only above `TRIM_ABOVE_MB` (what a worker does).

Reports the resident size (MB) after each episode and the growth per episode over the second
half. Prints JSON (or writes it with --out).

    python bench/bench_memory.py [--episodes 18] [--out bench/results/memory.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from report import emit

CHILD = r"""
import asyncio, itertools, json, sys, tempfile, time
from pathlib import Path

import mhrc.core.bus
from mhrc.run import malloc as memory
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process

episodes, shm, trim = int(sys.argv[1]), sys.argv[2] == "1", sys.argv[3]  # trim: none, every or policy
if trim == "policy":
    memory.limit_arenas()
if shm:  # the configuration before: zenoh's default shared-memory transport
    plain = mhrc.core.bus.make_config

    def with_shm(**kw):
        conf = plain(**kw)
        conf.insert_json5("transport/shared_memory/enabled", "true")
        return conf

    mhrc.core.bus.make_config = with_shm


async def main() -> None:
    grid = list(itertools.product(["pack_objects", "sort_solids", "make_sandwich"], ["kitchen", "bathroom", "bedroom"]))
    out = []
    wall, cpu = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as d:
        for i in range(episodes):
            task, scene = grid[i % len(grid)]
            cfg = EpisodeConfig.build(task=task, scene=scene, seed=i, n_objects=4, schedule="sequential",
                                      trace=Path(d) / f"{i}.jsonl").resolved()
            done = await up_in_process(cfg)
            assert done.metrics.success, (task, scene, i)
            if trim != "none":
                memory.release(above_mb=0 if trim == "every" else memory.TRIM_ABOVE_MB)
            out.append(int(memory.resident_mb()))
    print(json.dumps({"rss_mb": out, "wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu}))


asyncio.run(main())
"""

CONFIGS = {
    "before": ("1", "none"),
    "shm_off": ("0", "none"),
    "trim_every": ("0", "every"),
    "now": ("0", "policy"),
}


def run(episodes: int, shm: str, trim: str) -> dict[str, Any]:
    done = subprocess.run(
        [sys.executable, "-c", CHILD, str(episodes), shm, trim], capture_output=True, text=True, check=True
    )
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def growth(rss: list[int]) -> float:
    """MB per episode over the second half (after the first episodes' one-off allocations)."""
    half = len(rss) // 2
    return round((rss[-1] - rss[half]) / max(1, len(rss) - 1 - half), 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--episodes", type=int, default=18)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    report: dict[str, Any] = {
        "bench": "worker_memory",
        "episodes": args.episodes,
        "unit": "MB resident after each episode",
    }
    for name, (shm, trim) in CONFIGS.items():
        got = run(args.episodes, shm, trim)
        rss = got["rss_mb"]
        report[name] = {
            "rss_mb": rss,
            "last_mb": rss[-1],
            "growth_mb_per_episode": growth(rss),
            "wall_s": round(got["wall_s"], 2),
            "cpu_s": round(got["cpu_s"], 2),
        }
    emit(report, args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
