"""What a live Rerun recording costs an episode (`mhrc up --rerun OUT.rrd`, mhrc.viewer.rerun.live).

Runs the same heuristic episode in-process again and again, alternating without and with a live
recording to an .rrd file, and reports for each side the median of: the whole run's wall time
(scene built to everything closed), the episode's own (`wall_time` of its metrics: start to end),
and the CPU time of the episode's process (the world, the agents and, with a recording, the
hand-over of each sample to the logging process); then the time the recording takes to close once
the episode is over, the samples it logged and dropped, and the deepest its queue got. Last, the
same trace made into a recording afterwards (`mhrc show --rerun`), for comparison. Both sides are
measured in the same run. Prints JSON (and writes it with --out).

    python bench/bench_rerun.py [--repeats 7] [--objects 6] [--out bench/results/rerun.json]
"""

from __future__ import annotations

import argparse
import asyncio
import platform
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from report import emit

from mhrc.core import logs
from mhrc.core.team import PAPER_TEAM
from mhrc.run.config import EpisodeConfig
from mhrc.run.teams import resolve_team
from mhrc.viewer.rerun import Mode, Target
from mhrc.viewer.rerun.live import LiveRecording
from mhrc.viewer.rerun.record import write_recording


def one(cfg: EpisodeConfig, out: Path | None) -> dict[str, Any]:
    """One episode, with a live recording to `out` or without; its wall time and the recording's figures."""
    from mhrc.run.inprocess import up_in_process

    live = LiveRecording(Target(Mode.FILE, out), cfg.run) if out is not None else None
    t0, c0 = time.perf_counter(), time.process_time()
    done = asyncio.run(up_in_process(cfg, observe=None if live is None else live.observe))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    row: dict[str, Any] = {
        "cpu_s": cpu,
        "wall_s": wall,
        "episode_s": done.metrics.wall_time,
        "temporal_steps": done.metrics.temporal_steps,
    }
    if live is not None:
        t1 = time.perf_counter()
        stats = live.close()
        row.update(
            close_s=time.perf_counter() - t1,
            logged=stats.logged,
            dropped=stats.dropped,
            max_queue=stats.max_depth,
            bytes=out.stat().st_size if out is not None else 0,
        )
    return row


def team_case(name: str, team: str, args: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    spec = PAPER_TEAM if team == "paper" else resolve_team(team)
    without: list[dict[str, Any]] = []
    with_: list[dict[str, Any]] = []
    trace = tmp / f"{name}.jsonl"
    for i in range(args.repeats):
        for recording in (False, True):  # alternated: the machine's drift falls on both sides alike
            cfg = EpisodeConfig.build(
                seed=args.seed, n_objects=args.objects, horizon=args.horizon, team=spec, trace=trace
            ).resolved()
            (with_ if recording else without).append(one(cfg, tmp / f"{name}_{i}.rrd" if recording else None))
    t0 = time.perf_counter()
    written = write_recording(trace, Target(Mode.FILE, tmp / f"{name}_from_trace.rrd"))
    from_trace_s = time.perf_counter() - t0
    base = statistics.median(r["wall_s"] for r in without)
    live = statistics.median(r["wall_s"] for r in with_)
    base_episode = statistics.median(r["episode_s"] for r in without)
    live_episode = statistics.median(r["episode_s"] for r in with_)
    return {
        "team": team,
        "robots": len(spec.robots),
        "temporal_steps": without[0]["temporal_steps"],
        "without_s": round(base, 4),
        "with_s": round(live, 4),
        "overhead_pct": round(100 * (live - base) / base, 1),
        "episode_without_s": round(base_episode, 4),
        "episode_with_s": round(live_episode, 4),
        "episode_overhead_pct": round(100 * (live_episode - base_episode) / base_episode, 1),
        "cpu_without_s": round(statistics.median(r["cpu_s"] for r in without), 4),
        "cpu_with_s": round(statistics.median(r["cpu_s"] for r in with_), 4),
        "close_s": round(statistics.median(r["close_s"] for r in with_), 4),
        "logged": with_[-1]["logged"],
        "dropped": max(r["dropped"] for r in with_),
        "max_queue": max(r["max_queue"] for r in with_),
        "rrd_kb": round(with_[-1]["bytes"] / 1024, 1),
        "from_trace_s": round(from_trace_s, 4),
        "from_trace_records": written.records,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--objects", type=int, default=6)
    ap.add_argument("--horizon", type=int, default=50)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    logs.configure("warning")
    with tempfile.TemporaryDirectory(prefix="bench_rerun_") as tmp:
        runs = {
            name: team_case(name, team, args, Path(tmp)) for name, team in (("paper", "paper"), ("eight", "full_house"))
        }
    emit(
        {
            "benchmark": "rerun",
            "machine": {"python": platform.python_version(), "cpu": platform.processor() or platform.machine()},
            "episode": {"task": "pack_objects", "scene": "kitchen", "seed": args.seed, "n_objects": args.objects},
            "repeats": args.repeats,
            "runs": runs,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
