"""Start-up (issue 46 item 4): the wall time of `mhrc --help`, a command's --help and refused command
lines, in this tree and in a baseline tree measured in the same run, turn about (baseline, this
tree, baseline, ...), the best of `--repeats` each; and which heavy modules each imports.

    git worktree add /tmp/mhrc-base <commit>
    python bench/bench_startup.py --baseline /tmp/mhrc-base [--repeats 15] [--out bench/results/startup.json]

Each run is `python -m mhrc ARGS` in a fresh interpreter with PYTHONPATH set to the tree, so the
same installed dependencies serve both. A bare `python -c pass` is measured too: the floor.

The one-tick `mhrc up` is timed twice: as the environment runs it (where PYTHONDONTWRITEBYTECODE is
set, as in this project's sandbox, every module of the tree is compiled anew at each run), and with
a bytecode cache, as an installed package or a checkout run once before has one: each tree's own
cache in a temporary directory (PYTHONPYCACHEPREFIX), filled by one untimed run, the trees untouched.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from report import emit

HERE = Path(__file__).resolve().parents[1]
LINES = [
    ["--help"],
    ["up", "--help"],
    ["eval", "--help"],
    ["upp"],
    ["up", "--horizn", "3"],
    ["up", "--task", "pack_objetcs"],
    ["up", "--team", "ful_house"],
    ["eval", "--schedule", "lockstp"],
    ["agent", "--robot", "bob", "--connect", "tcp/127.0.0.1:9", "--team", "larg"],
]
# refused for a value checked against the world's data, past the names: timed with a bytecode cache, as an
# installed package runs (they import far more of the tree than a typo, so compiling it would be most of the time)
VALUE_LINES = [
    ["eval", "--trials", "0"],
    ["up", "--objects", "9"],
    ["up", "--team", "alice=mobile_manipulator,david=mobile_base"],
]
# `mhrc up` to the end of a one-tick episode (imports, the scene, the bus, the agents' attach, the tick):
# its start-up, as a person waits for it; a trace in a temporary directory, the open bus, no credentials
UP = ["up", "--horizon", "1", "--quiet", "--insecure", "--overwrite"]
HEAVY = ("structlog", "pydantic", "cryptography", "asyncio", "zenoh", "pybullet", "ompl", "numpy", "httpx")
PROBE = """
import json, runpy, sys
sys.argv = ["mhrc", *sys.argv[1:]]
try:
    runpy.run_module("mhrc", run_name="__main__")
except SystemExit:
    pass
sys.stderr.write("\\nHEAVY " + json.dumps(sorted(m for m in %r if m in sys.modules)) + "\\n")
"""


def _env(tree: Path, cache: Path | None = None) -> dict[str, str]:
    """The environment of a run of `tree`; with `cache`, bytecode written to and read from that tree's
    own directory under it (the trees are not written to)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    if cache is not None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(cache / ("baseline" if tree != HERE else "this"))
    return env


def _once(tree: Path, args: list[str], cache: Path | None = None) -> float:
    started = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "mhrc", *args], env=_env(tree, cache), capture_output=True, cwd=tree, check=False
    )
    return time.perf_counter() - started


def _heavy(tree: Path, args: list[str]) -> list[str]:
    done = subprocess.run(
        [sys.executable, "-c", PROBE % (HEAVY,), *args], env=_env(tree), capture_output=True, text=True, cwd=tree
    )
    line = [ln for ln in done.stderr.splitlines() if ln.startswith("HEAVY ")][-1]
    return list(json.loads(line[len("HEAVY ") :]))


def _timed(base: Path, line: list[str], command: str, repeats: int, cache: Path | None = None) -> dict[str, Any]:
    """`line`'s best wall time over `repeats` in the baseline and in this tree, the two in turn
    (with `cache`, each tree's bytecode cache under it, filled by a first run that is not timed)."""
    best = {"baseline": float("inf"), "this": float("inf")}
    if cache is not None:
        _once(base, line, cache)
        _once(HERE, line, cache)
    for _ in range(repeats):
        best["baseline"] = min(best["baseline"], _once(base, line, cache))
        best["this"] = min(best["this"], _once(HERE, line, cache))
    row = {
        "command": command,
        "baseline_s": round(best["baseline"], 3),
        "this_s": round(best["this"], 3),
        "speedup": round(best["baseline"] / best["this"], 2),
    }
    print(f"{command}: {row['baseline_s']} s -> {row['this_s']} s", file=sys.stderr)
    return row


def _floor(repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        best = min(best, time.perf_counter() - started)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", type=Path, required=True, help="a checkout of the commit to compare with")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--up-repeats", type=int, default=5, help="repeats of the one-tick `mhrc up`")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    base = args.baseline.resolve()
    if not (base / "mhrc" / "__init__.py").exists():
        ap.error(f"--baseline: {base} is not a checkout of mhrc")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=base, capture_output=True, text=True).stdout
    ours = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True, text=True).stdout
    rows: list[dict[str, Any]] = []
    for line in LINES:
        rows.append(
            _timed(base, line, "mhrc " + " ".join(line), args.repeats)
            | {"baseline_imports": _heavy(base, line), "this_imports": _heavy(HERE, line)}
        )
    with tempfile.TemporaryDirectory() as tmp:
        for line in VALUE_LINES:
            rows.append(
                _timed(base, line, "mhrc " + " ".join(line) + " (bytecode cached)", args.repeats, Path(tmp))
                | {"baseline_imports": _heavy(base, line), "this_imports": _heavy(HERE, line)}
            )
        line = [*UP, "--trace", str(Path(tmp) / "trace.jsonl")]
        rows.append(_timed(base, line, "mhrc " + " ".join(UP) + " --trace TMP", args.up_repeats))
        rows.append(
            _timed(base, line, "mhrc " + " ".join(UP) + " --trace TMP (bytecode cached)", args.up_repeats, Path(tmp))
        )
    emit(
        {
            "bench": "startup",
            "baseline": commit.strip(),
            "this": ours.strip(),
            "repeats": args.repeats,
            "python_floor_s": round(_floor(args.repeats), 3),
            "rows": rows,
            "note": "best wall time of `python -m mhrc ARGS` over the repeats, the two trees in turn; imports: the "
            "heavy modules in sys.modules when the command line was refused or its help printed; (bytecode cached): "
            "each tree's .pyc in a temporary PYTHONPYCACHEPREFIX filled by one untimed run, as an installed package "
            "has them (without it, with PYTHONDONTWRITEBYTECODE set, each run compiles the tree's modules anew)",
        },
        args.out,
    )


if __name__ == "__main__":
    main()
