"""One episode of an evaluation, run where an executor puts it (a local pool worker, a Ray
worker): the job it gets, the result it sends back, and the run itself.

An episode runs whole in the process that takes it: its world (a router on a free loopback
port) and its agents as asyncio tasks, with a trace in a temporary directory. Only the
trace goes back (zlib-compressed); the driver computes the row from it (`mhrc.analysis.metrics`,
`mhrc.analysis.diagnostics`), so a row means the same thing whichever process or host ran it.
"""

from __future__ import annotations

import asyncio
import os
import socket
import tempfile
import zlib
from pathlib import Path
from typing import Any

from mhrc.core.bus import Bus, Sample
from mhrc.core.keys import Keys, new_run_id
from mhrc.core.logs import get_logger
from mhrc.core.protocol import EpisodeDone, EpisodeStarted, ProtocolError, decode_event
from mhrc.eval.jobs import Job, WorkerResult
from mhrc.run import malloc as memory
from mhrc.run.inprocess import up_in_process
from mhrc.run.serve import EventHook

log = get_logger("mhrc.eval")


def worker_name() -> str:
    """How a row names the process that ran it: host and pid."""
    return f"{socket.gethostname()}:{os.getpid()}"


def watch_start(on_start: Any) -> EventHook:
    """An `up_in_process(observe=...)` hook calling `on_start()` once, when the episode has
    started (every robot attached) or ended: a pool worker starts the next episode's scene
    build only then."""
    fired = False

    def observe(bus: Bus, run: str) -> None:
        def on_event(sample: Sample) -> None:
            nonlocal fired
            if fired:
                return
            try:
                event = decode_event(sample.payload)
            except ProtocolError:
                return
            if isinstance(event, (EpisodeStarted, EpisodeDone)):
                fired = True
                on_start()

        bus.subscribe(Keys(run).world_event, on_event)

    return observe


async def run_job(
    job: Job, worker: str, *, observe: EventHook | None = None, trace_dest: Path | None = None
) -> WorkerResult:
    """Run one episode in this process; never raises but for cancellation. With `trace_dest`
    (a shared --out) the trace is written there and only its path goes back."""
    memory.limit_arenas()  # a worker's threads share malloc's arenas (before its first episode's threads start)
    with tempfile.TemporaryDirectory(prefix="mhrc-eval-") as tmp:
        trace = Path(tmp) / "trace.jsonl"
        try:
            cfg = job.config.model_copy(update={"run": new_run_id(), "trace": trace}).resolved()  # a run id per attempt
            await up_in_process(cfg, observe=observe)
            if trace_dest is not None:
                trace_dest.parent.mkdir(parents=True, exist_ok=True)
                part = trace_dest.with_name(f".{trace_dest.name}.{os.getpid()}")
                await asyncio.to_thread(lambda: part.write_bytes(trace.read_bytes()))
                os.replace(part, trace_dest)  # a retried attempt on another host never leaves half a file
                return WorkerResult(key=job.key, worker=worker, trace_file=str(trace_dest))
            data = await asyncio.to_thread(lambda: zlib.compress(trace.read_bytes(), 6))  # zlib lets go of the GIL
            return WorkerResult(key=job.key, worker=worker, trace_z=data)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            from mhrc.agents.llm import LLMFatalError

            log.warning("episode failed", key=job.key, error=str(exc))
            return WorkerResult(
                key=job.key, worker=worker, error=f"{type(exc).__name__}: {exc}", fatal=isinstance(exc, LLMFatalError)
            )
        finally:
            memory.release()  # a worker runs hundreds of episodes: give back what they freed once it holds too much
