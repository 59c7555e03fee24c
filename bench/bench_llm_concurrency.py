"""Concurrent planning, measured: one LLM episode against a loopback OpenAI-compatible server
that answers every request after `--latency` seconds (its replies are scripted: the robots
wait, so the episode runs to the horizon), run twice in the same process against the same
server, with the same seed and horizon: once with the world's sequential schedule (the paper's
Algorithm 1: one robot's LLM call after another) and once with the lockstep schedule (the
robots of a tick plan at once).

Reports for each schedule the ticks, the episode's wall time (the world's measure, from the
start of the episode to its end: scene building and attaching are not in it), the LLM calls
counted at the server and from the trace, and the measured speed-up of lockstep over
sequential (sequential wall / lockstep wall). Lockstep runs first, so any warm-up cost falls
on the faster schedule and can only understate the speed-up.

    python bench/bench_llm_concurrency.py [--latency 0.5] [--horizon 10] [--out bench/results/llm_concurrency.json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import tempfile
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from report import emit

from mhrc.analysis.metrics import from_trace
from mhrc.core.protocol import EpisodeStarted
from mhrc.core.records import messages, read_records
from mhrc.run.config import EpisodeConfig
from mhrc.run.inprocess import up_in_process

SEED = 0
SCHEDULES = ("lockstep", "sequential")  # in the order they run


class CountingServer(ThreadingHTTPServer):
    """The loopback model server; `requests` counts the chat requests it has received."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.requests = 0
        self._lock = threading.Lock()

    def count(self) -> None:
        with self._lock:
            self.requests += 1


def serve(latency: float) -> CountingServer:
    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802
            self.rfile.read(int(self.headers["Content-Length"]))
            self.server.count()  # type: ignore[attr-defined]
            time.sleep(latency)
            body = json.dumps({"choices": [{"message": {"content": "Command: wait()"}}]}).encode()
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    httpd = CountingServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    return httpd


def run_episode(httpd: CountingServer, schedule: str, horizon: int) -> dict[str, Any]:
    """One episode with `schedule`, measured."""
    url = f"http://127.0.0.1:{httpd.server_address[1]}/v1"
    before = httpd.requests
    with tempfile.TemporaryDirectory() as tmp:
        trace = Path(tmp) / "t.jsonl"
        cfg = EpisodeConfig.build(
            seed=SEED, horizon=horizon, schedule=schedule, llm="openai:fixed-latency", base_url=url, trace=trace
        )
        done = asyncio.run(up_in_process(cfg.resolved()))
        rows = read_records(trace)
    m = from_trace(rows)
    ran = [m.scheduler for m in messages(rows, EpisodeStarted)]
    if ran != [schedule]:
        raise RuntimeError(f"asked for the {schedule} schedule, the world reported {ran}")
    return {
        "reason": done.reason,
        "ticks": done.metrics.temporal_steps,
        "episode_wall_s": round(done.metrics.wall_time, 3),
        "llm_calls": m.llm_calls,
        "server_requests": httpd.requests - before,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--latency", type=float, default=0.5)
    ap.add_argument("--horizon", type=int, default=10)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    httpd = serve(args.latency)
    try:
        runs = {s: run_episode(httpd, s, args.horizon) for s in SCHEDULES}
    finally:
        httpd.shutdown()
        httpd.server_close()
    emit(
        {
            "bench": "llm_concurrency",
            "llm_latency_s": args.latency,
            "horizon": args.horizon,
            "seed": SEED,
            "runs": {s: runs[s] for s in ("sequential", "lockstep")},
            "speedup_lockstep_vs_sequential": round(
                runs["sequential"]["episode_wall_s"] / runs["lockstep"]["episode_wall_s"], 2
            ),
            "note": "both schedules measured in this run against the same server; lockstep ran first",
        },
        args.out,
    )


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
