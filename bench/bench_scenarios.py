"""The heuristic team on dynamic episodes (issue 25): the grid 3 tasks x 3 scenes x objects 3-6 x
seeds 0-9, static and with each shipped scenario (world/scenarios/*.json), all in one run.

Per scenario: Succ, PS, TS and its difference from the static episode over the same episodes
(same task, scene, object count and seed), how many of its events applied, were skipped (and
why) or never fired (the episode ended first), and per event kind the ticks the team took to
resume progress (the rows' `recovery`, mhrc/analysis/metrics.py). `per_kind` is the figure: the TS
cost of each event kind, from the scenario that has only that kind, over all episodes and over
those where the event applied.

    python bench/bench_scenarios.py [--seeds 10] [--objects 3,4,5,6] [--workers 2] [--scenarios relocate,close] [--out bench/results/scenarios.json]
    python bench/bench_scenarios.py --quick     # seed 0, 3 and 6 objects: 18 episodes a scenario, a few minutes
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

from report import emit

from mhrc.core.protocol import ScenarioEvent
from mhrc.core.records import messages, read_records
from mhrc.eval.engine import EvalSpec, evaluate
from mhrc.eval.means import summarize
from mhrc.eval.records import EvalRow
from mhrc.world.scenario import load_scenario, shipped_scenarios
from mhrc.world.scene import LAYOUTS
from mhrc.world.tasks import TASKS

STATIC = "static"


def _episode(row: EvalRow) -> tuple[str, str, int, int]:
    """What makes two rows the same episode but for the scenario."""
    m = row.metrics
    return m.task, m.scene, m.n_objects, m.seed


def _fired(out: Path, rows: list[EvalRow]) -> dict[tuple[str, str, int, int], list[dict[str, Any]]]:
    """The scenario_event payloads of each episode's trace, by episode."""
    fired = {}
    for row in rows:
        events = [e.model_dump(mode="json") for e in messages(read_records(out / str(row.trace)), ScenarioEvent)]
        fired[_episode(row)] = events
    return fired


def _mean(xs: list[float]) -> float | None:
    return round(statistics.fmean(xs), 3) if xs else None


def _scenario_run(
    name: str,
    path: Path,
    rows: list[EvalRow],
    out: Path,
    static: dict[tuple[str, str, int, int], EvalRow],
) -> dict[str, Any]:
    """One scenario's figures against the static rows of the same episodes."""
    spec = load_scenario(path)
    fired = _fired(out, rows)
    events = []
    for i, ev in enumerate(spec.events):
        seen = [e for evs in fired.values() for e in evs if e["index"] == i]
        events.append(
            {
                "index": i,
                "kind": ev.kind,
                "tick": ev.tick,
                "applied": sum(1 for e in seen if e["applied"]),
                "skipped": sum(1 for e in seen if not e["applied"]),
                "not_fired": len(rows) - len(seen),
                "skipped_why": dict(Counter(e["skipped"] for e in seen if not e["applied"])),
            }
        )
    deltas = {
        _episode(r): r.metrics.temporal_steps - static[_episode(r)].metrics.temporal_steps
        for r in rows
        if _episode(r) in static
    }
    per_kind: dict[str, dict[str, Any]] = {}
    for kind in sorted({ev.kind for ev in spec.events}):
        hit = [k for k, evs in fired.items() if any(e["event"] == kind and e["applied"] for e in evs)]
        recovery = [
            float(e["ticks_to_recover"])
            for r in rows
            for e in r.metrics.recovery or []
            if e.get("kind") == kind and e.get("applied") and e.get("ticks_to_recover") is not None
        ]
        unrecovered = sum(
            1
            for r in rows
            for e in r.metrics.recovery or []
            if e.get("kind") == kind and e.get("applied") and e.get("ticks_to_recover") is None
        )
        per_kind[kind] = {
            "applied_in": len(hit),
            "ts_cost_applied": _mean([deltas[k] for k in hit if k in deltas]),
            "recovery_ticks": _mean(recovery),
            "unrecovered": unrecovered,
        }
    solved = [r for r in rows if r.metrics.success]
    return {
        "scenario": name,
        "sha256": spec.sha256,
        "events_text": ", ".join(f"{ev.kind}@{ev.tick}" for ev in spec.events),
        "episodes": len(rows),
        "solved": len(solved),
        "unsolved": sorted(r.key for r in rows if not r.metrics.success),
        "succ": round(len(solved) / len(rows), 4),
        "ts": round(statistics.fmean(r.metrics.temporal_steps for r in rows), 3),
        "ts_static": _mean([static[k].metrics.temporal_steps for k in deltas]),
        "ts_delta": _mean(list(deltas.values())),
        "applied": sum(e["applied"] for e in events),
        "skipped": sum(e["skipped"] for e in events),
        "not_fired": sum(e["not_fired"] for e in events),
        "events": events,
        "per_kind": per_kind,
        "all": summarize([r.metrics for r in rows]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1 per task, scene and object count")
    ap.add_argument("--objects", default="3,4,5,6", help="comma-separated object counts")
    ap.add_argument("--quick", action="store_true", help="a small run: seed 0, objects 3 and 6")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scenarios", default=None, help="comma-separated shipped scenarios; default: all of them")
    ap.add_argument(
        "--schedule", default="sequential", help="the world's schedule (mhrc eval's default, the paper's: sequential)"
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    shipped = shipped_scenarios()
    names = sorted(shipped) if args.scenarios is None else [s.strip() for s in args.scenarios.split(",") if s.strip()]
    unknown = [n for n in names if n not in shipped]
    if unknown:
        ap.error(f"--scenarios: {', '.join(unknown)} not shipped; shipped: {', '.join(sorted(shipped))}")
    seeds, objects = (1, (3, 6)) if args.quick else (args.seeds, tuple(int(n) for n in args.objects.split(",")))
    result: dict[str, Any] = {
        "bench": "scenarios",
        "policy": "heuristic",
        "grid": f"{len(TASKS)} tasks x {len(LAYOUTS)} scenes x objects {','.join(map(str, objects))} x seeds 0-{seeds - 1}, horizon 50",
        "quick": args.quick,
        "workers": args.workers,
        "schedule": args.schedule,
        "runs": {},
        "note": "ts_delta: TS minus the static TS of the same episode (task, scene, objects, seed), averaged; "
        "per_kind.ts_cost_applied: the same over the episodes where that kind's event applied; recovery_ticks: ticks "
        "until progress resumed (mhrc/analysis/metrics.py), over applied events; not_fired: the episode ended before the tick",
    }
    static: dict[tuple[str, str, int, int], EvalRow] = {}
    table = []
    for name in [STATIC, *names]:
        spec = EvalSpec(
            tasks=tuple(TASKS),
            scenes=tuple(LAYOUTS),
            objects=objects,
            trials=seeds,
            schedule=args.schedule,
            events=None if name == STATIC else name,
        )
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "ev"
            t0 = time.perf_counter()
            rows = asyncio.run(evaluate(spec, out, workers=args.workers))
            wall = round(time.perf_counter() - t0, 1)
            if name == STATIC:
                static = {_episode(r): r for r in rows}
                summary = summarize([r.metrics for r in rows])
                run = {
                    "scenario": STATIC,
                    "episodes": len(rows),
                    "solved": sum(1 for r in rows if r.metrics.success),
                    "unsolved": sorted(r.key for r in rows if not r.metrics.success),
                    "succ": summary["succ"],
                    "ts": summary["ts"],
                    "all": summary,
                }
            else:
                run = _scenario_run(name, shipped[name], rows, out, static)
        run["wall_s"] = wall
        result["runs"][name] = run
        table.append(
            {
                k: run.get(k)
                for k in (
                    "scenario",
                    "events_text",
                    "episodes",
                    "succ",
                    "ts",
                    "ts_static",
                    "ts_delta",
                    "applied",
                    "skipped",
                    "not_fired",
                )
            }
        )
    result["table"] = table
    # the figure: TS cost per event kind, from the scenario holding only that kind
    result["per_kind"] = [
        {
            "kind": kind,
            "scenario": name,
            "episodes": run["episodes"],
            "succ": run["succ"],
            "ts_cost": run["ts_delta"],
            **run["per_kind"][kind],
        }
        for name, run in result["runs"].items()
        if name != STATIC and len(run["per_kind"]) == 1
        for kind in run["per_kind"]
    ]
    emit(result, args.out)


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
