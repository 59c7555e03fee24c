"""Teams (issue 33): the heuristic team on the evaluation's default grid for every shipped team, in
one run (Succ, TS, its lower bound TS*, AS, messages, redundant actions, each robot's share of the
objects moved, wall time), and the bus round trip of an action (request -> result, `wait`) with
the 8 robots of `full_house` attached beside the paper's 3, measured in the same run.

    python bench/bench_teams.py [--teams paper,two_fetchers,...] [--trials 1] [--workers 2] [--n 100]
                                [--out bench/results/teams.json]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench_bus import attach
from report import emit, percentile

from mhrc.core.bus import Bus, Sample, open_client
from mhrc.core.keys import Keys
from mhrc.core.protocol import ActionRequest, ActionResult, Wait, decode
from mhrc.core.team import TeamSpec
from mhrc.eval.engine import EvalSpec, evaluate
from mhrc.eval.means import summarize
from mhrc.eval.paper import PAPER_OBJECTS
from mhrc.eval.records import EvalRow
from mhrc.run.config import EpisodeConfig
from mhrc.run.serve import serve_world
from mhrc.world.scene import LAYOUTS
from mhrc.world.tasks import TASKS
from mhrc.world.teams import SHIPPED


def _team_row(rows: list[EvalRow], wall: float) -> dict[str, Any]:
    s = summarize([r.metrics for r in rows])
    moved: dict[str, int] = {}
    for r in rows:
        for robot, n in (r.metrics.moves_per_robot or {}).items():
            moved[robot] = moved.get(robot, 0) + n
    total = sum(moved.values())
    return {
        "episodes": len(rows),
        "succ": s.get("succ"),
        "ts": s.get("ts"),
        "ts_bound": s.get("ts_bound"),
        "as": s.get("as"),
        "as_per_robot": s.get("as_per_robot"),
        "makespan_s": s.get("makespan"),
        "messages": round(statistics.mean(r.metrics.messages for r in rows), 2),
        "communication_steps": round(statistics.mean(r.metrics.communication_steps or 0 for r in rows), 2),
        "redundant": round(
            statistics.mean((r.metrics.redundant_navigations or 0) + (r.metrics.redundant_picks or 0) for r in rows), 2
        ),
        "share": {robot: round(n / total, 3) for robot, n in moved.items()} if total else {},
        "unsolved": sorted(r.key for r in rows if not r.metrics.success),
        "wall_s": round(wall, 1),
    }


async def grid(teams: list[TeamSpec], trials: int, workers: int, tmp: Path) -> dict[str, Any]:
    """Every team on the default grid (3 tasks x 3 scenes x the paper's object counts), one
    evaluation per team so that each team's wall time is its own."""
    out: dict[str, Any] = {}
    for team in teams:
        spec = EvalSpec(tasks=tuple(TASKS), scenes=tuple(LAYOUTS), objects=PAPER_OBJECTS, trials=trials, teams=(team,))
        t0 = time.perf_counter()
        rows = await evaluate(spec, tmp / team.name, workers=workers)
        out[team.name] = {"robots": team.kinds, **_team_row(rows, time.perf_counter() - t0)}
    return out


def _into(q: asyncio.Queue[ActionResult]) -> Callable[[Sample], None]:
    return lambda sample: q.put_nowait(decode(sample.payload, ActionResult))


async def round_trips(team: TeamSpec, n: int, tmp: Path) -> dict[str, float]:
    """Every robot of `team` attached on a session of its own, each sending `wait` every tick of
    a lockstep world: the time from a robot's request to its result (the tick closes when all
    have acted), p50 and p99 over every robot and tick."""
    cfg = EpisodeConfig.build(
        team=team, horizon=n + 5, start_timeout=30.0, run=f"bench-{team.name}", trace=tmp / f"{team.name}.jsonl"
    ).resolved()
    world = asyncio.create_task(serve_world(cfg))
    buses = [await open_client(cfg.endpoint, 60.0) for _ in team.robots]
    try:
        keys = Keys(cfg.run)
        results: dict[str, asyncio.Queue[ActionResult]] = {r: asyncio.Queue() for r in team.names}
        for bus, robot in zip(buses, team.names, strict=True):
            bus.subscribe(keys.action_result(robot), _into(results[robot]))
        ticks = [(await attach(bus, keys, robot)).tick for bus, robot in zip(buses, team.names, strict=True)]
        tick = max(ticks)
        times: list[float] = []

        async def act(bus: Bus, robot: str, tick: int) -> float:
            t0 = time.perf_counter()
            bus.put(
                keys.action_request(robot),
                ActionRequest(robot=robot, agent_id=f"bench-{robot}", tick=tick, action=Wait()),
            )
            while (await asyncio.wait_for(results[robot].get(), 30)).tick != tick:
                pass
            return (time.perf_counter() - t0) * 1e3

        for _ in range(n):
            times += await asyncio.gather(*(act(b, r, tick) for b, r in zip(buses, team.names, strict=True)))
            tick += 1
        times.sort()
        return {
            "robots": len(team.robots),
            "result_ms_p50": round(statistics.median(times), 3),
            "result_ms_p99": round(percentile(times, 0.99), 3),
            "n": len(times),
        }
    finally:
        for bus in buses:
            await bus.close()
        world.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await world


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--teams", default=",".join(SHIPPED), help="comma-separated shipped teams (default: all)")
    ap.add_argument("--trials", type=int, default=1, help="episodes per cell of the grid")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--n", type=int, default=100, help="lockstep ticks of the round-trip measure")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    teams = [SHIPPED[name] for name in args.teams.split(",")]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        report = {
            "bench": "teams",
            "policy": "heuristic",
            "grid": f"{len(TASKS)} tasks x {len(LAYOUTS)} scenes x objects {PAPER_OBJECTS} x {args.trials} trial(s), "
            "horizon 50, schedule sequential (mhrc eval's defaults)",
            "note": "ts_bound: world/bound.py's lower bound on TS; redundant: redundant navigations + picks per "
            "episode (mhrc/analysis/teamwork.py); share: each robot's part of the objects picked and placed",
            "teams": asyncio.run(grid(teams, args.trials, args.workers, tmp)),
            "round_trip": {
                "paper": asyncio.run(round_trips(SHIPPED["paper"], args.n, tmp)),
                "full_house": asyncio.run(round_trips(SHIPPED["full_house"], args.n, tmp)),
            },
        }
    emit(report, args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
