"""What the driver hands a worker (Job) and what comes back (WorkerResult): plain data, so that
the grid's plan and a refused command line import no runner, bus or simulator."""

from __future__ import annotations

from enum import StrEnum

from pydantic import BaseModel, ConfigDict

from mhrc.run.config import EpisodeConfig


class Job(BaseModel):
    """One episode of the grid: its key (`task/scene/objects/seed`) and its config, built and
    checked once by the driver (mhrc.eval.spec); the process that runs it picks the run id, the
    port and the trace, and checks nothing again."""

    key: str
    config: EpisodeConfig
    repeat: int = 0
    trial: int = 0


class WorkerFailure(StrEnum):
    """An episode lost to its worker rather than to itself (WorkerResult.error_code)."""

    WORKER_DIED = "worker_died"  # the worker process ended during the episode
    WORKERS_KEEP_DYING = "workers_keep_dying"  # every worker died, again and again: the job was never run


class WorkerResult(BaseModel):
    """What comes back of a job: the trace (zlib of the JSONL), or where it was written
    (a shared --out), or the error that ended the episode. Its JSON carries the trace in base64
    (a pool worker's pipe)."""

    model_config = ConfigDict(ser_json_bytes="base64", val_json_bytes="base64")

    key: str
    worker: str
    trace_z: bytes = b""
    trace_file: str | None = None  # written there by the worker (--shared-out): nothing to carry back
    error: str | None = None
    error_code: WorkerFailure | None = (
        None  # what ended the episode outside it, for programs (`error` says it for people)
    )
    fatal: bool = False  # the error will recur in every episode (bad credentials, no such model): stop the evaluation
