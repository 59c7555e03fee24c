"""`mhrc eval` locally (a pool of worker processes) beside `mhrc eval --ray` on a local Ray cluster
(`ray start --head` on 127.0.0.1 with the machine's cores, token authentication on), the same
grids in the same run:

- `default`: the paper's grid (36 episodes) with the heuristic team (CPU-bound: one episode per
  core either way);
- `paper_llm`: the same 36 episodes with a scripted model on loopback that answers every
  request after `--latency` seconds (the robots wait, so each episode runs to `--horizon`),
  `--concurrency` episodes at once per local worker / per Ray CPU.

Reports each grid's wall time locally and on Ray and their ratio (Ray / local), and Ray's own
start-up cost: `ray start --head`, a driver's `ray.init`, and the first task's round trip (a
fresh worker process). The local runs go first, so a warm-up cost falls on them.

    python bench/bench_ray.py [--latency 1.0] [--horizon 10] [--concurrency 6] [--grids default,paper_llm] [--out bench/results/ray.json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import secrets
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench_llm_concurrency import serve
from report import emit

from mhrc.core.endpoints import free_port
from mhrc.eval.engine import EvalSpec, evaluate

TASKS = ("pack_objects", "sort_solids", "make_sandwich")
SCENES = ("kitchen", "bathroom", "bedroom")

STARTUP = """
import json, sys, time
t0 = time.perf_counter()
import ray
ray.init(address=sys.argv[1], logging_level="ERROR", log_to_driver=False)
t1 = time.perf_counter()
ray.get(ray.remote(lambda: 1).remote())
t2 = time.perf_counter()
print(json.dumps({"ray_init_s": round(t1 - t0, 2), "first_task_s": round(t2 - t1, 2)}))
ray.shutdown()
"""


def run(spec: EvalSpec, out: Path, **kw: Any) -> dict[str, Any]:
    t0 = time.perf_counter()
    rows = asyncio.run(evaluate(spec, out, **kw))
    wall = time.perf_counter() - t0
    return {
        "episodes": len(rows),
        "succeeded": sum(bool(r.metrics.success) for r in rows),
        "errors": len((out / "errors.jsonl").read_text().splitlines()) if (out / "errors.jsonl").exists() else 0,
        "wall_s": round(wall, 2),
        "episodes_per_min": round(60 * len(rows) / wall, 2),
        "scores": {r.key: [r.metrics.success, r.metrics.temporal_steps, r.metrics.action_steps] for r in rows},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--latency", type=float, default=1.0, help="s the scripted model takes per reply")
    ap.add_argument("--horizon", type=int, default=10, help="temporal steps of the LLM episodes")
    ap.add_argument("--concurrency", type=int, default=6, help="LLM episodes at once per local worker / per Ray CPU")
    ap.add_argument("--cpus", type=int, default=os.cpu_count() or 1, help="local workers, and the Ray cluster's CPUs")
    ap.add_argument("--grids", default="default,paper_llm")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    grids = args.grids.split(",")
    own = Path(sys.executable).parent / "ray"  # this interpreter's Ray, not one of another Python on PATH
    ray_exe = str(own) if own.exists() else shutil.which("ray") or str(own)
    os.environ.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32))
    tmp = Path(tempfile.mkdtemp(prefix="mhrc-bench-ray-", dir="/tmp"))
    httpd = serve(args.latency)
    url = f"http://127.0.0.1:{httpd.server_address[1]}/v1"
    specs = {
        "default": EvalSpec(tasks=TASKS, scenes=SCENES),
        "paper_llm": EvalSpec(
            tasks=TASKS, scenes=SCENES, llm="openai:scripted", base_url=url, horizon=args.horizon, llm_timeout=60.0
        ),
    }
    results: dict[str, Any] = {}
    startup: dict[str, Any] = {}
    try:
        for name in grids:  # local first
            conc = args.concurrency if specs[name].llm else 1
            results[name] = {"local": run(specs[name], tmp / f"{name}-local", workers=args.cpus, concurrency=conc)}
        port = free_port("127.0.0.1")
        (tmp / "work").mkdir()
        t0 = time.perf_counter()
        subprocess.run(
            [
                ray_exe,
                "start",
                "--head",
                "--node-ip-address=127.0.0.1",
                f"--port={port}",
                f"--num-cpus={args.cpus}",
                "--include-dashboard=false",
                "--disable-usage-stats",
                f"--temp-dir={tmp / 'ray'}",
            ],
            check=True,
            capture_output=True,
            env=dict(os.environ, TMPDIR=str(tmp / "work")),
        )
        startup["ray_start_head_s"] = round(time.perf_counter() - t0, 2)
        address = f"127.0.0.1:{port}"
        probe = subprocess.run([sys.executable, "-c", STARTUP, address], check=True, capture_output=True, text=True)
        startup |= json.loads(probe.stdout.strip().splitlines()[-1])
        for name in grids:
            conc = args.concurrency if specs[name].llm else 1
            on_ray = run(specs[name], tmp / f"{name}-ray", ray=address, concurrency=conc)
            local = results[name]["local"]
            results[name]["ray"] = on_ray
            results[name]["ray_over_local"] = round(on_ray["wall_s"] / local["wall_s"], 3)
            results[name]["same_scores"] = on_ray["scores"] == local["scores"]
            for r in (local, on_ray):
                r.pop("scores")
    finally:
        subprocess.run([ray_exe, "stop", "--force"], capture_output=True)
        httpd.shutdown()
        httpd.server_close()
        shutil.rmtree(tmp, ignore_errors=True)
    emit(
        {
            "bench": "eval_local_vs_ray",
            "cpus": args.cpus,
            "llm_latency_s": args.latency,
            "llm_horizon": args.horizon,
            "llm_concurrency": args.concurrency,
            "ray_startup": startup,
            "grids": results,
            "note": "one machine: the local pool and a one-node Ray cluster with the same CPUs, same grids, same run, local first; "
            "Ray's figures include its task scheduling and sending each trace through the object store",
        },
        args.out,
    )


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
