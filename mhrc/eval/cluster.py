"""The Ray executor of `mhrc eval --ray ADDRESS`: every episode a Ray task on a cluster the user
runs (`ray start` by hand, KubeRay, Slurm), with Ray's retries, resources and dashboard.

A task runs one episode whole in its Ray worker process (world and agents, as a local pool
worker does: mhrc.eval.episode) and returns its `WorkerResult` through the object store, the
trace zlib-compressed; with a shared --out (`--shared-out`: the same path on every node) it
writes the trace there and returns only the path. A task whose worker process or node dies is
run again by Ray (`max_retries=RAY_RETRIES`). Resources: one CPU per heuristic episode (it is
CPU-bound); with an LLM 1/concurrency of one, so that `--concurrency` episodes waiting on a
model share a core.

Ray is an extra (`pip install -e ".[ray]"`); nothing here imports it before `--ray` is given.
Its token authentication (on by default for `ray start`) is Ray's: this driver presents the
token Ray finds ($RAY_AUTH_TOKEN, $RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token).
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import logging
import os
import re
import socket
import sys
import time
from pathlib import Path
from typing import Any

from mhrc.core.logs import get_logger
from mhrc.eval.jobs import Job, WorkerResult
from mhrc.run.config import ConfigError

log = get_logger("mhrc.eval")

RAY_MIN = (2, 40)  # the oldest Ray this code is written against
INSTALL = 'pip install -e ".[ray]"'
NOT_INSTALLED = f"--ray: Ray is not installed; install the extra: {INSTALL}"
RAY_RETRIES = 3  # runs of a task whose worker process or node died, after the first
PROBE_TIMEOUT = 5.0  # s to wait for anything to answer at --ray HOST:PORT before saying nothing does
# A head's Ray Client server forks a server process for every driver that connects; that process
# sometimes dies at once (a gRPC fork race in Ray's proxier, ray-project/ray#63202: here the first
# join after `ray start` on 11 of 53 fresh heads, never a later one). Ray says so only in words, these.
CLIENT_START_FAILED = "Starting Ray client server failed"
JOIN_ATTEMPTS = 3  # ray:// joins tried when the cluster failed to start this driver's session


def import_ray() -> Any:
    """The `ray` module, or a ConfigError naming the install command / the version needed."""
    try:
        import ray
    except ImportError:
        raise ConfigError(NOT_INSTALLED) from None
    version = getattr(ray, "__version__", "0")
    parts = tuple(int(p) for p in re.findall(r"\d+", version)[:2])
    if parts < RAY_MIN:
        need = ".".join(map(str, RAY_MIN))
        raise ConfigError(f"--ray: Ray {version} is not supported; mhrc needs ray>={need}: {INSTALL}")
    return ray


def require_ray() -> None:
    """A ConfigError naming the install command when Ray is not installed, found without importing
    it (Ray's import takes most of a second): a refusal for the address comes before that import."""
    installed = sys.modules["ray"] is not None if "ray" in sys.modules else importlib.util.find_spec("ray") is not None
    if not installed:
        raise ConfigError(NOT_INSTALLED)


def probe(address: str, timeout: float = PROBE_TIMEOUT) -> None:
    """Fail within `timeout` s, naming --ray, when nothing listens at a HOST:PORT or
    ray://HOST:PORT address (ray.init would retry for a minute or more); `auto` and `local`
    are ray.init's to resolve."""
    if address in ("auto", "local"):
        return
    rest = address.split("://", 1)[1] if "://" in address else address
    host, colon, port = rest.rstrip("/").rpartition(":")
    if not colon or not port.isdigit() or not host:
        raise ConfigError(
            f"--ray: {address!r} is not an address ray.init takes: auto, HOST:PORT (the head's GCS, e.g. 10.0.0.5:6379) or ray://HOST:10001"
        )
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            pass
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        raise ConfigError(
            f"--ray: nothing answers at {address} ({why}); start the head with `ray start --head` (it prints "
            f"the address), or pass --ray auto on a node of the cluster"
        ) from None


def has_token() -> bool:
    """Whether this process can present a Ray token (where Ray looks for one)."""
    path = os.environ.get("RAY_AUTH_TOKEN_PATH")
    return bool(os.environ.get("RAY_AUTH_TOKEN")) or Path(path or Path.home() / ".ray" / "auth_token").is_file()


def _episode(job_json: str, trace_dest: str | None) -> dict[str, Any]:
    """The Ray task: one episode in this worker process (see mhrc.eval.episode.run_job)."""
    from mhrc.core import logs
    from mhrc.eval.episode import run_job, worker_name

    logs.configure("error")
    job = Job.model_validate_json(job_json)
    result = asyncio.run(run_job(job, worker_name(), trace_dest=Path(trace_dest) if trace_dest else None))
    return result.model_dump()


class RayExecutor:
    """Episodes as Ray tasks on the cluster at `address`; the same interface as the local pool
    (mhrc.eval.pool.PoolExecutor): `submit`, `next`, `stop`."""

    def __init__(self, address: str, *, concurrency: int = 1, llm: bool = False, traces: Path | None = None) -> None:
        self.address = address
        self.num_cpus = 1.0 / concurrency if llm else 1.0
        self.traces = traces  # a shared --out's traces/ (absolute): tasks write there
        self._ray: Any = None
        self._task: Any = None
        self._running: dict[asyncio.Future[Any], tuple[Job, Any]] = {}

    async def __aenter__(self) -> RayExecutor:
        ray = import_ray()
        await asyncio.to_thread(probe, self.address)
        try:
            await self._join(ray)
        except Exception as exc:  # a version mismatch, a refused token, a cluster that went away
            lines = [x.strip() for x in str(exc).splitlines() if x.strip()] or [type(exc).__name__]
            first = (
                lines[0] if len(lines) == 1 else f"{lines[0]} {lines[-1]}"
            )  # a server's traceback: its heading and its error
            hint = (
                ""
                if has_token()
                else (
                    "; this driver has no Ray token: set RAY_AUTH_MODE=token and RAY_AUTH_TOKEN (or copy the head's ~/.ray/auth_token)"
                )
            )
            raise ConfigError(f"--ray: could not join the Ray cluster at {self.address}: {first}{hint}") from None
        self._ray = ray
        self._task = ray.remote(max_retries=RAY_RETRIES, retry_exceptions=False)(_episode)
        log.info("joined the Ray cluster", address=self.address, resources=ray.cluster_resources())
        return self

    async def _join(self, ray: Any) -> None:
        """ray.init; through Ray Client, again (up to JOIN_ATTEMPTS) when the cluster's client
        server failed to start this driver's session, which is Ray's bug and not the user's."""
        for attempt in range(1, JOIN_ATTEMPTS + 1):
            try:
                await asyncio.to_thread(
                    ray.init,
                    address=self.address,
                    logging_level=logging.ERROR,
                    log_to_driver=False,
                    configure_logging=True,
                    namespace="mhrc-eval",
                )
                return
            except ConnectionAbortedError as exc:
                if CLIENT_START_FAILED not in str(exc) or attempt == JOIN_ATTEMPTS:
                    raise
                log.warning(
                    "the Ray cluster failed to start this driver's Ray Client session (ray-project/ray#63202); joining again",
                    address=self.address,
                    attempt=attempt + 1,
                    of=JOIN_ATTEMPTS,
                )
                with contextlib.suppress(Exception):
                    await asyncio.to_thread(ray.shutdown)

    async def __aexit__(self, *exc: object) -> None:
        await self.stop(grace=0.0)
        if self._ray is not None:
            await asyncio.to_thread(self._ray.shutdown)
            self._ray = None

    def submit(self, job: Job) -> None:
        dest = str(self.traces / (job.key.replace("/", "_") + ".jsonl")) if self.traces is not None else None
        ref = self._task.options(num_cpus=self.num_cpus, name=f"mhrc-episode {job.key}").remote(
            job.model_dump_json(), dest
        )
        self._running[asyncio.wrap_future(ref.future())] = (job, ref)

    def _take(self, fut: asyncio.Future[Any]) -> WorkerResult:
        job, _ref = self._running.pop(fut)
        try:
            return WorkerResult.model_validate(fut.result())
        except Exception as exc:  # the task failed past its retries: its worker or node kept dying
            first = (str(exc).strip().splitlines() or [""])[0]
            return WorkerResult(key=job.key, worker="ray", error=f"{type(exc).__name__}: {first}")

    async def next(self) -> WorkerResult:
        done, _ = await asyncio.wait(set(self._running), return_when=asyncio.FIRST_COMPLETED)
        return self._take(next(iter(done)))

    async def stop(self, grace: float) -> list[WorkerResult]:
        """Cancel the tasks still running (their worker processes are killed) and return the
        results that had arrived: finished episodes are never lost."""
        out = [self._take(f) for f in [f for f in self._running if f.done()]]
        out = [r for r in out if r.error is None]
        if self._running and self._ray is not None:
            for _fut, (_job, ref) in self._running.items():
                with contextlib.suppress(Exception):
                    self._ray.cancel(ref, force=True)
            deadline = time.monotonic() + grace
            while self._running and time.monotonic() < deadline:
                done, _ = await asyncio.wait(set(self._running), timeout=max(0.0, deadline - time.monotonic()))
                if not done:
                    break
                out += [r for r in (self._take(f) for f in done) if r.error is None]
        for fut in self._running:
            fut.cancel()  # the loop may close before Ray settles them
        self._running.clear()
        return out


def shared(out: Path) -> Path:
    """The traces directory a shared --out gives the tasks: absolute, as every node sees it."""
    return Path(os.path.abspath(out)) / "traces"
