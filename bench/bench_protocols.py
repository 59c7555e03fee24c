"""Coordination protocols (issue 45): every protocol's heuristic form x every shipped team on the
evaluation's default grid, in one run, the paper's protocol (`mhrc`) measured beside the others:
Succ, TS, TS over its lower bound, AS, messages, makespan (simulated seconds), wall time. With
--out the file is written after each team (`"complete": false` until the last).

    python bench/bench_protocols.py [--protocols mhrc,centralized,leader] [--teams paper,two_fetchers,...]
                                    [--trials 1] [--workers 2] [--schedule sequential]
                                    [--out bench/results/protocols.json]

TS, AS and the rest are deterministic (the same seeds give the same episodes, in every run and on
every machine); wall time is the shared machine's and noisy.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from report import emit

from mhrc.agents.protocols import PROTOCOLS
from mhrc.core.team import TeamSpec
from mhrc.eval.engine import EvalSpec, evaluate
from mhrc.eval.means import summarize
from mhrc.eval.paper import PAPER_OBJECTS
from mhrc.eval.records import EvalRow
from mhrc.world.scene import LAYOUTS
from mhrc.world.tasks import TASKS
from mhrc.world.teams import SHIPPED

DEFAULT_TEAMS = ("paper", "two_fetchers", "large", "full_house")


def _row(rows: list[EvalRow], wall: float) -> dict[str, Any]:
    s = summarize([r.metrics for r in rows])
    ts, bound = s.get("ts"), s.get("ts_bound")
    ratios = [r.metrics.temporal_steps / r.metrics.lower_bound for r in rows if r.metrics.lower_bound]
    return {
        "episodes": len(rows),
        "succ": s.get("succ"),
        "ts": ts,
        "ts_bound": bound,
        "ts_over_bound": round(statistics.mean(ratios), 3) if ratios else None,
        "as": s.get("as"),
        "messages": round(statistics.mean(r.metrics.messages for r in rows), 2),
        "makespan_s": s.get("makespan"),
        "unsolved": sorted(r.key for r in rows if not r.metrics.success),
        "wall_s": round(wall, 1),
    }


async def cell(protocol: str, team: TeamSpec, trials: int, workers: int, schedule: str, tmp: Path) -> dict[str, Any]:
    """One protocol with one team on the default grid (3 tasks x 3 scenes x the paper's object counts)."""
    spec = EvalSpec(
        tasks=tuple(TASKS),
        scenes=tuple(LAYOUTS),
        objects=PAPER_OBJECTS,
        trials=trials,
        teams=(team,),
        protocols=(protocol,),  # the evaluation's own axis: every row records it
        schedule=schedule,
    )
    t0 = time.perf_counter()
    rows = await evaluate(spec, tmp / f"{protocol}-{team.name}", workers=workers)
    assert {r.settings.protocol for r in rows} <= {protocol}
    return {"protocol": protocol, "team": team.name, **_row(rows, time.perf_counter() - t0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--protocols", default=",".join(PROTOCOLS), help="comma-separated protocols (default: all)")
    ap.add_argument("--teams", default=",".join(DEFAULT_TEAMS), help="comma-separated shipped teams")
    ap.add_argument("--trials", type=int, default=1, help="episodes per cell of the grid")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--schedule", default="sequential", help="the world's schedule (mhrc eval's default)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    protocols = args.protocols.split(",")
    teams = [SHIPPED[name] for name in args.teams.split(",")]
    out: dict[str, dict[str, Any]] = {p: {} for p in protocols}
    report = {
        "bench": "protocols",
        "policy": "heuristic",
        "grid": f"{len(TASKS)} tasks x {len(LAYOUTS)} scenes x objects {PAPER_OBJECTS} x {args.trials} trial(s), "
        f"horizon 50, schedule {args.schedule}",
        "note": "ts_bound: world/bound.py's lower bound on TS; ts_over_bound: the mean of each episode's TS over its "
        "bound; makespan_s: simulated seconds; TS, AS and messages are deterministic, wall_s is the shared machine's",
        "complete": False,
        "protocols": out,
    }
    with tempfile.TemporaryDirectory() as d:
        for team in teams:  # a team's protocols side by side; with --out, the file grows a team at a time
            for p in protocols:
                out[p][team.name] = asyncio.run(cell(p, team, args.trials, args.workers, args.schedule, Path(d)))
            if args.out:
                args.out.parent.mkdir(parents=True, exist_ok=True)
                args.out.write_text(json.dumps(report, indent=2) + "\n")
    report["complete"] = True
    emit(report, args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
