"""`mhrc eval` with an LLM of fixed latency: a small grid against a loopback OpenAI-compatible
server that answers every request after `--latency` seconds (its replies are scripted: the
robots wait, so every episode runs to the horizon), with 1 and with 2 worker processes.

Reports the grid's wall time against what the paper's loop would take: one robot's LLM call
after another, tick after tick, episode after episode (robots x ticks x latency, summed).

    python bench/bench_eval.py [--latency 0.5] [--horizon 10] [--trials 4] [--out bench/results/eval.json]
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from pathlib import Path

from bench_llm_concurrency import serve
from report import emit

from mhrc.evaluation import EvalSpec, evaluate


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
        spec = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=args.trials,
                        llm="openai:fixed-latency", base_url=url, horizon=args.horizon)  # fmt: skip
        for w in (int(x) for x in args.workers.split(",")):
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                rows = asyncio.run(evaluate(spec, Path(tmp) / "ev", workers=w))
                wall = time.perf_counter() - t0
            sequential = sum(len(r["robots"]) * r["temporal_steps"] * args.latency for r in rows)
            runs[f"workers_{w}"] = {
                "episodes": len(rows),
                "llm_calls": sum(r["llm_calls"] for r in rows),
                "grid_wall_s": round(wall, 2),
                "paper_sequential_s": round(sequential, 2),
                "speedup": round(sequential / wall, 2),
                "episode_wall_s_mean": round(sum(r["wall_time"] for r in rows) / len(rows), 3),
            }
    finally:
        httpd.shutdown()
        httpd.server_close()
    emit({"bench": "eval_fixed_latency_llm", "llm_latency_s": args.latency, "horizon": args.horizon, "runs": runs,
          "note": "grid wall time includes starting the worker processes and building every scene"}, args.out)  # fmt: skip


if __name__ == "__main__":
    main()
