"""The test suite's wall time, this tree beside a baseline tree (issue 46 item 5): the fast tier
(`-m "not slow"`) by default, or the whole suite (`--marker ""`), each tree's pytest in turn in this
interpreter's environment with PYTHONPATH set to the tree (its own tests, its own conftest, the
pytest options of its own pyproject and conftest: its xdist workers), CI=true as `.ci/run` sets it.

Per tree: the wall seconds, pytest's exit status and counts line, the tests that failed or erred (its
-ra lines), and its 25 slowest tests (pytest's own `--durations=25`). The static checks and the
package install that `.ci/run` adds are the same for both trees and not timed here.

With `--rounds N` the trees take turns N times, the first of each round alternating (baseline and
this, then this and baseline, ...): a machine whose speed drifts under long load (a shared or
throttled host) then weighs on both alike. Each tree's `wall_s` is the mean of its rounds, `rounds`
lists every round's, and `wall_ratio` is the ratio of the means; the slowest tests and the counts
are those of each tree's last run.

    git worktree add --detach /tmp/mhrc-base <commit>
    python bench/bench_suite.py --baseline /tmp/mhrc-base [--marker "not slow"] [--rounds 1] [--out bench/results/suite_fast.json]
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from report import check_tree, commit_of, emit

ROOT = Path(__file__).resolve().parents[1]
DURATION = re.compile(r"^(?P<s>[0-9.]+)s (?P<phase>call|setup|teardown)\s+(?P<test>\S+)")
# pytest's last line, with or without -q's rule
COUNTS = re.compile(r"(?P<line>\d+ (?:passed|failed)[^=]*?) in [0-9.]+s")


def run_tree(root: Path, marker: str) -> dict[str, Any]:
    check_tree(root)
    argv = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"] + (["-m", marker] if marker else [])
    env = {**os.environ, "PYTHONPATH": str(root), "CI": "true"}
    t0 = time.perf_counter()
    done = subprocess.run(argv, cwd=root, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    lines = done.stdout.splitlines()
    slowest = [
        {"seconds": float(m["s"]), "phase": m["phase"], "test": m["test"]}
        for line in lines
        if (m := DURATION.match(line.strip()))
    ]
    counts = next((m["line"] for line in reversed(lines) if (m := COUNTS.search(line))), None)
    failed = [line.split(" ", 1)[1] for line in lines if line.startswith(("FAILED ", "ERROR "))]  # pytest's -ra lines
    return {
        "commit": commit_of(root),
        "wall_s": round(wall, 1),
        "exit": done.returncode,
        "counts": counts,
        "failed": failed,
        "slowest": slowest[:25],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline", type=Path, required=True, help="a checkout of the tree to compare with")
    ap.add_argument("--marker", default="not slow", help='pytest -m expression ("" for the whole suite)')
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--rounds", type=int, default=1, help="turns of the two trees, the first of each alternating")
    args = ap.parse_args()
    if args.rounds < 1:
        ap.error("--rounds: at least 1")
    trees = {"baseline": args.baseline.resolve(), "this": ROOT}
    runs: dict[str, list[dict[str, Any]]] = {"baseline": [], "this": []}
    for r in range(args.rounds):
        for name in ("baseline", "this") if r % 2 == 0 else ("this", "baseline"):
            runs[name].append(run_tree(trees[name], args.marker))
            print(f"round {r + 1}: {name} {runs[name][-1]['wall_s']} s", file=sys.stderr)
    result = {
        name: {**done[-1], "wall_s": round(sum(d["wall_s"] for d in done) / len(done), 1)}
        for name, done in runs.items()
    }
    emit(
        {
            "bench": "suite",
            "machine": f"{platform.machine()}, CPython {platform.python_version()}, {os.cpu_count()} cores",
            "tier": f'-m "{args.marker}"' if args.marker else "the whole suite",
            "baseline": result["baseline"],
            "this": result["this"],
            "rounds": [{name: runs[name][r]["wall_s"] for name in runs} for r in range(args.rounds)],
            "wall_ratio": round(result["this"]["wall_s"] / result["baseline"]["wall_s"], 3),
            "note": "wall seconds of each tree's pytest (its own xdist workers, CI=true), the trees in turn on a "
            "machine otherwise quiet (the mean of the rounds, the first of each round alternating); the static checks "
            "and install of .ci/run are not timed; slowest: pytest's --durations=25 of each tree's last run",
        },
        args.out,
    )


if __name__ == "__main__":
    main()
