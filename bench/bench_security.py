"""The action round trip (request -> ack -> result for `wait`) on the open tcp bus beside
the secured one (TLS links, a login per participant, the world's access control), measured in
the same run, in-process (the world and the agent are two Zenoh sessions of this process).
Runs bench_bus's in-process round trip twice. (`mhrc eval` has no bus of its own any more:
its local workers are child processes, and Ray guards a cluster with its token.) Prints JSON
(or writes it with --out).

    python bench/bench_security.py [--n 300] [--out bench/results/security.json]
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
from pathlib import Path

import bench_bus
from report import emit


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=300, help="round trips per mode")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        report = {
            "bench": "action_round_trip_wait_security",
            "open_tcp": asyncio.run(bench_bus.in_process(args.n, Path(d), run="bench-open")),
            "tls_usrpwd_acl": asyncio.run(bench_bus.in_process(args.n, Path(d), run="bench-secure", secure=True)),
        }
    emit(report, args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
