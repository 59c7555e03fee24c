"""Action round trip over the bus, excluding skill time: request -> ack -> result for `wait`.

One robot (alice) attached, so each tick closes on its action alone. In-process: the world
and the agent are separate Zenoh sessions in this process. Cross-process: the world runs as
`mhrc world` in a child process. Prints JSON (or writes it with --out).

    python bench/bench_bus.py [--n 300] [--out bench/results/bus.json]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from report import emit, percentile

from mhrc.core.bus import open_client
from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionAck, ActionRequest, ActionResult, AttachReply, AttachRequest, Wait, decode
from mhrc.core.security import Credentials
from mhrc.run.config import EpisodeConfig
from mhrc.run.processes import wait_for_port, world_command
from mhrc.run.serve import serve_world


async def _round_trips(endpoint: str, run: str, n: int, security: Credentials | None = None) -> dict[str, float]:
    bus = await open_client(endpoint, 30.0, security=security)
    try:
        k = Keys(run)
        acks: asyncio.Queue[ActionAck] = asyncio.Queue()
        results: asyncio.Queue[ActionResult] = asyncio.Queue()
        bus.subscribe(k.action_ack("alice"), lambda s: acks.put_nowait(decode(s.payload, ActionAck)))
        bus.subscribe(k.action_result("alice"), lambda s: results.put_nowait(decode(s.payload, ActionResult)))
        reply = None
        for _ in range(300):
            got = await bus.get(k.attach("alice"), AttachRequest(robot="alice", agent_id="bench"))
            if got:
                reply = decode(got[0], AttachReply)
                break
            await asyncio.sleep(0.1)
        assert reply is not None and reply.accepted, reply
        bus.declare_token(k.alive_robot("alice"))
        await asyncio.sleep(1.0)  # the world starts after its start timeout
        tick, ack_ms, res_ms = reply.tick, [], []
        for _ in range(n):
            t0 = time.perf_counter()
            bus.put(k.action_request("alice"), ActionRequest(robot="alice", agent_id="bench", tick=tick, action=Wait()))
            ack = await asyncio.wait_for(acks.get(), 10)
            t1 = time.perf_counter()
            res = await asyncio.wait_for(results.get(), 10)
            t2 = time.perf_counter()
            assert ack.accepted, ack.reason
            tick = res.tick + 1
            ack_ms.append((t1 - t0) * 1e3)
            res_ms.append((t2 - t0) * 1e3)
        return {**_stats("ack_ms", ack_ms), **_stats("result_ms", res_ms), "n": n}
    finally:
        await bus.close()


def _stats(name: str, xs: list[float]) -> dict[str, float]:
    xs = sorted(xs)
    return {f"{name}_p50": round(statistics.median(xs), 3), f"{name}_p99": round(percentile(xs, 0.99), 3)}


async def in_process(n: int, tmp: Path, *, run: str = "bench-inproc", secure: bool = False) -> dict[str, float]:
    """The world and the agent as two sessions of this process; with `secure`, on the run's own
    credentials (TLS, logins, the world's access control), the agent logged in as alice."""
    cfg = EpisodeConfig.build(horizon=n + 5, start_timeout=3.0, run=run, trace=tmp / f"{run}.jsonl").resolved()
    if secure:
        cfg = cfg.with_credentials(tmp / f"{run}-credentials")
    world = asyncio.create_task(serve_world(cfg))
    try:
        return await _round_trips(cfg.endpoint, cfg.run, n, security=cfg.participant("alice"))
    finally:
        world.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await world


async def cross_process(n: int, tmp: Path) -> dict[str, float]:
    cfg = EpisodeConfig.build(horizon=n + 5, run="bench-xproc", trace=tmp / "x.jsonl").resolved()
    proc = subprocess.Popen([*world_command(cfg), "--start-timeout", "3.0"])
    try:
        await asyncio.to_thread(wait_for_port, cfg.host, cfg.port, 60, proc)
        return await _round_trips(cfg.endpoint, cfg.run, n)
    finally:
        proc.terminate()
        proc.wait(10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=300, help="round trips per mode")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        report = {
            "bench": "action_round_trip_wait",
            "in_process": asyncio.run(in_process(args.n, Path(d))),
            "cross_process": asyncio.run(cross_process(args.n, Path(d))),
        }
    emit(report, args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
