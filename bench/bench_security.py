"""The action round trip (request -> ack -> result for `wait`) on the open tcp bus beside
the secured one (TLS links, a login per participant, the world's access control), measured in
the same run, in-process (the world and the agent are two Zenoh sessions of this process).
Reuses bench_bus's round-trip loop. Prints JSON (or writes it with --out).

    python bench/bench_security.py [--n 300] [--out bench/results/security.json]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import tempfile
from pathlib import Path

import bench_bus
from report import emit

from mhrc.episode import EpisodeConfig, open_client, serve_world


async def one(n: int, tmp: Path, secure: bool) -> dict[str, float]:
    run = "bench-secure" if secure else "bench-open"
    cfg = EpisodeConfig.build(horizon=n + 5, start_timeout=0.5, run=run, trace=tmp / f"{run}.jsonl").resolved()
    if secure:
        cfg = cfg.with_credentials(tmp / "credentials")
    creds = cfg.participant("alice")

    async def login(endpoint: str, timeout: float):  # type: ignore[no-untyped-def]
        return await open_client(endpoint, timeout, security=creds)  # bench_bus's client, logged in as alice

    world = asyncio.create_task(serve_world(cfg))
    bench_bus.open_client = login  # type: ignore[assignment]
    try:
        return await bench_bus._round_trips(cfg.endpoint, cfg.run, n)
    finally:
        bench_bus.open_client = open_client
        world.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await world


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=300, help="round trips per mode")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        report = {
            "bench": "action_round_trip_wait_security",
            "open_tcp": asyncio.run(one(args.n, Path(d), secure=False)),
            "tls_usrpwd_acl": asyncio.run(one(args.n, Path(d), secure=True)),
        }
    emit(report, args.out)


if __name__ == "__main__":
    main()
