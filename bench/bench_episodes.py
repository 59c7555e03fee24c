"""The heuristic team on a grid of Pack Objects episodes, in-process and with --processes.

Reports Succ, PS, TS, AS (summed over robots) per mode, each episode's wall time, and whether
both modes gave identical metrics for every seed. Prints JSON (or writes it with --out).

    python bench/bench_episodes.py [--seeds 0-9] [--objects 3,4,5,6] [--modes in_process,processes]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

from report import int_range

from mhrc.core.protocol import EpisodeDone, Metrics
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process
from mhrc.run.processes import up_processes

RUNNERS: dict[str, Callable[[EpisodeConfig], Coroutine[Any, Any, EpisodeDone]]] = {
    "in_process": lambda cfg: up_in_process(cfg),
    "processes": lambda cfg: up_processes(cfg),
}


def summarize(rows: list[Metrics]) -> dict[str, float]:
    return {
        "episodes": len(rows),
        "succ": round(sum(m.success for m in rows) / len(rows), 4),
        "ps": round(statistics.mean(m.partial_success for m in rows), 4),
        "ts": round(statistics.mean(m.temporal_steps for m in rows), 3),
        "as": round(statistics.mean(m.action_steps for m in rows), 3),
        "wall_s_p50": round(statistics.median(m.wall_time for m in rows), 3),
        "wall_s_max": round(max(m.wall_time for m in rows), 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0-9")
    ap.add_argument("--objects", default="3,4,5,6")
    ap.add_argument("--modes", default="in_process,processes")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    modes = args.modes.split(",")
    episodes: dict[str, dict[str, Metrics]] = {m: {} for m in modes}
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for mode in modes:
            for n in int_range(args.objects):
                for seed in int_range(args.seeds):
                    cfg = EpisodeConfig.build(
                        seed=seed, n_objects=n, trace=Path(tmp) / f"{mode}-{n}-{seed}.jsonl"
                    ).resolved()
                    done = asyncio.run(RUNNERS[mode](cfg))
                    episodes[mode][f"{n}-{seed}"] = done.metrics
                    m = done.metrics
                    print(
                        f"{mode} objects={n} seed={seed}: success={m.success} PS={m.partial_success:.2f} "
                        f"TS={m.temporal_steps} AS={m.action_steps} wall={m.wall_time:.1f}s",
                        file=sys.stderr,
                    )
    report: dict[str, object] = {
        "bench": "heuristic_pack_objects_grid",
        "seeds": args.seeds,
        "objects": args.objects,
        "total_wall_s": round(time.perf_counter() - t_start, 1),
        "summary": {mode: summarize(list(eps.values())) for mode, eps in episodes.items()},
        "per_objects": {
            mode: {n: summarize([m for k, m in eps.items() if k.startswith(f"{n}-")]) for n in int_range(args.objects)}
            for mode, eps in episodes.items()
        },
        "failures": {mode: [k for k, m in eps.items() if not m.success] for mode, eps in episodes.items()},
        "episodes": {mode: {k: m.model_dump() for k, m in eps.items()} for mode, eps in episodes.items()},
    }
    if len(modes) == 2:
        a, b = (episodes[m] for m in modes)
        report["modes_agree"] = all(
            a[k].model_dump(exclude={"wall_time"}) == b[k].model_dump(exclude={"wall_time"}) for k in a
        )
    text = json.dumps(report, indent=2)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    print(json.dumps({k: v for k, v in report.items() if k != "episodes"}, indent=2))


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
