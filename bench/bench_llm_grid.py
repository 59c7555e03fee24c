"""The paper's grid (3 tasks x 3 scenes x objects 3,4,5,6 = 36 episodes) with an LLM of fixed
latency, on one local worker running one episode at a time and running all 36 at once
(`--concurrency`), both measured in the same run.

The model is a loopback OpenAI-compatible HTTP server that answers every request after
`--latency` seconds with `Command: wait()`, so every episode runs its full horizon. The goal
line is the ideal concurrent run, longest episode's ticks x latency (every episode's calls in
flight together, the world and the bus costing nothing); the concurrent run should come
within 1.5x of it.

    python bench/bench_llm_grid.py [--latency 1.0] [--horizon 50] [--concurrency 1,36] [--out bench/results/llm_grid.json]

With the defaults the one-at-a-time run takes about 36 x 50 x 1 s = 30 min (--latency 0.2: 6 min).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import tempfile
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from report import emit

from mhrc.eval.engine import EvalSpec, evaluate
from mhrc.world.scene import LAYOUTS
from mhrc.world.tasks import TASKS

GOAL = 1.5  # the concurrent run's wall time may be this many times the ideal


class FixedLatencyModel(ThreadingHTTPServer):
    """An OpenAI-compatible chat endpoint on 127.0.0.1: every request is answered after `latency`
    seconds with a wait; counts requests and the most in flight at once."""

    daemon_threads = True
    request_queue_size = 512  # 36 episodes x 3 robots connect at once; the default backlog is 5

    def __init__(self, latency: float) -> None:
        self.latency = latency
        self.lock = threading.Lock()
        self.requests = 0
        self.in_flight = 0
        self.max_in_flight = 0
        model = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"  # keep-alive: each robot's client reuses its connection

            def do_POST(self) -> None:  # noqa: N802
                self.rfile.read(int(self.headers["Content-Length"]))
                with model.lock:
                    model.requests += 1
                    model.in_flight += 1
                    model.max_in_flight = max(model.max_in_flight, model.in_flight)
                time.sleep(model.latency)
                with model.lock:
                    model.in_flight -= 1
                body = json.dumps(
                    {
                        "choices": [
                            {
                                "message": {
                                    "role": "assistant",
                                    "content": "Analysis: nothing to do yet.\nCommand: wait()",
                                },
                                "finish_reason": "stop",
                            }
                        ],
                        "usage": {"prompt_tokens": 1000, "completion_tokens": 10},
                    }
                ).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: object) -> None:
                pass

        super().__init__(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server_address[1]}/v1"
        threading.Thread(target=self.serve_forever, daemon=True).start()

    def reset(self) -> None:
        with self.lock:
            self.requests = self.max_in_flight = 0

    def close(self) -> None:
        self.shutdown()
        self.server_close()


def lockstep_grid(horizon: int, base_url: str) -> EvalSpec:
    """Every task and scene with 3-6 objects, seed 0, driven by the model at `base_url`, lockstep: as the
    recorded figures ran (mhrc eval now defaults to sequential); bench_llm_client.py runs it too."""
    return EvalSpec(
        tasks=tuple(TASKS),
        scenes=tuple(LAYOUTS),
        objects=(3, 4, 5, 6),
        horizon=horizon,
        llm="m",
        base_url=base_url,
        schedule="lockstep",
    )


def run(spec: EvalSpec, model: FixedLatencyModel, concurrency: int) -> dict[str, Any]:
    """One evaluation of the grid on one local worker running `concurrency` episodes at once."""
    model.reset()
    with tempfile.TemporaryDirectory() as tmp:
        cpu0, t0 = os.times(), time.perf_counter()
        rows = asyncio.run(evaluate(spec, Path(tmp) / "ev", workers=1, concurrency=concurrency))
        wall, cpu = time.perf_counter() - t0, os.times()
    ticks = max(r.metrics.temporal_steps for r in rows)
    ideal = ticks * model.latency
    return {
        "concurrency": concurrency,
        "episodes": len(rows),
        "valid": sum(1 for r in rows if r.metrics.valid),
        "llm_calls": sum(r.metrics.llm_calls for r in rows),
        "server_requests": model.requests,
        "server_max_in_flight": model.max_in_flight,
        "longest_episode_ticks": ticks,
        "wall_s": round(wall, 2),
        "ideal_s": round(ideal, 2),
        "ratio_to_ideal": round(wall / ideal, 2),
        "episode_wall_s_mean": round(sum(r.metrics.wall_time for r in rows) / len(rows), 2),
        "episode_wall_s_max": round(max(r.metrics.wall_time for r in rows), 2),
        # the worker process (every episode) and this one (the coordinator's router, scoring, the model server)
        "worker_cpu_s": {
            "user": round(cpu.children_user - cpu0.children_user, 1),
            "sys": round(cpu.children_system - cpu0.children_system, 1),
        },
        "coordinator_cpu_s": {"user": round(cpu.user - cpu0.user, 1), "sys": round(cpu.system - cpu0.system, 1)},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--latency",
        type=float,
        default=1.0,
        help="seconds the model takes per request (the issue's 1 s; 0.2 for a quicker run)",
    )
    ap.add_argument("--horizon", type=int, default=50)
    ap.add_argument(
        "--concurrency", default="1,36", help="comma-separated: episodes the worker runs at once, one evaluation each"
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    levels = [int(x) for x in args.concurrency.split(",")]
    model = FixedLatencyModel(args.latency)
    spec = lockstep_grid(args.horizon, model.url)
    try:
        runs = {f"concurrency_{c}": run(spec, model, c) for c in levels}
    finally:
        model.close()
    result: dict[str, Any] = {
        "bench": "llm_grid",
        "config": {
            "grid": f"{len(TASKS)} tasks x {len(LAYOUTS)} scenes x objects 3,4,5,6 = {len(spec.jobs())} episodes, seed 0",
            "horizon": args.horizon,
            "llm_latency_s": args.latency,
            "llm_reply": "Command: wait() (every episode runs its full horizon)",
            "workers": 1,
            "concurrency": levels,
            "cpus": os.cpu_count(),
        },
        "runs": runs,
        "note": "wall_s: the whole evaluation (worker process start, every scene built, every trace shipped and scored); "
        "*_cpu_s: CPU seconds of the worker process and of this one (the coordinator's router, scoring, the model server); "
        "ideal_s = longest episode's ticks x latency (the only figure computed, not measured); "
        f"goal: the most concurrent run within {GOAL}x of ideal",
    }
    low, high = runs[f"concurrency_{min(levels)}"], runs[f"concurrency_{max(levels)}"]
    if len(levels) > 1:
        result["speedup"] = round(low["wall_s"] / high["wall_s"], 2)  # both measured above
    result["goal_met"] = high["ratio_to_ideal"] <= GOAL
    emit(result, args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
