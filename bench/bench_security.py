"""The action round trip (request -> ack -> result for `wait`) on the open tcp bus beside
the secured one (TLS links, a login per participant, the world's access control), measured in
the same run, in-process (the world and the agent are two Zenoh sessions of this process).
Runs bench_bus's in-process round trip twice. Then a small heuristic evaluation (`evaluate`,
two local workers) open beside secured (TLS, the workers' login), alternating, best of
--rounds. Prints JSON (or writes it with --out).

    python bench/bench_security.py [--n 300] [--eval-trials 4] [--rounds 2] [--out bench/results/security.json]
"""

from __future__ import annotations

import argparse
import asyncio
import tempfile
import time
from pathlib import Path

import bench_bus
from report import emit


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=300, help="round trips per mode")
    ap.add_argument("--eval-trials", type=int, default=4, help="episodes of the evaluation (pack_objects, kitchen, 3 objects)")
    ap.add_argument("--rounds", type=int, default=2, help="evaluations per mode, alternating; the best counts")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        report = {
            "bench": "action_round_trip_wait_security",
            "open_tcp": asyncio.run(bench_bus.in_process(args.n, Path(d), run="bench-open")),
            "tls_usrpwd_acl": asyncio.run(bench_bus.in_process(args.n, Path(d), run="bench-secure", secure=True)),
            "eval": evaluation(args.eval_trials, args.rounds, Path(d)),
        }
    emit(report, args.out)


def evaluation(trials: int, rounds: int, tmp: Path) -> dict[str, object]:
    """Wall seconds of one small evaluation with two local workers, open and secured."""
    from mhrc.evaluation import EvalSpec, evaluate

    spec = EvalSpec(tasks=("pack_objects",), scenes=("kitchen",), objects=(3,), trials=trials)
    walls: dict[str, list[float]] = {"open_tcp": [], "tls_login": []}
    for r in range(rounds):
        for mode in walls:
            t0 = time.perf_counter()
            rows = asyncio.run(evaluate(spec, tmp / f"eval-{mode}-{r}", workers=2, secure=mode == "tls_login"))
            walls[mode].append(round(time.perf_counter() - t0, 2))
            assert len(rows) == trials and all(row["success"] for row in rows), rows
    best = {m: min(w) for m, w in walls.items()}
    return {"episodes": trials, "workers": 2, "wall_s": walls, "best_s": best, "secured_over_open": round(best["tls_login"] / best["open_tcp"], 3)}


if __name__ == "__main__":
    main()
