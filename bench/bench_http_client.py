"""Where a model call's CPU goes on the client's side (issue 46 item 3): our OpenAIChatClient (as
this tree has it: httpx over aiohttp's connections, agents/llm/transport.py), the same HTTP exchange
through httpx alone with its own transport (the client's before), through httpx over a bare aiohttp
transport, and through aiohttp alone, each in a fresh interpreter, against one local server in a
process of its own.

The server (starlette on uvicorn, 127.0.0.1) answers every POST of /v1/chat/completions with a
streamed reply of CHUNKS `data:` events (one token each, as llama.cpp and hosted APIs stream), the
usage and [DONE]. Each client process sends `--calls` requests through one client, C at once for
each C of `--concurrency` (1: an episode's robot, whose client has one call in flight; 36: one client
shared by many calls), with the bench_llm_grid's prompt size, after `--warmup` calls it does not count,
and prints its own CPU (process_time) per call; the modes take turns round by round. Only the
client's CPU is counted, never the server's.

    python bench/bench_http_client.py [--calls 1000] [--chunks 1,30] [--concurrency 1,36] [--rounds 2]
                                      [--out bench/results/http_client.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from report import commit_of, emit

from mhrc.core.endpoints import free_port

ROOT = Path(__file__).resolve().parents[1]

SERVER = """
import json, sys
import uvicorn
from starlette.applications import Starlette
from starlette.responses import StreamingResponse
from starlette.routing import Route

CHUNK = b"data: " + json.dumps({"choices": [{"index": 0, "delta": {"content": "tok "}}]}).encode() + b"\\n\\n"
END = b'data: {"choices":[],"usage":{"prompt_tokens":900,"completion_tokens":30}}\\n\\ndata: [DONE]\\n\\n'

async def complete(request):
    body = await request.json()
    n = int(body.get("chunks", 30))
    async def events():
        for _ in range(n):
            yield CHUNK
        yield END
    return StreamingResponse(events(), media_type="text/event-stream")

app = Starlette(routes=[Route("/v1/chat/completions", complete, methods=["POST"])])
uvicorn.run(app, host="127.0.0.1", port=int(sys.argv[1]), log_level="error", access_log=False)
"""

# one client process: argv = port, mode, calls, concurrency, warmup, chunks; prints {"cpu_ms_per_call": ...}
CLIENT = """
import asyncio, json, sys, time
port, mode, calls, concurrency, warmup, chunks = sys.argv[1], sys.argv[2], *map(int, sys.argv[3:7])
base = f"http://127.0.0.1:{port}/v1"
url = base + "/chat/completions"
messages = [{"role": "system", "content": "s" * 6000}, {"role": "user", "content": "u" * 3000}]
body = {"model": "m", "messages": messages, "temperature": 0.0, "max_tokens": 1024, "stream": True,
        "stream_options": {"include_usage": True}, "chunks": chunks}

async def run(one, close):
    limit = asyncio.Semaphore(concurrency)
    async def bounded():
        async with limit:
            await one()
    await asyncio.gather(*(bounded() for _ in range(warmup)))
    t, w = time.process_time(), time.perf_counter()
    await asyncio.gather(*(bounded() for _ in range(calls)))
    cpu, wall = time.process_time() - t, time.perf_counter() - w
    await close()
    print(json.dumps({"cpu_ms_per_call": 1000 * cpu / calls, "wall_s": wall}))

async def ours():
    from mhrc.agents.llm import OpenAIChatClient
    client = OpenAIChatClient("m", base, max_concurrency=concurrency, extra_body={"chunks": chunks})
    async def one():
        c = await client.complete(messages, temperature=0.0)
        assert c.completion_tokens == 30, c
    await run(one, client.aclose)

def lines_of(http):
    async def one():
        async with http.stream("POST", url, json=body) as resp:
            n = 0
            async for line in resp.aiter_lines():
                n += line.startswith("data:")
            assert n == chunks + 2, n
    return one

async def httpx_alone():
    import httpx
    http = httpx.AsyncClient(timeout=httpx.Timeout(None, connect=60.0))
    await run(lines_of(http), http.aclose)

async def httpx_over_aiohttp():
    import aiohttp, httpx

    class Stream(httpx.AsyncByteStream):
        def __init__(self, resp):
            self.resp = resp
        async def __aiter__(self):
            async for chunk in self.resp.content.iter_any():
                yield chunk
        async def aclose(self):
            self.resp.release()

    class Transport(httpx.AsyncBaseTransport):
        def __init__(self):
            self.session = None
        async def handle_async_request(self, request):
            if self.session is None:
                self.session = aiohttp.ClientSession(auto_decompress=False)
            data = b"".join([part async for part in request.stream])
            headers = [(k.decode(), v.decode()) for k, v in request.headers.raw]
            resp = await self.session.request(request.method, str(request.url), data=data, headers=headers)
            return httpx.Response(resp.status, headers=list(resp.raw_headers), stream=Stream(resp))
        async def aclose(self):
            if self.session is not None:
                await self.session.close()

    http = httpx.AsyncClient(timeout=httpx.Timeout(None, connect=60.0), transport=Transport())
    await run(lines_of(http), http.aclose)

async def aiohttp_alone():
    import aiohttp
    session = aiohttp.ClientSession()
    async def one():
        async with session.post(url, json=body) as resp:
            n = 0
            async for line in resp.content:
                n += line.startswith(b"data:")
            assert n == chunks + 2, n
    await run(one, session.close)

asyncio.run({"ours": ours, "httpx": httpx_alone, "httpx_over_aiohttp": httpx_over_aiohttp,
             "aiohttp": aiohttp_alone}[mode]())
"""

MODES = ("ours", "httpx", "httpx_over_aiohttp", "aiohttp")


def _wait_listening(port: int, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"the bench's model server exited with {proc.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.1)
    raise SystemExit("the bench's model server did not listen within 30 s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--calls", type=int, default=1000, help="counted calls per client process")
    ap.add_argument("--warmup", type=int, default=100, help="calls before counting (connections, imports)")
    ap.add_argument("--concurrency", default="1,36", help="calls at once through the one client, comma-separated")
    ap.add_argument("--chunks", default="1,30", help="streamed tokens per reply, comma-separated")
    ap.add_argument("--rounds", type=int, default=2, help="every mode this many times, in turns")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    chunk_counts = [int(c) for c in args.chunks.split(",")]
    at_once = [int(c) for c in args.concurrency.split(",")]
    cases = [(k, c) for c in at_once for k in chunk_counts]
    name = {case: f"{case[0]} chunk(s), {case[1]} at once" for case in cases}
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    port = free_port()
    server = subprocess.Popen([sys.executable, "-c", SERVER, str(port)], env=env)
    runs: dict[str, dict[str, list[float]]] = {name[case]: {m: [] for m in MODES} for case in cases}
    try:
        _wait_listening(port, server)
        for r in range(args.rounds):
            for chunks, concurrency in cases:
                for mode in MODES if r % 2 == 0 else tuple(reversed(MODES)):
                    argv = [port, mode, args.calls, concurrency, args.warmup, chunks]
                    out = subprocess.run(
                        [sys.executable, "-c", CLIENT, *map(str, argv)],
                        env=env,
                        capture_output=True,
                        text=True,
                        check=True,
                    )
                    got = json.loads(out.stdout.strip().splitlines()[-1])
                    runs[name[chunks, concurrency]][mode].append(round(got["cpu_ms_per_call"], 3))
                    print(
                        f"round {r + 1}, {name[chunks, concurrency]}, {mode}: {got['cpu_ms_per_call']:.3f} ms",
                        file=sys.stderr,
                    )
    finally:
        server.terminate()
        server.wait(timeout=30)
    summary: list[dict[str, Any]] = []
    for case in cases:
        means = {m: round(statistics.mean(v), 3) for m, v in runs[name[case]].items()}
        summary.append(
            {
                "case": name[case],
                **{f"{m}_ms": v for m, v in means.items()},
                "httpx_over_aiohttp_ratio": round(means["httpx_over_aiohttp"] / means["httpx"], 3),
                "ours_over_httpx_ratio": round(means["ours"] / means["httpx"], 3),
            }
        )
    first = summary[len(chunk_counts) - 1]  # the most chunks, the fewest at once
    report = {
        "bench": "http_client",
        "machine": {"python": platform.python_version(), "cpus": os.cpu_count()},
        "commit": commit_of(ROOT),
        "config": {
            "calls": args.calls,
            "warmup": args.warmup,
            "concurrency": at_once,
            "chunks": chunk_counts,
            "rounds": args.rounds,
            "prompt_chars": 9000,
        },
        "runs": runs,
        "summary": summary,
        "note": (
            f"ms of the client's CPU a call ({first['case']}): OpenAIChatClient {first['ours_ms']}, httpx alone "
            f"{first['httpx_ms']}, httpx over an aiohttp transport {first['httpx_over_aiohttp_ms']}, aiohttp alone "
            f"{first['aiohttp_ms']}. The server's CPU is not counted."
        ),
    }
    emit(report, args.out)


if __name__ == "__main__":
    main()
