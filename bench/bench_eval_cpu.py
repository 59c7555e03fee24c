"""The evaluation's own CPU beside the simulator's (issue 46 item 2): the eval's main process and its
workers, this tree beside a baseline tree, and whether both trees write the same files.

Each run is `mhrc eval --workers W` over the same grid in a fresh interpreter with PYTHONPATH set to the
tree, the trees taking turns (the next round in the other order). Per run: the main process's CPU
(its getrusage, imports and the summaries included) and its workers' (the children it waited for).
Then the driver's work per episode alone, in one process per tree (three times, in turns), over the same
traces (the first baseline run's), the best of nine passes: `score` (the trace read and decoded, metrics, diagnostics)
and `write_episode_report` (the HTML report), as the engine calls them.

Identity: every tree's episodes.jsonl (every field but wall_time and worker), summary.md, .csv and
.html and every episode's report HTML against the first baseline run's, after blanking what two
runs of one tree differ in anyway: the directory's path, wall times, and the random goal, run and
agent ids.

    git worktree add --detach /tmp/mhrc-base <commit>
    python bench/bench_eval_cpu.py --baseline /tmp/mhrc-base [--rounds 2] [--workers 2]
                                   [--out bench/results/eval_cpu.json]
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from report import check_tree, commit_of, emit

# runs `mhrc eval` in this interpreter and prints its own CPU and its children's (the workers it waited for)
EVAL = """
import json, resource, sys
import mhrc
from mhrc.cli import main
try:
    main(sys.argv[1:])
except SystemExit as exc:
    if exc.code not in (0, None):
        raise
me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"main_cpu_s": me.ru_utime + me.ru_stime, "workers_cpu_s": kids.ru_utime + kids.ru_stime,
                  "mhrc": mhrc.__file__}))
"""

# the driver's per-episode work over the traces in argv[1] (copied to argv[2]), best of three; prints ms an episode
TAKE = """
import json, shutil, sys, time
from pathlib import Path
import mhrc
from mhrc.eval.scoring import score, write_episode_report
src, dst = Path(sys.argv[1]), Path(sys.argv[2])
dst.mkdir(parents=True, exist_ok=True)
traces = []
for f in sorted(src.glob("*.jsonl")):
    shutil.copy(f, dst / f.name)
    traces.append(dst / f.name)
write_episode_report(score(traces[0]))  # imports and caches, not counted
best = None
for _ in range(3):
    s = r = 0.0
    for t in traces:
        t0 = time.process_time()
        scored = score(t)
        t1 = time.process_time()
        write_episode_report(scored)
        s, r = s + t1 - t0, r + time.process_time() - t1
    best = (s, r) if best is None or s + r < sum(best) else best
n = len(traces)
print(json.dumps({"score_ms": best[0] / n * 1e3, "report_ms": best[1] / n * 1e3, "mhrc": mhrc.__file__}))
"""


def _run(root: Path, args: list[str], cwd: Path) -> dict[str, Any]:
    """`python ARGS` with `root`'s mhrc: the last line of its output, as JSON. The working directory is a
    neutral one: `python -c` and `-m` (the workers) put theirs first on sys.path, before PYTHONPATH."""
    done = subprocess.run(
        [sys.executable, *args],
        env={**os.environ, "PYTHONPATH": str(root)},
        cwd=cwd,
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise SystemExit(f"{root}: {' '.join(args[2:5])} exited {done.returncode}: {done.stderr[-2000:]}")
    out = dict(json.loads(done.stdout.strip().splitlines()[-1]))
    if not Path(out.pop("mhrc")).resolve().is_relative_to(root.resolve()):
        raise SystemExit(f"{root}: the run imported another tree's mhrc")
    return out


def run_eval(root: Path, out: Path, workers: int, extra: list[str]) -> dict[str, Any]:
    args = ["-c", EVAL, "eval", "--workers", str(workers), "--out", str(out), "--log-level", "error", *extra]
    return _run(root, args, out.parent)


def take(root: Path, traces: Path, dst: Path) -> dict[str, float]:
    return _run(root, ["-c", TAKE, str(traces), str(dst)], dst.parent)


def _blank(d: Path, p: Path) -> str:
    """The file with what differs between two runs of one tree blanked (module docstring)."""
    s = p.read_text(encoding="utf-8").replace(str(d), "<DIR>")
    if p.suffix == ".csv":
        rows = list(csv.reader(io.StringIO(s)))
        wall = [i for i, h in enumerate(rows[0]) if "wall" in h] if rows else []
        for r in rows[1:]:
            for i in wall:
                r[i] = "W"
        buf = io.StringIO()
        csv.writer(buf).writerows(rows)
        return buf.getvalue()
    s = re.sub(r"<th>wall_time</th><td>[^<]*</td>", "<th>wall_time</th><td>W</td>", s)
    s = re.sub(r"\b[0-9a-f]{16}\b", "GOAL", s)
    s = re.sub(r"run-[0-9a-f]{8}", "RUN", s)
    return re.sub(r"\b([a-z0-9_]+)-[0-9a-f]{8}\b", r"\1-AGENT", s)


def differences(a: Path, b: Path) -> list[str]:
    """The files of evaluation directory `b` that differ from `a`'s (rows compared without wall_time and worker)."""

    def rows(d: Path) -> dict[str, dict[str, Any]]:
        lines = (d / "episodes.jsonl").read_text(encoding="utf-8").splitlines()
        return {
            r["key"]: {k: v for k, v in r.items() if k not in ("wall_time", "worker")} for r in map(json.loads, lines)
        }

    out = [] if rows(a) == rows(b) else ["episodes.jsonl"]
    files = {p.relative_to(d) for d in (a, b) for p in d.rglob("*") if p.suffix in (".md", ".csv", ".html")}
    for f in sorted(files):
        if not (a / f).is_file() or not (b / f).is_file() or _blank(a, a / f) != _blank(b, b / f):
            out.append(str(f))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", type=Path, required=True, help="the tree to compare with (a git worktree)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--tasks", default=None, help="a smaller grid: mhrc eval's --tasks")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    extra = ["--tasks", args.tasks] if args.tasks else []
    this_root = Path(__file__).resolve().parent.parent
    trees = {"baseline": args.baseline.resolve(), "this": this_root}
    for root in trees.values():
        check_tree(root, "mhrc.eval")
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in trees}
    with tempfile.TemporaryDirectory(prefix="bench-eval-cpu-") as tmp:
        first: Path | None = None
        different: dict[str, list[str]] = {}
        for rnd in range(args.rounds):
            for name in list(trees) if rnd % 2 == 0 else list(trees)[::-1]:
                out = Path(tmp) / f"{name}-{rnd}"
                r = run_eval(trees[name], out, args.workers, extra)
                r["episodes"] = len((out / "episodes.jsonl").read_text().splitlines())
                runs[name].append(r)
                print(f"round {rnd} {name}: {r}", file=sys.stderr)
                if first is None:
                    first = out
                else:
                    different[out.name] = differences(first, out)
        assert first is not None
        timings: dict[str, list[dict[str, float]]] = {name: [] for name in trees}
        for rnd in range(3):  # the trees in turns, as the runs: the machine's load shifts under one timing
            for name in list(trees) if rnd % 2 == 0 else list(trees)[::-1]:
                timings[name].append(take(trees[name], first / "traces", Path(tmp) / f"take-{name}-{rnd}"))
        driver = {name: min(t, key=lambda d: d["score_ms"] + d["report_ms"]) for name, t in timings.items()}
    episodes = runs["this"][0]["episodes"]

    def per_episode(name: str, field: str) -> float:
        return round(min(r[field] for r in runs[name]) / episodes, 4)

    summary = {
        name: {
            "main_cpu_s_per_episode": per_episode(name, "main_cpu_s"),
            "workers_cpu_s_per_episode": per_episode(name, "workers_cpu_s"),
            "main_cpu_s": [round(r["main_cpu_s"], 2) for r in runs[name]],
            "workers_cpu_s": [round(r["workers_cpu_s"], 2) for r in runs[name]],
            "driver_ms_per_episode": {k: round(v, 1) for k, v in driver[name].items()},
        }
        for name in trees
    }
    report = {
        "bench": "eval_cpu",
        "machine": f"{platform.machine()}, {platform.python_implementation()} {platform.python_version()}, "
        f"{os.cpu_count()} cores",
        "baseline": str(args.baseline),
        "baseline_commit": commit_of(args.baseline),
        "this_commit": commit_of(this_root),
        "grid": f"mhrc eval --workers {args.workers} {' '.join(extra)} (the default grid: 3 tasks x 3 scenes x "
        "objects 3-6), heuristic",
        "episodes": episodes,
        "rounds": args.rounds,
        "summary": summary,
        "identical": all(not d for d in different.values()),
        "different": {k: v for k, v in different.items() if v},
        "note": "CPU per episode: the least of the rounds over the episodes; the main process's includes its "
        "imports and the summaries (once a run), the workers' their start; driver_ms_per_episode: score and "
        "write_episode_report alone, the best of three processes of three passes each over the first baseline run's traces; identical: every "
        "run's rows, summaries and reports against the first baseline run's (see the docstring)",
    }
    emit(report, args.out)


if __name__ == "__main__":
    main()
