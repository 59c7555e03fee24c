"""Where our CPU goes per model call (issue 46 item 3): py-spy samples the LLM grid
(`bench_llm_grid.py`, all episodes at once against a fixed-latency model that answers wait) and
every on-CPU sample is put in one bucket by the first rule its stack matches, in the order of
`BUCKETS`. The stacks are kept (py-spy's raw format, gzipped) beside the shares.

    python bench/profile_llm_calls.py [--latency 0.2] [--horizon 20] [--concurrency 36]
                                      [--out bench/results/llm_call_profile.json]
    python bench/profile_llm_calls.py --stacks FILE.raw.gz   # the shares of stacks sampled before

py-spy samples with `--gil`: only the thread holding the GIL, i.e. running Python. Without it,
py-spy took every thread for active (its idle detection does not see threads waiting in native
code): zenoh-python's callback threads, each blocked in Rust on its channel below `Thread.run`,
and the executor's idle threads made 63% of the worker's samples in an earlier profile, while
their real CPU (bench/bench_llm_client.py reads it per thread from /proc) was a small part. Native
work without the GIL (Zenoh's runtime threads) is not sampled at all: bench_llm_client.py has its
CPU. Shares are of the samples, on a machine that may be shared: read them as where the Python
time goes, not as seconds.
"""

from __future__ import annotations

import argparse
import collections
import gzip
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from report import emit

Rule = Callable[[list[str]], bool]


def _any(*needles: str) -> Rule:
    return lambda frames: any(n in f for f in frames for n in needles)


BUCKETS: list[tuple[str, Rule]] = [
    (
        "a thread in native code under Thread.run (zenoh-python's callback threads)",
        lambda f: f[-1].startswith("Thread.run"),
    ),
    ("world: building the scene", _any("Sim.__init__", "Sim._build", "ArmPlanner.__init__", "mhrc/world/robots.py")),
    ("world: skills", _any("mhrc/world/skills", "mhrc/world/arm.py", "mhrc/world/astar.py")),
    ("writing the summary and reports", _any("matplotlib", "mhrc/eval/html", "mhrc/viewer", "mhrc/eval/report")),
    ("imports", _any("_find_and_load")),
    ("prompt rendering", _any("LLMPolicy.prepare", "LLMPolicy.render", "agents/prompt")),
    (
        "model client (httpx, aiohttp, httpcore, h11, anyio, the LLM client)",
        _any("httpx", "aiohttp", "httpcore", "h11", "anyio", "agents/llm/"),
    ),
    ("the trace (recorder)", _any("recorder", "core/records.py")),
    ("bus, Python side (put, get, decode)", _any("mhrc/core/bus.py")),
    ("pydantic", _any("pydantic")),
    ("world: service, observing", _any("mhrc/world/")),
    ("agents, other", _any("mhrc/agents/")),
    ("asyncio's loop", _any("asyncio")),
]
WORKER = "mhrc.eval.pool"


def shares(stacks: Path) -> dict[str, object]:
    """The share of each bucket among the worker's samples and among all samples."""
    worker: collections.Counter[str] = collections.Counter()
    loop: collections.Counter[str] = collections.Counter()  # the worker's main thread: its asyncio loop
    total = outside = 0
    opener = gzip.open if stacks.suffix == ".gz" else open
    with opener(stacks, "rt") as lines:
        for line in lines:
            stack, _, count = line.rstrip().rpartition(" ")
            n = int(count)
            frames = stack.split(";")
            total += n
            if not any(WORKER in f for f in frames[:2]):
                outside += n  # the bench's own process: the model server, the coordinator
                continue
            bucket = next((name for name, rule in BUCKETS if rule(frames)), "other")
            worker[bucket] += n
            if any(f.startswith("Runner.run ") for f in frames):
                loop[bucket] += n
    in_worker = total - outside
    return {
        "samples": total,
        "worker_samples": in_worker,
        "outside_worker_share": round(outside / total, 3) if total else None,
        "worker_shares": {k: round(v / in_worker, 3) for k, v in worker.most_common()} if in_worker else {},
        "worker_loop_thread_samples": sum(loop.values()),
        "worker_loop_thread_shares": {k: round(v / sum(loop.values()), 3) for k, v in loop.most_common()}
        if loop
        else {},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--latency", default="0.2")
    ap.add_argument("--horizon", default="20")
    ap.add_argument("--concurrency", default="36")
    ap.add_argument("--rate", default="50", help="py-spy samples a second")
    ap.add_argument("--stacks", type=Path, help="read these stacks (py-spy raw, maybe gzipped) instead of sampling")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    config = {"latency_s": args.latency, "horizon": args.horizon, "concurrency": args.concurrency, "py_spy": "--gil"}
    stacks = args.stacks
    if stacks is None:
        spy = shutil.which("py-spy", path=str(Path(sys.executable).parent)) or shutil.which("py-spy")
        if spy is None:
            ap.error("py-spy is not installed (pip install py-spy)")
        raw = Path(tempfile.mkdtemp()) / "llm_grid.raw"
        grid = [sys.executable, str(Path(__file__).with_name("bench_llm_grid.py"))]
        grid += ["--latency", args.latency, "--horizon", args.horizon, "--concurrency", args.concurrency]
        subprocess.run(
            [spy, "record", "--gil", "--subprocesses", "-r", args.rate, "-f", "raw", "-o", str(raw), "--", *grid],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        stacks = raw
        if args.out:
            kept = args.out.with_suffix(".raw.gz")
            with raw.open("rb") as src, gzip.open(kept, "wb") as dst:
                shutil.copyfileobj(src, dst)
            config["stacks"] = kept.name
    emit({"bench": "llm_call_profile", "config": config, **shares(stacks)}, args.out)


if __name__ == "__main__":
    main()
