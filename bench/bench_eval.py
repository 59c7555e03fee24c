"""`mhrc eval` with an LLM of fixed latency: a small grid against a loopback OpenAI-compatible
server that answers every request after `--latency` seconds (its replies are scripted: the
robots wait, so every episode runs to the horizon), with 1 and with 2 worker processes.

For each worker count the same grid (same seeds, horizon and server) runs twice in this run:
once with the world's sequential schedule (the paper's Algorithm 1: one robot's LLM call after
another) and once with the lockstep schedule (the robots of a tick plan at once). Reports the
measured grid wall time of both, the LLM calls (summed from the episodes' traces and counted
at the server) and the ratio sequential / lockstep. Lockstep runs first at each worker count,
so a warm-up cost falls on the faster schedule and can only understate the ratio.

The defaults are those the benchmark had before the sequential runs were added (latency 0.5 s,
horizon 10, 4 trials, workers 1 and 2): nothing was cut; the script takes about 2.5 minutes.

    python bench/bench_eval.py [--latency 0.5] [--horizon 10] [--trials 4] [--workers 1,2] [--out bench/results/eval.json]
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from pathlib import Path
from typing import Any

from bench_llm_concurrency import CountingServer, serve
from report import emit

from mhrc.eval.engine import EvalSpec, evaluate

SCHEDULES = ("lockstep", "sequential")  # in the order they run


def run_grid(httpd: CountingServer, spec: EvalSpec, workers: int) -> dict[str, Any]:
    """The grid of `spec` with `workers` worker processes, measured."""
    before = httpd.requests
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        rows = asyncio.run(evaluate(spec, Path(tmp) / "ev", workers=workers))
        wall = time.perf_counter() - t0
    ran = {r.settings.schedule for r in rows}
    if ran != {spec.schedule}:
        raise RuntimeError(f"asked for the {spec.schedule} schedule, the episodes report {sorted(ran)}")
    return {
        "episodes": len(rows),
        "ticks": sum(r.metrics.temporal_steps for r in rows),
        "llm_calls": sum(r.metrics.llm_calls for r in rows),
        "server_requests": httpd.requests - before,
        "grid_wall_s": round(wall, 2),
        "episode_wall_s_mean": round(sum(r.metrics.wall_time for r in rows) / len(rows), 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--latency", type=float, default=0.5)
    ap.add_argument("--horizon", type=int, default=10)
    ap.add_argument("--trials", type=int, default=4)
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    httpd = serve(args.latency)
    runs = {}
    try:
        url = f"http://127.0.0.1:{httpd.server_address[1]}/v1"
        for w in (int(x) for x in args.workers.split(",")):
            grids = {}
            for schedule in SCHEDULES:
                spec = EvalSpec(
                    tasks=("pack_objects",),
                    scenes=("kitchen",),
                    objects=(3,),
                    trials=args.trials,
                    llm="openai:fixed-latency",
                    base_url=url,
                    horizon=args.horizon,
                    schedule=schedule,
                )
                grids[schedule] = run_grid(httpd, spec, w)
            runs[f"workers_{w}"] = {
                "sequential": grids["sequential"],
                "lockstep": grids["lockstep"],
                "speedup_lockstep_vs_sequential": round(
                    grids["sequential"]["grid_wall_s"] / grids["lockstep"]["grid_wall_s"], 2
                ),
            }
    finally:
        httpd.shutdown()
        httpd.server_close()
    emit(
        {
            "bench": "eval_fixed_latency_llm",
            "llm_latency_s": args.latency,
            "horizon": args.horizon,
            "trials": args.trials,
            "runs": runs,
            "note": "both schedules measured in this run against the same server, lockstep first at each worker count; "
            "grid wall time includes starting the worker processes and building every scene",
        },
        args.out,
    )


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
