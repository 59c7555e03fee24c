"""The grid's wall time and CPU, this tree beside a baseline tree, as a user runs it (issue 46 item 2).

Each run is `python -m mhrc eval` over the same grid in a fresh interpreter, with PYTHONPATH set to
the tree (the same installed dependencies serve both), the trees taking turns (baseline, this,
this with one worker; the next round in the other order), so that both see the same machine.
Per run: the wall time, the CPU of the eval and its worker processes (getrusage of the children)
and every episode's row; the report says whether both trees gave every episode the same TS, AS,
placed, messages and success, and gives this tree's wall time with 1 and with 2 workers.

    git worktree add /tmp/mhrc-base <commit>
    python bench/bench_grid_speed.py --baseline /tmp/mhrc-base [--trials 1] [--workers 2] [--rounds 1]
                                     [--out bench/results/grid_speed.json]

`--trials 1` is the evaluation's default grid (36 episodes: 3 tasks x 3 scenes x 3-6 objects);
`--trials 10` the paper's 360-episode grid (bench/bench_grid.py's `paper` run).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from report import check_tree, commit_of, emit

SAME = ("success", "temporal_steps", "action_steps", "placed", "messages")


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def run_eval(root: Path, trials: int, workers: int, tmp: Path, extra: list[str]) -> dict[str, Any]:
    """One `mhrc eval` of the grid with `root`'s mhrc: wall, CPU and the rows by key."""
    out = tmp / f"eval-{time.monotonic_ns()}"
    cmd = [sys.executable, "-m", "mhrc", "eval", "--trials", str(trials), "--workers", str(workers), *extra]
    cmd += ["--out", str(out), "--log-level", "error"]
    cpu0, t0 = _children_cpu(), time.perf_counter()
    done = subprocess.run(
        cmd, env={**os.environ, "PYTHONPATH": str(root)}, cwd=tmp, capture_output=True, text=True, check=False
    )
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    if done.returncode != 0:
        raise SystemExit(f"{root}: mhrc eval exited {done.returncode}: {done.stderr[-2000:]}")
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines() if line.strip()]
    return {
        "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2),
        "episodes": len(rows),
        "rows": {r["key"]: {k: r.get(k) for k in SAME} for r in rows},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", type=Path, required=True, help="the tree to compare with (a git worktree)")
    ap.add_argument("--trials", type=int, default=1, help="1: the default grid (36 episodes); 10: the paper's 360")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument(
        "--one-worker", action=argparse.BooleanOptionalAction, default=True, help="also this tree with 1 worker"
    )
    ap.add_argument("--tasks", default=None, help="a smaller grid: mhrc eval's --tasks")
    ap.add_argument("--scenes", default=None, help="a smaller grid: mhrc eval's --scenes")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    extra = [*(["--tasks", args.tasks] if args.tasks else []), *(["--scenes", args.scenes] if args.scenes else [])]
    this_root = Path(__file__).resolve().parent.parent
    for root in (args.baseline, this_root):
        check_tree(root, "mhrc.eval")
    runs: dict[str, list[dict[str, Any]]] = {"baseline": [], "this": [], "this_1_worker": []}
    plan = [
        ("baseline", args.baseline, args.workers),
        ("this", this_root, args.workers),
        *([("this_1_worker", this_root, 1)] if args.one_worker else []),
    ]
    with tempfile.TemporaryDirectory(prefix="bench-grid-speed-") as tmp:
        for rnd in range(args.rounds):
            for name, root, workers in plan if rnd % 2 == 0 else plan[::-1]:
                r = run_eval(root, args.trials, workers, Path(tmp), extra)
                runs[name].append(r)
                print(
                    f"round {rnd} {name}: {r['episodes']} episodes, {r['wall_s']} s wall, {r['cpu_s']} CPU-s",
                    file=sys.stderr,
                )
    base_rows, this_rows = runs["baseline"][0]["rows"], runs["this"][0]["rows"]
    different = sorted(k for k in base_rows if base_rows[k] != this_rows.get(k))
    one_worker_rows = runs["this_1_worker"][0]["rows"] if runs["this_1_worker"] else None

    def best(name: str, field: str) -> float:
        return min(r[field] for r in runs[name])

    episodes = runs["this"][0]["episodes"]
    summary = {
        name: {
            "wall_s": best(name, "wall_s"),
            "cpu_s": best(name, "cpu_s"),
            "cpu_s_per_episode": round(best(name, "cpu_s") / episodes, 3),
            "walls": [r["wall_s"] for r in runs[name]],
        }
        for name in runs
        if runs[name]
    }
    report = {
        "bench": "grid_speed",
        "machine": f"{platform.machine()}, {platform.python_implementation()} {platform.python_version()}, "
        f"{os.cpu_count()} cores",
        "baseline": str(args.baseline),
        "baseline_commit": commit_of(args.baseline),
        "this_commit": commit_of(this_root),
        "grid": f"mhrc eval --trials {args.trials} {' '.join(extra)} (by default 3 tasks x 3 scenes x objects 3-6 "
        f"x {args.trials} trial(s)), heuristic, the defaults otherwise",
        "episodes": episodes,
        "workers": args.workers,
        "rounds": args.rounds,
        "summary": summary,
        "wall_speedup": round(summary["baseline"]["wall_s"] / summary["this"]["wall_s"], 2),
        "cpu_speedup": round(summary["baseline"]["cpu_s"] / summary["this"]["cpu_s"], 2),
        "two_workers_over_one": round(summary["this_1_worker"]["wall_s"] / summary["this"]["wall_s"], 2)
        if "this_1_worker" in summary
        else None,
        "episodes_identical": f"{episodes - len(different)}/{episodes}",
        "different": different,
        "one_worker_identical": None if one_worker_rows is None else one_worker_rows == this_rows,
        "mean_ts": round(statistics.mean(r["temporal_steps"] for r in this_rows.values()), 3),
        "note": "wall and CPU: the best of the rounds; CPU is the eval's and its workers' (children's getrusage); "
        "identical: the same success, TS, AS, placed and messages for every episode key",
    }
    emit(report, args.out)


if __name__ == "__main__":
    main()
