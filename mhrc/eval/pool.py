"""The local executor of `mhrc eval`: a pool of worker processes of this machine, no Ray, no bus
between them.

Each worker is `python -m mhrc.eval.pool --concurrency N`, a child that dies with the driver
(mhrc.core.lifeline). The driver writes jobs (`Job`, one JSON line each) to its stdin and reads
results (`WorkerResult`, one JSON line each, the trace in base64) from its stdout; a worker
holds at most N jobs, so a free slot is the only thing that brings it another. Inside the
worker an episode runs whole (mhrc.eval.episode); up to N at once (LLM episodes mostly wait
on the model), at most STARTS_AT_ONCE of them building their scene and attaching their agents
at the same moment (a burst of N scene builds would hold up every world past its agents'
attach timeout).

A worker ignores SIGINT (a terminal's Ctrl-C reaches the whole group): the driver decides,
and stops workers with SIGTERM, which cancels their episodes. A worker that dies (killed, out
of memory) hands its jobs back as errors; the driver tries each once more on a new worker.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import signal
import sys
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import IO

from pydantic import ValidationError

from mhrc.core.lifeline import child_env
from mhrc.core.logs import get_logger
from mhrc.eval.episode import run_job, watch_start, worker_name
from mhrc.eval.jobs import Job, WorkerFailure, WorkerResult

log = get_logger("mhrc.eval")

# to_thread calls one episode may have in flight: its world's sim, its sessions opening or closing (one
# on the open bus, where the agents share the world's; four when each logs in) (a query holds none: core/bus.py)
THREADS_PER_EPISODE = 6
STARTS_AT_ONCE = 4  # episodes of one worker building their scene and attaching their agents at the same time
LINE_LIMIT = 1 << 30  # a result line carries a whole trace
RESPAWNS_PER_WORKER = 3  # workers that die before the grid is done are replaced this many times per --workers


# --------------------------------------------------------------------------- the worker process


async def _serve(concurrency: int, results: IO[bytes]) -> None:
    """Run the jobs read from stdin, up to `concurrency` at once, until stdin closes and every
    episode has ended; SIGTERM cancels them."""
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None
    loop.add_signal_handler(signal.SIGTERM, task.cancel)
    if concurrency > 1:
        # asyncio's default pool (cores + 4 threads) is too small for several episodes starting at
        # once: each builds its scene and opens its sessions on threads
        loop.set_default_executor(
            ThreadPoolExecutor(max_workers=THREADS_PER_EPISODE * concurrency + 4, thread_name_prefix="mhrc-worker")
        )
    reader = asyncio.StreamReader(limit=LINE_LIMIT)
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    starting = asyncio.Semaphore(STARTS_AT_ONCE)
    me = worker_name()
    running: set[asyncio.Task[None]] = set()

    async def one(job: Job) -> None:
        await starting.acquire()
        held = True

        def started() -> None:
            nonlocal held
            if held:
                held = False
                starting.release()

        try:
            result = await run_job(job, me, observe=watch_start(started))
        finally:
            started()
        results.write(result.model_dump_json().encode() + b"\n")
        results.flush()

    try:
        while line := await reader.readline():
            t = asyncio.create_task(one(Job.model_validate_json(line)), name=f"job-{line[:60]!r}")
            running.add(t)
            t.add_done_callback(running.discard)
        if running:
            await asyncio.gather(*running)
    finally:
        for t in running:
            t.cancel()
        await asyncio.gather(*running, return_exceptions=True)


def main(argv: list[str] | None = None) -> None:
    """`python -m mhrc.eval.pool`: one worker of the local pool (started by `mhrc eval`)."""
    from mhrc.core import logs
    from mhrc.core.lifeline import die_with_parent

    parser = argparse.ArgumentParser(prog="python -m mhrc.eval.pool")
    parser.add_argument("--concurrency", type=int, default=1)
    parser.add_argument("--log-level", default="error")
    args = parser.parse_args(argv)
    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the driver's Ctrl-C; it stops us with SIGTERM
    results = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # what else writes to stdout (PyBullet's banner, a stray print) goes to stderr, not into the results
    logs.configure(args.log_level)
    with contextlib.suppress(asyncio.CancelledError, KeyboardInterrupt):
        asyncio.run(_serve(args.concurrency, results))


# --------------------------------------------------------------------------- the driver's side


class _Worker:
    """One worker process as the driver sees it: its jobs in flight and the task reading its results."""

    def __init__(self, proc: asyncio.subprocess.Process) -> None:
        self.proc = proc
        self.jobs: dict[str, Job] = {}
        self.reader: asyncio.Task[None] | None = None


class PoolExecutor:
    """`workers` local worker processes, each running up to `concurrency` episodes at once.

    `submit` queues a job; `next` waits for the next result (an error result for each job of a
    worker that died); `stop` ends every worker (SIGTERM, then SIGKILL after `grace` s) and
    returns the results that arrived meanwhile: finished episodes are never lost."""

    def __init__(self, workers: int, concurrency: int, log_level: str = "error") -> None:
        self.workers = workers
        self.concurrency = concurrency
        self.log_level = log_level
        self._queue: deque[Job] = deque()
        self._pool: list[_Worker] = []
        self._results: asyncio.Queue[WorkerResult] = asyncio.Queue()
        self._respawns = RESPAWNS_PER_WORKER * workers
        self._spawned = 0
        self._stopping = False
        self._lock = asyncio.Lock()

    async def __aenter__(self) -> PoolExecutor:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop(grace=10.0)

    def submit(self, job: Job) -> None:
        self._queue.append(job)

    async def next(self) -> WorkerResult:
        await self._dispatch()
        return await self._results.get()

    async def _spawn(self) -> _Worker:
        cmd = [
            sys.executable,
            "-m",
            "mhrc.eval.pool",
            "--concurrency",
            str(self.concurrency),
            "--log-level",
            self.log_level,
        ]
        proc = await asyncio.create_subprocess_exec(
            *cmd,
            stdin=asyncio.subprocess.PIPE,
            stdout=asyncio.subprocess.PIPE,
            limit=LINE_LIMIT,
            env=child_env(dict(os.environ, PYTHONUNBUFFERED="1")),
        )
        w = _Worker(proc)
        w.reader = asyncio.create_task(self._read(w), name=f"pool-reader-{proc.pid}")
        self._pool.append(w)
        self._spawned += 1
        return w

    async def _read(self, w: _Worker) -> None:
        assert w.proc.stdout is not None
        while line := await w.proc.stdout.readline():
            try:
                res = WorkerResult.model_validate_json(line)
            except ValidationError:  # not a result (something wrote to stdout before the worker moved it aside)
                log.warning("not a result line from a pool worker", pid=w.proc.pid, line=line[:200])
                continue
            w.jobs.pop(res.key, None)
            self._results.put_nowait(res)
            if not self._stopping:
                await self._dispatch()
        code = await w.proc.wait()
        self._pool.remove(w)
        for job in w.jobs.values():  # died with these unfinished
            why = f"the worker process ended (exit {code}) during the episode"
            self._results.put_nowait(
                WorkerResult(key=job.key, worker=f"pid {w.proc.pid}", error=why, error_code=WorkerFailure.WORKER_DIED)
            )
        w.jobs.clear()
        if not self._stopping:
            await self._dispatch()

    async def _dispatch(self) -> None:
        async with self._lock:
            await self._hand_out()

    async def _hand_out(self) -> None:
        """Hand queued jobs to workers with a free slot, starting workers up to `workers`."""
        while self._queue and not self._stopping:
            free = [
                w
                for w in self._pool
                if len(w.jobs) < self.concurrency
                and w.proc.returncode is None
                and w.proc.stdin is not None
                and not w.proc.stdin.is_closing()
            ]
            if free:
                w = min(free, key=lambda x: len(x.jobs))
            elif len(self._pool) < self.workers and self._spawned < self.workers + self._respawns:
                w = await self._spawn()
            elif not self._pool:  # every worker died, again and again: give the jobs back as errors
                while self._queue:
                    job = self._queue.popleft()
                    self._results.put_nowait(
                        WorkerResult(
                            key=job.key,
                            worker="",
                            error="the worker processes keep dying; see their errors above",
                            error_code=WorkerFailure.WORKERS_KEEP_DYING,
                        )
                    )
                return
            else:
                return
            job = self._queue.popleft()
            w.jobs[job.key] = job
            assert w.proc.stdin is not None
            w.proc.stdin.write(job.model_dump_json().encode() + b"\n")
            with contextlib.suppress(ConnectionError):
                await w.proc.stdin.drain()
        if not self._queue:  # nothing more to hand out: a worker with nothing to do ends
            for w in self._pool:
                if not w.jobs and w.proc.stdin is not None and not w.proc.stdin.is_closing():
                    w.proc.stdin.close()

    async def stop(self, grace: float) -> list[WorkerResult]:
        """End every worker: those with nothing left end by themselves (stdin closed); with
        episodes running (an interrupt), SIGTERM cancels them. Returns the results not yet taken."""
        self._stopping = True
        self._queue.clear()
        for w in list(self._pool):
            if w.proc.stdin is not None and not w.proc.stdin.is_closing():
                w.proc.stdin.close()
            if w.jobs and w.proc.returncode is None:
                _signal(w.proc.terminate)
        readers = [w.reader for w in self._pool if w.reader is not None]
        deadline = time.monotonic() + grace
        for w in list(self._pool):
            try:
                await asyncio.wait_for(asyncio.shield(w.proc.wait()), timeout=max(0.0, deadline - time.monotonic()))
            except asyncio.TimeoutError:
                _signal(w.proc.terminate)
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(asyncio.shield(w.proc.wait()), timeout=1.0)
                if w.proc.returncode is None:
                    _signal(w.proc.kill)
                    await w.proc.wait()
        await asyncio.gather(*readers, return_exceptions=True)  # every result line written is read
        out = []
        while not self._results.empty():
            res = self._results.get_nowait()
            if res.error_code is not WorkerFailure.WORKER_DIED:
                out.append(res)
        return out


def _signal(send: Callable[[], None]) -> None:
    """`send` a worker its signal; one that ended meanwhile (asyncio knows it before its return
    code is set, and raises ProcessLookupError) needs none."""
    with contextlib.suppress(ProcessLookupError):
        send()


if __name__ == "__main__":
    main()
