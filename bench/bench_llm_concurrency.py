"""Concurrent planning: an LLM episode against a loopback OpenAI-compatible server with a fixed
latency, against what the paper's sequential loop (one robot's call after another) would take.

    python bench/bench_llm_concurrency.py [--latency 0.5] [--horizon 10]
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

from report import emit

from mhrc.episode import EpisodeConfig, up_in_process


def serve(latency: float) -> ThreadingHTTPServer:
    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:  # noqa: N802
            self.rfile.read(int(self.headers["Content-Length"]))
            time.sleep(latency)
            body = json.dumps({"choices": [{"message": {"content": "Command: wait()"}}]}).encode()
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    return httpd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--latency", type=float, default=0.5)
    ap.add_argument("--horizon", type=int, default=10)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    httpd = serve(args.latency)
    try:
        url = f"http://127.0.0.1:{httpd.server_address[1]}/v1"
        with tempfile.TemporaryDirectory() as tmp:
            cfg = EpisodeConfig.build(horizon=args.horizon, llm="openai:fixed-latency", base_url=url, trace=Path(tmp) / "t.jsonl")
            done = asyncio.run(up_in_process(cfg.resolved()))
    finally:
        httpd.shutdown()
        httpd.server_close()
    sequential = 3 * args.horizon * args.latency
    emit(
        {
            "bench": "llm_concurrency",
            "llm_latency_s": args.latency,
            "ticks": done.metrics.temporal_steps,
            "episode_wall_s": round(done.metrics.wall_time, 3),
            "sequential_loop_s": sequential,
            "speedup": round(sequential / done.metrics.wall_time, 2),
        },
        args.out,
    )


if __name__ == "__main__":
    main()
