"""Action round trip over the bus, excluding skill time: request -> ack -> result for `wait`.

The paper's three robots attach, each on a session of its own, and all wait each tick; the
round trip is alice's. In-process: the world and the agents are separate Zenoh sessions in
this process. Cross-process: the world runs as
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
from collections.abc import Callable
from pathlib import Path

from report import emit, percentile

from mhrc.core.bus import Bus, open_client
from mhrc.core.keys import Keys
from mhrc.core.protocol import (
    ActionAck,
    ActionRequest,
    ActionResult,
    AttachReply,
    AttachRequest,
    EpisodeStarted,
    Wait,
    decode,
    decode_event,
)
from mhrc.core.security import Credentials
from mhrc.run.config import ROBOTS, EpisodeConfig
from mhrc.run.processes import wait_for_port, world_command
from mhrc.run.serve import serve_world


async def attach(bus: Bus, keys: Keys, robot: str) -> AttachReply:
    """`robot` attached on `bus` (retrying while the world starts), its liveliness token declared."""
    for _ in range(300):
        got = await bus.get(keys.attach(robot), AttachRequest(robot=robot, agent_id=f"bench-{robot}"))
        if got:
            reply = decode(got[0], AttachReply)
            assert reply.accepted, reply.reason
            bus.declare_token(keys.alive_robot(robot))
            return reply
        await asyncio.sleep(0.1)
    raise TimeoutError(f"{robot} could not attach")


async def _round_trips(
    endpoint: str, run: str, n: int, login: Callable[[str], Credentials | None] = lambda _robot: None
) -> dict[str, float]:
    """`n` ticks of the whole paper team waiting; the round trip is alice's. Every robot attaches,
    so the world starts at once (no start timeout to wait out or to miss under load)."""
    k = Keys(run)
    buses: list[Bus] = []
    try:
        for robot in ROBOTS:  # a session each, logged in as itself
            buses.append(await open_client(endpoint, 30.0, security=login(robot)))
        alice = buses[0]  # hears the world's start, and her acks and results
        started = asyncio.Event()
        alice.subscribe(
            k.world_event, lambda s: started.set() if isinstance(decode_event(s.payload), EpisodeStarted) else None
        )
        acks: asyncio.Queue[ActionAck] = asyncio.Queue()
        results: asyncio.Queue[ActionResult] = asyncio.Queue()
        alice.subscribe(k.action_ack(ROBOTS[0]), lambda s: acks.put_nowait(decode(s.payload, ActionAck)))
        alice.subscribe(k.action_result(ROBOTS[0]), lambda s: results.put_nowait(decode(s.payload, ActionResult)))
        replies = [await attach(bus, k, robot) for bus, robot in zip(buses, ROBOTS, strict=True)]  # the last starts it
        await asyncio.wait_for(started.wait(), 60)
        tick, ack_ms, res_ms = replies[0].tick, [], []
        for _ in range(n):
            t0 = time.perf_counter()
            for robot, bus in zip(ROBOTS, buses, strict=True):
                bus.put(
                    k.action_request(robot),
                    ActionRequest(robot=robot, agent_id=f"bench-{robot}", tick=tick, action=Wait()),
                )
            ack = await asyncio.wait_for(acks.get(), 10)
            t1 = time.perf_counter()
            res = await asyncio.wait_for(results.get(), 10)
            t2 = time.perf_counter()
            assert ack.accepted, ack.reason
            tick = res.tick + 1
            ack_ms.append((t1 - t0) * 1e3)
            res_ms.append((t2 - t0) * 1e3)
        return {**_stats("ack_ms", ack_ms), **_stats("result_ms", res_ms), "n": n, "robots": len(ROBOTS)}
    finally:
        for bus in buses:
            await bus.close()


def _stats(name: str, xs: list[float]) -> dict[str, float]:
    xs = sorted(xs)
    return {f"{name}_p50": round(statistics.median(xs), 3), f"{name}_p99": round(percentile(xs, 0.99), 3)}


async def in_process(n: int, tmp: Path, *, run: str = "bench-inproc", secure: bool = False) -> dict[str, float]:
    """The world and the agent as two sessions of this process; with `secure`, on the run's own
    credentials (TLS, logins, the world's access control), the agent logged in as alice."""
    cfg = EpisodeConfig.build(horizon=n + 5, start_timeout=60.0, run=run, trace=tmp / f"{run}.jsonl").resolved()
    if secure:
        cfg = cfg.with_credentials(tmp / f"{run}-credentials")
    world = asyncio.create_task(serve_world(cfg))
    try:
        return await _round_trips(cfg.endpoint, cfg.run, n, login=cfg.participant)
    finally:
        world.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await world


async def cross_process(n: int, tmp: Path) -> dict[str, float]:
    cfg = EpisodeConfig.build(horizon=n + 5, run="bench-xproc", trace=tmp / "x.jsonl").resolved()
    proc = subprocess.Popen([*world_command(cfg), "--start-timeout", "60"])
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
