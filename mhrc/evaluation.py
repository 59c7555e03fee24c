"""`mhrc eval`: the paper's benchmark grid as one command, episodes spread over worker processes
on one Zenoh bus, results as traces, `episodes.jsonl` and summary tables.

The coordinator opens a Zenoh router and serves the grid; workers (local processes it starts,
or `mhrc worker --connect tls/HOST:PORT --credentials ...` on other hosts) pull jobs, run each episode in-process
with its own run id on the same bus, and push back the episode's trace. A worker runs up to
`--concurrency` episodes at once (LLM episodes mostly wait on the model). Keys, under
`mhrc/eval/<eval id>/`:

    job                   queryable: a worker asks (JobRequest) and gets a JobReply: a job,
                          "wait" (everything is handed out, results pending) or "done"
    result                put: a worker's EvalResult (the job's key and its zlib'd trace)
    alive/coordinator     liveliness token of the coordinator (workers find the eval by it)
    alive/worker/<id>     liveliness token of each worker: when one vanishes, its unfinished
                          jobs go back to the queue

Secured (`secure=True`, the default of `mhrc eval`): the router listens on tls/ with the
coordinator's certificate and logs in every worker with the evaluation's one worker login
(`mhrc.security.make_eval_credentials`, in DIR/credentials/ while the evaluation runs); a
worker's episodes (world and agents) log in with it too.

Each episode's metrics and failure diagnostics (`diag_*` columns) are computed by the coordinator
from the trace (`mhrc.metrics`, `mhrc.diagnostics`), so a row means the same thing whichever host
ran it. Rows are appended to DIR/episodes.jsonl as they arrive; `--resume` skips the keys already
there. Summaries (tables, confidence intervals, the paper's figures; summary.md, .csv and .html)
are `mhrc.report`'s.

The default grid is the paper's: per task, every scene with one episode per object count 3, 4,
5 and 6 (3 scenes x 4 = 12 episodes per task). Seeds: an episode's seed is
`repeat * trials + trial`, so with the default one trial, repeat r of the paper grid runs every
episode with seed r (repeat 0, seed 0, is a run without --repeats; more repeats extend it). The
job key is `task/scene/objects/seed`.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
import zlib
from collections import defaultdict, deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog
from pydantic import BaseModel, Field

from . import memory
from .bus import Bus, Sample, endpoint, free_port, split_endpoint
from .diagnostics import diagnose
from .episode import DEFAULT_MAX_TOKENS, ConfigError, EpisodeConfig, EventHook, open_client, up_in_process
from .fidelity import label
from .keys import Keys
from .lifeline import child_env
from .metrics import TraceError, from_trace
from .protocol import EpisodeDone, EpisodeStarted, ProtocolError, decode, decode_event
from .report import PAPER_OBJECTS, merge_runs, read_rows, summary_csv, summary_markdown, write_summaries
from .trace import read_trace, unwritable

if TYPE_CHECKING:
    from .security import Credentials

__all__ = ["EvalSpec", "evaluate", "merge_runs", "run_worker", "summary_csv", "summary_markdown", "write_summaries"]

log = structlog.get_logger("mhrc.eval")

ROOT = "mhrc/eval"
# s an issued job may take before it goes back to the queue. Per job, whatever a worker's
# --concurrency: a worker asks for a job only when it has a free slot, so a job starts running
# when it is issued (N jobs sharing one CPU-bound worker each take longer; 600 s leaves room).
JOB_TIMEOUT = 600.0
THREADS_PER_EPISODE = 6  # to_thread calls one episode may have in flight: its world's sim, its four sessions' opens and gets
STARTS_AT_ONCE = 4  # episodes of one worker building their scene and attaching their agents at the same time


# --------------------------------------------------------------------------- messages


class Job(BaseModel):
    key: str
    config: dict[str, Any]  # EpisodeConfig fields (no run, port or trace: the worker picks those)
    repeat: int = 0
    trial: int = 0


class JobRequest(BaseModel):
    worker: str


class JobReply(BaseModel):
    status: str = Field(description="job | wait | done")
    job: Job | None = None


class EvalResult(BaseModel):
    key: str
    worker: str
    trace_z: str = ""  # base64 of the zlib-compressed JSONL trace
    error: str | None = None
    fatal: bool = False  # the error will recur in every episode (bad credentials, no such model): stop the evaluation


class EvalAborted(RuntimeError):
    """The evaluation cannot go on (an error every episode would hit, or no worker left); finished rows are kept."""


def _keys(eval_id: str) -> dict[str, str]:
    base = f"{ROOT}/{eval_id}"
    return {
        "job": f"{base}/job",
        "result": f"{base}/result",
        "coordinator": f"{base}/alive/coordinator",
        "worker": f"{base}/alive/worker",
    }


# --------------------------------------------------------------------------- the grid


@dataclass(frozen=True)
class EvalSpec:
    """What an evaluation runs: the grid and how each episode is driven."""

    tasks: tuple[str, ...]
    scenes: tuple[str, ...]
    objects: tuple[int, ...] = PAPER_OBJECTS
    trials: int = 1  # episodes per (task, scene, object count) in each repeat
    llm: str | None = None
    ablation: str = "none"
    horizon: int = 50
    base_url: str | None = None
    llm_timeout: float | None = None  # None: per spec (mhrc.episode.EpisodeConfig.timeout_for)
    llm_idle_timeout: float | None = None  # None: mhrc.episode.IDLE_TIMEOUT
    stream: bool = True  # False: --no-stream
    prompts: str | None = None
    repeats: int = 1  # the grid, run this many times with other seeds
    aids: tuple[str, ...] = ()  # mhrc.fidelity names; () is the paper's fidelity
    history_cap: int | None = None
    max_tokens: int = DEFAULT_MAX_TOKENS
    llm_seed: int | None = None
    structured: bool = False  # JSON decisions (not the paper's free text)
    step_deadline: float | None = None
    schedule: str = "sequential"  # the world's time policy (mhrc.episode.SCHEDULES); the paper's loop by default
    time_scale: float = 0.0  # async: simulated seconds per wall second, 0 as fast as possible

    @property
    def mode(self) -> str:
        """How the model answers: free (the paper's text) or structured (JSON Schema)."""
        return "structured" if self.structured else "free"

    @property
    def method(self) -> str:
        return self.llm or "heuristic"

    @property
    def fidelity(self) -> str:
        return label(self.aids)

    def identity(self) -> dict[str, Any]:
        """What must match for --resume to continue a run: everything that changes the numbers
        (the grid may grow: more trials, repeats, object counts, scenes or tasks)."""
        return {
            "method": self.method, "ablation": self.ablation, "horizon": self.horizon, "fidelity": self.fidelity,
            "history_cap": self.history_cap, "prompts": self.prompts, "mode": self.mode,
            "max_tokens": self.max_tokens if self.llm else None, "llm_seed": self.llm_seed, "schedule": self.schedule,
            "time_scale": self.time_scale,
        }  # fmt: skip

    def seed(self, repeat: int, trial: int) -> int:
        """The episode seed of a trial in a repeat: distinct for every (repeat, trial)."""
        return repeat * self.trials + trial

    def jobs(self) -> list[Job]:
        """Repeat by repeat (a finished repeat is a whole grid), then task, scene, objects, trial."""
        out = []
        for repeat in range(self.repeats):
            for task in self.tasks:
                for scene in self.scenes:
                    for n in self.objects:
                        for trial in range(self.trials):
                            seed = self.seed(repeat, trial)
                            cfg: dict[str, Any] = {
                                "task": task, "scene": scene, "seed": seed, "n_objects": n, "horizon": self.horizon,
                                "llm": self.llm, "ablation": self.ablation, "base_url": self.base_url,
                                "llm_timeout": self.llm_timeout, "prompts": self.prompts,
                                "llm_idle_timeout": self.llm_idle_timeout, "stream": None if self.stream else False,
                                "aids": list(self.aids) or None, "history_cap": self.history_cap,
                                "max_tokens": self.max_tokens, "llm_seed": self.llm_seed, "structured": self.structured or None,
                                "step_deadline": self.step_deadline, "schedule": self.schedule,
                                "time_scale": self.time_scale or None,
                            }  # fmt: skip
                            config = {k: v for k, v in cfg.items() if v is not None}
                            out.append(Job(key=f"{task}/{scene}/{n}/{seed}", config=config, repeat=repeat, trial=trial))
        return out

    def validate(self) -> None:
        """Fail before anything starts, naming the option: every cell of the grid must be a valid episode."""
        if self.repeats < 1:
            raise ConfigError(f"--repeats: must be at least 1 (got {self.repeats})")
        if self.trials < 1:
            raise ConfigError(f"--trials: must be at least 1 (got {self.trials})")
        if not (self.tasks and self.scenes and self.objects):
            raise ConfigError("--tasks, --scenes and --objects must each name at least one value")
        seen: set[tuple[str, str, int]] = set()
        for job in self.jobs():
            c = job.config
            cell = (c["task"], c["scene"], c["n_objects"])
            if cell not in seen:
                seen.add(cell)
                EpisodeConfig.build(**c)


# --------------------------------------------------------------------------- worker


async def find_eval(bus: Bus, timeout: float = 10.0) -> str:
    """The id of the only evaluation whose coordinator is alive on this bus."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        ids = sorted({k.split("/")[2] for k in await bus.alive(f"{ROOT}/*/alive/coordinator", timeout=1.0)})
        if ids or loop.time() >= deadline:
            break
        await asyncio.sleep(0.3)
    if len(ids) != 1:
        raise ConfigError(f"pass --eval: expected exactly one evaluation on the bus, found {', '.join(ids) or 'none'}")
    return ids[0]


async def run_worker(
    connect: str,
    eval_id: str | None = None,
    worker_id: str | None = None,
    connect_timeout: float = 30.0,
    concurrency: int = 1,
    login: Credentials | None = None,
) -> int:
    """Pull jobs from the coordinator at `connect` and run them until it says done; returns
    how many episodes this worker ran. With `login` (the evaluation's worker credentials, for
    a secured coordinator) this worker and every participant of its episodes log in with it.

    Up to `concurrency` episodes run at once as tasks of this process, each with its own world
    (its own PyBullet clients) and run id. With an LLM an episode mostly waits on the model, so
    N at once keep a model server's batch full; the heuristic is CPU-bound and gains little.
    A new job is asked for whenever a slot is free and fewer than STARTS_AT_ONCE episodes are
    still starting (building their scene, attaching their agents): a burst of N scene builds
    would hold up every world past its agents' attach timeout."""
    if concurrency < 1:
        raise ConfigError(f"--concurrency: must be at least 1 (got {concurrency})")
    if concurrency > 1:
        # asyncio's default pool (cores + 4 threads) starves with several episodes: their agents'
        # attach gets hold threads while the worlds they wait on need one to answer
        asyncio.get_running_loop().set_default_executor(
            ThreadPoolExecutor(max_workers=THREADS_PER_EPISODE * concurrency + 4, thread_name_prefix="mhrc-worker")
        )
    worker_id = worker_id or f"w-{uuid.uuid4().hex[:8]}"
    if login is not None and eval_id is None:
        eval_id = login.run  # an evaluation's credentials name it
    bus = await open_client(connect, connect_timeout, security=login)
    wake = asyncio.Event()  # an episode started or a job ended
    slots: list[_Slot] = []
    ran = 0
    try:
        eval_id = eval_id or await find_eval(bus)
        keys = _keys(eval_id)
        await _await_coordinator(bus, keys["coordinator"], eval_id, connect_timeout)
        bus.declare_token(f"{keys['worker']}/{worker_id}")
        done = False  # the coordinator has nothing more to hand out
        while True:
            wake.clear()
            for slot in [s for s in slots if s.task.done()]:
                slots.remove(slot)
                bus.put(keys["result"], slot.task.result())
                ran += 1
            waiting = False  # asked and heard "wait": ask again a little later
            while not done and len(slots) < concurrency and sum(not s.started for s in slots) < STARTS_AT_ONCE:
                replies = await bus.get(keys["job"], JobRequest(worker=worker_id), timeout=10.0)
                if not replies:
                    if not await bus.alive(keys["coordinator"], timeout=1.0):
                        log.warning("the coordinator is gone; stopping", eval=eval_id, unfinished=len(slots))
                        return ran  # nobody would take the results: the finally block cancels what runs
                    continue
                reply = decode(replies[0], JobReply)
                if reply.status == "done":
                    done = True  # the jobs still running finish first
                elif reply.job is None:
                    waiting = True
                    break
                else:
                    slots.append(_Slot(reply.job, worker_id, connect, wake, login))
            if not slots:
                if done:
                    return ran
                await asyncio.sleep(0.3)
                continue
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(wake.wait(), timeout=0.3 if waiting else None)
    finally:
        for slot in slots:
            slot.task.cancel()
        await asyncio.gather(*(s.task for s in slots), return_exceptions=True)
        await bus.close()


async def _await_coordinator(bus: Bus, token: str, eval_id: str, timeout: float) -> None:
    """Wait for the coordinator's token: a worker may connect the moment the router listens,
    before the coordinator serves jobs (it would take the silence for a coordinator gone)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not await bus.alive(token, timeout=1.0):
        if loop.time() >= deadline:
            raise ConfigError(f"no evaluation {eval_id!r} on this bus within {timeout:.0f} s (pass --eval, or none for the only one)")
        await asyncio.sleep(0.2)


class _Slot:
    """One job a worker runs: its episode's task, and whether the episode has started (every
    robot attached) or ended; either wakes the worker."""

    def __init__(self, job: Job, worker_id: str, connect: str, wake: asyncio.Event, login: Credentials | None = None) -> None:
        self.started = False
        self._wake = wake
        self.task = asyncio.create_task(_run_job(job, worker_id, connect, self._observe, login), name=f"job-{job.key}")
        self.task.add_done_callback(lambda _t: wake.set())

    def _observe(self, bus: Bus, run: str) -> None:
        """Hooked onto the episode's world session (`up_in_process(observe=...)`)."""

        def on_event(sample: Sample) -> None:
            if self.started:
                return
            try:
                event = decode_event(sample.payload)
            except ProtocolError:
                return
            if isinstance(event, (EpisodeStarted, EpisodeDone)):
                self.started = True
                self._wake.set()

        bus.subscribe(Keys(run).world_event, on_event)


async def _run_job(
    job: Job, worker_id: str, connect: str, observe: EventHook | None = None, login: Credentials | None = None
) -> EvalResult:
    with tempfile.TemporaryDirectory(prefix="mhrc-eval-") as tmp:
        trace = Path(tmp) / "trace.jsonl"
        try:
            cfg = EpisodeConfig.build(**job.config, trace=trace).resolved()
            await up_in_process(cfg, connect=connect, observe=observe, login=login)
            data = await asyncio.to_thread(lambda: zlib.compress(trace.read_bytes(), 6))  # zlib lets go of the GIL
            return EvalResult(key=job.key, worker=worker_id, trace_z=base64.b64encode(data).decode())
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            from mhrc.agents.llm import LLMFatalError

            log.warning("episode failed", key=job.key, error=str(exc))
            return EvalResult(key=job.key, worker=worker_id, error=f"{type(exc).__name__}: {exc}", fatal=isinstance(exc, LLMFatalError))
        finally:
            memory.release()  # a worker runs hundreds of episodes: give back what this one freed


def worker_command(connect: str, eval_id: str, concurrency: int = 1, credentials: Path | None = None) -> list[str]:
    return [
        sys.executable, "-m", "mhrc", "worker", "--connect", connect, "--eval", eval_id, "--concurrency", str(concurrency),
        "--log-level", "error", *(["--credentials", str(credentials)] if credentials else ["--insecure"]),
    ]  # fmt: skip


# --------------------------------------------------------------------------- coordinator
def own_credentials(out: Path) -> Path:
    """Where an evaluation without --credentials writes its own (deleted when it ends, however it ends)."""
    return out / "credentials"


def _forget(creds_dir: Path, ephemeral: bool) -> None:
    """The evaluation's own credentials live as long as it runs: nobody can log in to a later one with them."""
    if ephemeral:
        shutil.rmtree(creds_dir, ignore_errors=True)


def _given_credentials(directory: Path) -> tuple[Credentials, Path]:
    """The coordinator's credentials and the workers' login file in a directory issued by
    `mhrc credentials --eval`."""
    from .security import COORDINATOR, EVAL, WORKER, SecurityError, load

    try:
        creds = load(directory / f"{COORDINATOR}.json")
    except SecurityError as exc:
        raise ConfigError(f"--credentials: {exc} (issue them with: mhrc credentials --eval --out {directory})") from None
    login = directory / WORKER / f"{WORKER}.json"
    if creds.kind != EVAL or not creds.is_server or not login.is_file():
        raise ConfigError(f"--credentials: {directory} does not hold an evaluation's credentials (mhrc credentials --eval --out DIR)")
    return creds, login




@dataclass
class Tally:
    """The progress of one `evaluate` call: `total` episodes to run now, `done` of them ended
    (finished or given up); `before` and `before_succeeded` count the grid's episodes an earlier
    run finished (--resume), not run again."""

    total: int
    done: int = 0
    succeeded: int = 0
    errors: int = 0
    invalid: int = 0
    by_key: dict[str, dict[str, Any]] = field(default_factory=dict)
    before: int = 0
    before_succeeded: int = 0


ProgressHook = Callable[[Tally, dict[str, Any] | None], None]


WORKER_GRACE = 10.0  # s a worker that heard "done" has to finish before it is terminated
STOP_GRACE = 2.0  # s workers told to stop (SIGTERM) have before they are killed: Ctrl-C exits within 3 s


async def _reap(procs: list[subprocess.Popen[bytes]], grace: float) -> None:
    """Wait up to `grace` seconds (without blocking the loop) for `procs` to end; terminate,
    then kill, the ones still running."""
    deadline = time.monotonic() + grace
    while any(p.poll() is None for p in procs) and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    late = [p for p in procs if p.poll() is None]
    for p in late:
        p.terminate()
    deadline = time.monotonic() + min(1.0, grace)
    while any(p.poll() is None for p in late) and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
    for p in late:
        if p.poll() is None:
            p.kill()
            p.wait()


def _episode_report(trace: Path) -> None:
    """The episode's HTML report beside its trace (summary.html links it); a report that cannot
    be drawn costs a warning, never the episode's row."""
    from .viewer.show import write_report

    try:
        write_report(trace)
    except Exception as exc:
        log.warning("episode report not written", trace=str(trace), error=f"{type(exc).__name__}: {exc}")


def check_out(out: Path, spec: EvalSpec, resume: bool) -> None:
    """Raise ConfigError naming --out when DIR cannot hold this evaluation (not creatable, or
    holding another one); creates nothing, so the CLI checks it before anything starts."""
    if why := unwritable(out, directory=True):
        raise ConfigError(f"--out: {why}")
    manifest = out / "eval.json"
    if out.exists() and any(out.iterdir()):
        if not resume:
            raise ConfigError(f"--out: {out} is not empty; pass --resume to continue that evaluation, or choose another --out")
        if manifest.exists():
            old = json.loads(manifest.read_text())
            # a manifest written before a field was part of the identity ran with its default
            before = {"fidelity": "paper", "history_cap": None, "prompts": None, "mode": "free", "max_tokens": None, "llm_seed": None,
                      "schedule": "lockstep", "time_scale": 0.0}
            before |= old.get("identity") or {}
            if before != spec.identity():
                raise ConfigError(
                    f"--out: {out} holds an evaluation of {before}, not {spec.identity()}; --resume needs the same --llm, "
                    "--ablation, --horizon, --aids, --history-cap, --prompts, --structured, --max-tokens, --llm-seed, --schedule and --time-scale"
                )


def prepare_out(out: Path, spec: EvalSpec, resume: bool) -> dict[str, dict[str, Any]]:
    """Create DIR (or check it for --resume); return the rows already finished, by key."""
    check_out(out, spec, resume)
    manifest = out / "eval.json"
    out.mkdir(parents=True, exist_ok=True)
    (out / "traces").mkdir(exist_ok=True)
    manifest.write_text(json.dumps({"identity": spec.identity(), "spec": spec.__dict__}, indent=2, default=list) + "\n")
    rows = read_rows(out / "episodes.jsonl")
    if rows:  # rewrite without a torn last line, so that new rows start on a line of their own
        (out / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows), encoding="utf-8")
    return {r["key"]: r for r in rows}


async def evaluate(
    spec: EvalSpec,
    out: Path,
    *,
    workers: int = 1,
    resume: bool = False,
    listen: str | None = None,
    progress: ProgressHook | None = None,
    idle_timeout: float = 120.0,
    concurrency: int = 1,
    secure: bool = False,
    hosts: tuple[str, ...] = (),
    credentials: Path | None = None,
) -> list[dict[str, Any]]:
    """Run the grid; returns every row of DIR/episodes.jsonl (old ones too, with --resume).

    `workers` local worker processes are started, each running up to `concurrency` episodes at
    once; with `listen`, workers on other hosts may join (with workers=0 only they run
    episodes). Without any worker alive for `idle_timeout` seconds, the evaluation stops with
    an error rather than hang.

    `secure` puts the bus on TLS with logins (`mhrc.security.make_eval_credentials`): the
    coordinator's certificate names 127.0.0.1, localhost, the --listen host and `hosts`; the
    workers' login is written to DIR/credentials/worker/worker.json for as long as the
    evaluation runs (workers elsewhere need a copy). With `credentials` (a directory issued by
    `mhrc credentials --eval`) those are used instead and kept: remote workers keep one login
    across evaluations; the evaluation id is theirs."""
    if concurrency < 1:
        raise ConfigError(f"--concurrency: must be at least 1 (got {concurrency})")
    spec.validate()
    coordinator: Credentials | None = None
    worker_login: Path | None = None
    if credentials is not None:
        coordinator, worker_login = _given_credentials(credentials)
        secure = True
    if listen is not None and secure and not listen.startswith("tls/"):
        raise ConfigError(f"--listen: a secured evaluation listens on tls/ (e.g. tls/0.0.0.0:7448), not {listen}; or pass --insecure")
    if listen is not None and not secure and listen.startswith("tls/"):
        raise ConfigError(f"--listen: {listen} is tls/, which needs the evaluation's credentials: drop --insecure, or listen on tcp/")
    finished = prepare_out(out, spec, resume)
    todo = deque(j for j in spec.jobs() if j.key not in finished)
    earlier = [finished[j.key] for j in spec.jobs() if j.key in finished]
    tally = Tally(total=len(todo), before=len(earlier), before_succeeded=sum(bool(r.get("success")) for r in earlier))
    eval_id = coordinator.run if coordinator is not None else f"e{uuid.uuid4().hex[:8]}"
    keys = _keys(eval_id)
    listen = listen or endpoint("127.0.0.1", free_port("127.0.0.1"), tls=secure)
    creds_dir = own_credentials(out)
    ephemeral = secure and coordinator is None  # made for this evaluation, deleted at its end
    if ephemeral:
        from .security import COORDINATOR, WORKER, load, make_eval_credentials

        _, listen_host, _ = split_endpoint(listen)
        names = tuple(h for h in (listen_host, *hosts) if h not in ("0.0.0.0", "::", ""))
        files = make_eval_credentials(eval_id, creds_dir, hosts=names)
        coordinator, worker_login = load(files[COORDINATOR]), files[WORKER]
    issued: dict[str, tuple[Job, str, float]] = {}
    attempts: dict[str, int] = defaultdict(int)
    alive_workers: set[str] = set()
    all_done = asyncio.Event()
    aborted: list[str] = []
    if not todo:
        all_done.set()
    rows_path = out / "episodes.jsonl"

    async def on_job(_key: str, _params: dict[str, str], payload: bytes) -> JobReply:
        req = decode(payload, JobRequest)
        now = time.monotonic()
        for k, (job, _w, t0) in list(issued.items()):  # a job that takes far too long goes back
            if now - t0 > JOB_TIMEOUT:
                issued.pop(k)
                todo.append(job)
        if todo:
            job = todo.popleft()
            issued[job.key] = (job, req.worker, now)
            attempts[job.key] += 1
            return JobReply(status="job", job=job)
        return JobReply(status="wait" if issued else "done")

    def on_result(sample: Sample) -> None:
        res = decode(sample.payload, EvalResult)
        entry = issued.pop(res.key, None)
        if entry is None:
            return  # a duplicate (the job was re-issued and both ran)
        job = entry[0]
        row: dict[str, Any] | None = None
        if res.fatal:
            aborted.append(f"{res.key}: {res.error}")
            todo.clear()
            issued.clear()  # workers hear "done"; the episodes they still run would fail the same way
            all_done.set()
            return
        if res.error is None:
            trace_path = out / "traces" / (res.key.replace("/", "_") + ".jsonl")
            trace_path.write_bytes(zlib.decompress(base64.b64decode(res.trace_z)))
            try:
                trace_rows = read_trace(trace_path)
                m = from_trace(trace_rows)
                diag = diagnose(trace_rows)
            except TraceError as exc:
                res.error = f"TraceError: {exc}"
            else:
                _episode_report(trace_path)
        if res.error is not None:
            if attempts[res.key] < 2:
                todo.append(job)
                return
            tally.errors += 1
            with (out / "errors.jsonl").open("a", encoding="utf-8") as f:
                f.write(json.dumps({"key": res.key, "worker": res.worker, "error": res.error}) + "\n")
        else:
            row = {
                "key": res.key, "method": spec.method, "ablation": spec.ablation, "repeat": job.repeat, "trial": job.trial,
                **m.as_dict(), "aids": list(spec.aids), "history_cap": spec.history_cap, "mode": spec.mode,
                "max_tokens": spec.max_tokens if spec.llm else None, "llm_seed": spec.llm_seed, "schedule": spec.schedule,
                "time_scale": spec.time_scale, "worker": res.worker, "trace": str(trace_path.relative_to(out)),
                **diag.columns(),
            }  # fmt: skip
            with rows_path.open("a", encoding="utf-8") as f:
                f.write(json.dumps(row) + "\n")
            tally.succeeded += bool(m.success)
            tally.invalid += not m.valid
        tally.done += 1
        if progress is not None:
            progress(tally, row)
        if tally.done >= tally.total:
            all_done.set()

    def on_worker(sample: Sample) -> None:
        wid = sample.key.rsplit("/", 1)[1]
        if sample.is_put:
            alive_workers.add(wid)
            return
        alive_workers.discard(wid)
        for k, (job, w, _t) in list(issued.items()):
            if w == wid:
                log.warning("worker gone; its job goes back to the queue", worker=wid, job=k)
                issued.pop(k)
                todo.appendleft(job)

    procs: list[subprocess.Popen[bytes]] = []
    try:
        bus = await Bus.open(mode="router", listen=[listen], security=coordinator)
    except BaseException:
        _forget(creds_dir, ephemeral)
        raise
    try:
        bus.serve(keys["job"], on_job)
        bus.subscribe(keys["result"], on_result)
        bus.watch_liveliness(f"{keys['worker']}/*", on_worker)
        bus.declare_token(keys["coordinator"])
        if progress is not None:
            progress(tally, None)
        env = child_env(dict(os.environ, PYTHONUNBUFFERED="1"))  # workers die with the coordinator, even after a SIGKILL
        for _ in range(workers if todo else 0):
            procs.append(subprocess.Popen(worker_command(listen, eval_id, concurrency, worker_login), env=env, stdin=subprocess.DEVNULL))
        idle_since = time.monotonic()
        while not all_done.is_set():
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(all_done.wait(), timeout=1.0)
            if alive_workers or any(p.poll() is None for p in procs):
                idle_since = time.monotonic()
            elif time.monotonic() - idle_since > idle_timeout:
                raise EvalAborted(
                    f"no worker has been alive for {idle_timeout:.0f} s with {tally.total - tally.done} episodes left; "
                    f"start workers with: mhrc worker --connect {listen}"
                    + (f" --credentials {worker_login}" if worker_login else " --insecure")
                )
        await asyncio.sleep(0.5)  # let workers ask once more and hear "done"
        if aborted:
            kept = read_rows(rows_path)
            write_summaries(kept, out)
            raise EvalAborted(
                f"stopped: {aborted[0]}. Every episode would fail the same way; "
                + (f"the {len(kept)} finished episode(s) are kept in {rows_path}" if kept else "no episode finished")
                + f" (fix the cause, then continue with --resume --out {out})"
            )
    except BaseException:  # interrupted (Ctrl-C, SIGTERM) or failed: stop the workers now
        for p in procs:
            if p.poll() is None:
                p.terminate()
        await _reap(procs, STOP_GRACE)
        raise
    finally:
        await _reap(procs, WORKER_GRACE)  # the workers heard "done": they end by themselves
        await bus.close()
        _forget(creds_dir, ephemeral)
    rows = read_rows(rows_path)
    write_summaries(rows, out)
    return rows
