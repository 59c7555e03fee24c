"""`mhrc eval`: the paper's benchmark grid as one command, episodes spread over processes of this
machine or over a Ray cluster, results as traces, `episodes.jsonl` and summary tables.

Where episodes run is an executor's business: by default a pool of worker processes of this
machine (mhrc.eval.pool: `--workers` processes, each up to `--concurrency` episodes at once);
with `--ray ADDRESS` each episode is a Ray task on that cluster (mhrc.eval.cluster, the `ray`
extra), with Ray's retries for a worker or node that dies. Either way an episode runs whole in
one process (its world and its agents, mhrc.eval.episode) and only its trace comes back.

Each episode's metrics and failure diagnostics (`diag_*` columns) are computed here, by the
driver, from the trace (`mhrc.analysis.metrics`, `mhrc.analysis.diagnostics`), so a row means the same thing
whichever process or host ran it. Rows are appended to DIR/episodes.jsonl as they arrive;
`--resume` skips the keys already there. Summaries (tables, confidence intervals, the paper's
figures; summary.md, .csv and .html) are `mhrc.eval.report`'s.

The default grid is the paper's: per task, every scene with one episode per object count 3, 4,
5 and 6 (3 scenes x 4 = 12 episodes per task). Seeds: an episode's seed is
`repeat * trials + trial`, so with the default one trial, repeat r of the paper grid runs every
episode with seed r (repeat 0, seed 0, is a run without --repeats; more repeats extend it). The
job key is `task/scene/objects/seed`.
"""

from __future__ import annotations

import asyncio
import json
import shlex
import zlib
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from mhrc.analysis.metrics import Invalid
from mhrc.core.logs import get_logger
from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.core.writable import unwritable
from mhrc.eval.directory import append_text, make_dirs, refuse_links, write_bytes, write_text
from mhrc.eval.jobs import Job, WorkerResult
from mhrc.eval.records import EvalManifest, EvalRow, Settings, read_manifest, read_rows, trace_of
from mhrc.eval.report import summary_csv, summary_markdown
from mhrc.eval.rows import merge_runs
from mhrc.eval.scoring import Scored, score, write_episode_report
from mhrc.eval.spec import EvalSpec, Plan, RunOptions, identity_difference
from mhrc.eval.summaries import write_summaries
from mhrc.run.config import ConfigError, check_model_servers

__all__ = [
    "EvalAborted",
    "EvalSpec",
    "Job",
    "Plan",
    "RunOptions",
    "Tally",
    "check_out",
    "preflight",
    "resume_command",
    "evaluate",
    "merge_runs",
    "run",
    "summary_csv",
    "summary_markdown",
    "write_summaries",
]

log = get_logger("mhrc.eval")


class EvalAborted(RuntimeError):
    """The evaluation cannot go on (an error every episode would hit); finished rows are kept."""


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
    before: int = 0
    before_succeeded: int = 0
    given_up: list[str] = field(default_factory=list)  # keys of the episodes given up (errors.jsonl), in order


ProgressHook = Callable[[Tally, EvalRow | None], None]


STOP_GRACE = (
    2.0  # s episodes told to stop (an interrupt) have before their processes are killed: Ctrl-C exits within 3 s
)
RETRIES = 1  # an episode that fails (not fatally) is run this many more times before it is given up
# invalid episodes whose cause is the machine's, as an error is: run again like one (RETRIES); one still so after that
# is written as an invalid row, which every summary leaves out (mhrc.eval.report)
RETRIED = frozenset({Invalid.NOT_PLAYED})


class Executor(Protocol):
    """Where episodes run: mhrc.eval.pool.PoolExecutor (this machine) or mhrc.eval.cluster.RayExecutor."""

    async def __aenter__(self) -> Executor: ...
    async def __aexit__(self, *exc: object) -> None: ...
    def submit(self, job: Job) -> None: ...
    async def next(self) -> WorkerResult: ...
    async def stop(self, grace: float) -> list[WorkerResult]: ...


def resume_command(out: Path, *, ray: str | None = None, shared_out: bool = False) -> str:
    """The command that finishes the evaluation in `out` and nothing more: --resume takes the grid and
    every setting from its eval.json; only where the episodes run is said again."""
    where = ([f"--ray {shlex.quote(ray)}"] if ray else []) + (["--shared-out"] if shared_out else [])
    return " ".join(["mhrc eval --resume --out", shlex.quote(str(out)), *where])


def check_out(out: Path, plan: Plan, resume: bool) -> None:
    """Raise ConfigError naming --out when DIR cannot hold this evaluation (not creatable, holding
    another one, or, with --resume, holding none: a mistyped path must not start, and pay for, a
    whole grid; a file of it a symlink; a row that is no row of this grid); creates nothing, so
    the CLI checks it before anything starts."""
    if why := unwritable(out, directory=True):
        raise ConfigError(f"--out: {why}")
    manifest = out / "eval.json"
    if out.exists():
        refuse_links(out)
    if resume and not manifest.is_file():
        raise ConfigError(
            f"--resume: {out} holds no evaluation (no {manifest.name}); check the path, or leave out --resume to start one"
        )
    if out.exists() and any(out.iterdir()):
        if not resume:
            raise ConfigError(
                f"--out: {out} is not empty; pass --resume to continue that evaluation, or choose another --out"
            )
        before = read_manifest(manifest).identity  # an older manifest's missing fields: what it ran with
        if before != plan.identity:
            raise ConfigError(f"--resume: {out} holds another evaluation: {identity_difference(before, plan.identity)}")
        finished_rows(out, plan)


def preflight(plan: Plan, out: Path, options: RunOptions, resume: bool) -> None:
    """Every check an evaluation passes before it starts, for `evaluate` and `mhrc eval` alike: DIR
    (`check_out`), each team's model servers listening (ModelServerDown, as `mhrc up` checks them:
    one line now, not every episode's retries), and with Ray the extra and the cluster answering.
    Raises ConfigError naming the option; creates nothing."""
    check_out(out, plan, resume)
    for job in {j.config.team.name: j for j in plan.jobs}.values():
        check_model_servers(job.config, job.config.robots)
    if options.ray is not None:  # a missing extra, an old Ray, an address nothing answers at
        from mhrc.eval.cluster import import_ray, probe, require_ray

        require_ray()
        probe(options.ray)  # before Ray's import, which takes most of a second
        import_ray()  # its version


def finished_rows(out: Path, plan: Plan) -> dict[str, EvalRow]:
    """The rows DIR holds, by key, each validated (`read_rows`) and of this plan's grid and
    setting: a row outside the grid, or run with another method, ablation or horizon, is a
    ConfigError naming its line, never counted."""
    path = out / "episodes.jsonl"
    rows = read_rows(path, {j.key for j in plan.jobs})
    spec = plan.spec
    for r in rows:
        s, horizon = r.settings, r.metrics.horizon
        if (s.method, s.ablation) != (spec.method, spec.ablation) or horizon not in (None, spec.horizon):
            raise ConfigError(
                f"{path}: episode {r.key} ran {s.method}, ablation {s.ablation}, horizon {horizon}: "
                "not this evaluation's"
            )
    return {r.key: r for r in rows}


def prepare_out(out: Path, plan: Plan) -> dict[str, EvalRow]:
    """Create DIR (checked by `check_out`) and write its manifest; return the rows already finished, by key."""
    make_dirs(out)
    refuse_links(out)
    finished = finished_rows(out, plan)
    write_text(out / "eval.json", EvalManifest(identity=plan.identity, spec=plan.spec).text())
    if finished:  # rewrite without a torn last line, so that new rows start on a line of their own
        write_text(out / "episodes.jsonl", "".join(r.line() for r in finished.values()))
    return finished


async def evaluate(
    spec: EvalSpec | Plan,
    out: Path,
    *,
    workers: int = 1,
    resume: bool = False,
    progress: ProgressHook | None = None,
    concurrency: int = 1,
    ray: str | None = None,
    shared_out: bool = False,
) -> list[EvalRow]:
    """Check everything once (the options, the grid, DIR), then `run` the grid; returns every row
    of DIR/episodes.jsonl (old ones too, with --resume).

    Locally, `workers` processes of this machine each run up to `concurrency` episodes at once
    (mhrc.eval.pool). With `ray` (an address as ray.init takes it) every episode is a Ray task
    on that cluster instead (mhrc.eval.cluster); `shared_out`: DIR is the same path on every node,
    so tasks write their traces there rather than send them back."""
    options = RunOptions(
        workers=None if ray is not None and workers == 1 else workers,
        concurrency=concurrency,
        ray=ray,
        shared_out=shared_out,
    )
    plan = spec if isinstance(spec, Plan) else spec.validate()
    preflight(plan, out, options, resume)
    return await run(plan, out, options, resume=resume, progress=progress)


async def run(
    plan: Plan, out: Path, options: RunOptions, *, resume: bool = False, progress: ProgressHook | None = None
) -> list[EvalRow]:
    """Run a plan already checked (`evaluate`, or the CLI: the options, the grid, then `preflight`):
    each row is computed here, from the episode's trace, and appended to DIR/episodes.jsonl as it
    arrives; an interrupt (cancellation) keeps every finished row."""
    executor: Executor
    if options.ray is not None:
        from mhrc.eval.cluster import RayExecutor, shared

        traces = shared(out) if options.shared_out else None
        executor = RayExecutor(
            options.ray, concurrency=options.concurrency or 1, llm=plan.spec.llm is not None, traces=traces
        )
    else:
        from mhrc.eval.pool import PoolExecutor

        executor = PoolExecutor(options.processes, options.concurrency or 1)
    async with executor:  # joins a Ray cluster before --out is touched: a cluster that refuses us (or a missing extra) leaves nothing behind
        return await _drive(plan, out, resume, executor, progress)


def _row(plan: Plan, job: Job, res: WorkerResult, scored: Scored, out: Path) -> EvalRow:
    """The row of a finished episode: the evaluation's settings, the metrics and the diagnostics."""
    spec = plan.spec
    settings = Settings(
        method=spec.method,
        ablation=spec.ablation,
        aids=list(spec.aids),
        history_cap=spec.history_cap,
        mode=spec.mode,
        max_tokens=spec.max_tokens if spec.llm else None,
        llm_seed=spec.llm_seed,
        schedule=spec.schedule,
        time_scale=spec.time_scale,
        scenario=plan.scenario,
        scenario_sha256=plan.scenario_sha256,
        prompts=spec.prompts,
        base_url=spec.base_url,  # whether the paper's figures may stand beside it (mhrc.eval.paper)
        # the paper's protocol is not written: its rows stay as they were (a row without one ran it)
        **({} if job.config.protocol == DEFAULT_PROTOCOL else {"protocol": job.config.protocol}),
    )
    return EvalRow(
        key=res.key,
        repeat=job.repeat,
        trial=job.trial,
        settings=settings,
        metrics=scored.metrics,
        diagnostics=scored.diagnostics,
        worker=res.worker,
        trace=str(scored.path.relative_to(out)),
    )


async def _drive(
    plan: Plan, out: Path, resume: bool, executor: Executor, progress: ProgressHook | None
) -> list[EvalRow]:
    """Run the jobs of `plan` not yet in `out` on `executor`, writing each row as it arrives."""
    finished = prepare_out(out, plan)
    todo = [j for j in plan.jobs if j.key not in finished]
    earlier = [finished[j.key] for j in plan.jobs if j.key in finished]
    tally = Tally(total=len(todo), before=len(earlier), before_succeeded=sum(r.metrics.success for r in earlier))
    rows_path = out / "episodes.jsonl"
    jobs = {j.key: j for j in todo}
    attempts: dict[str, int] = defaultdict(int)
    aborted: list[str] = []

    def take(res: WorkerResult) -> tuple[Job | None, bool, EvalRow | None]:
        """Write the row of a finished episode (or count a given-up one): the job to run again, if any,
        whether the episode was counted, and its row. Blocking (trace, metrics, HTML): off the loop."""
        job = jobs[res.key]
        if res.fatal:
            aborted.append(f"{res.key}: {res.error}")
            return None, False, None
        trace_path = out / trace_of(res.key)
        scored: Scored | None = None
        if res.error is None:
            if res.trace_file is None:
                write_bytes(trace_path, zlib.decompress(res.trace_z))
            try:
                scored = score(trace_path)  # the trace read once; metrics and diagnostics computed once
            except (ValueError, OSError) as exc:  # TraceError, a line that is not JSON, a file gone
                res.error = f"{type(exc).__name__}: {exc}"
            else:
                m = scored.metrics
                if m.invalid_code in RETRIED and attempts[res.key] <= RETRIES:
                    log.warning(
                        "episode invalid, running it again", key=res.key, code=m.invalid_code, reason=m.invalid_reason
                    )
                    return job, False, None
                write_episode_report(scored)
        if scored is None:
            if attempts[res.key] <= RETRIES:
                return job, False, None
            tally.errors += 1
            tally.given_up.append(res.key)
            append_text(
                out / "errors.jsonl", json.dumps({"key": res.key, "worker": res.worker, "error": res.error}) + "\n"
            )
            tally.done += 1
            return None, True, None
        row = _row(plan, job, res, scored, out)
        append_text(rows_path, row.line())
        tally.succeeded += row.metrics.success
        tally.invalid += not row.valid
        tally.done += 1
        return None, True, row

    def told(taken: tuple[Job | None, bool, EvalRow | None]) -> Job | None:
        """Report a counted episode to `progress` (on the loop); the job to run again, if any."""
        again, counted, row = taken
        if counted and progress is not None:
            progress(tally, row)
        return again

    if progress is not None:
        progress(tally, None)
    if todo:
        for job in todo:
            attempts[job.key] += 1
            executor.submit(job)
        outstanding = len(todo)
        try:
            while outstanding and not aborted:
                res = await executor.next()
                outstanding -= 1
                again = told(await asyncio.to_thread(take, res))  # one at a time: take's state is never shared
                if again is not None:
                    attempts[again.key] += 1
                    executor.submit(again)
                    outstanding += 1
        except BaseException:  # interrupted (Ctrl-C, SIGTERM) or failed: stop the episodes, keep what finished
            for res in await asyncio.shield(executor.stop(STOP_GRACE)):
                told(take(res))  # on the loop: it is being stopped, and must not lose these rows to a second cancel
            raise
        if aborted:
            for res in await executor.stop(STOP_GRACE):
                if not res.fatal and res.error is None:
                    told(await asyncio.to_thread(take, res))
    if aborted:
        kept = read_rows(rows_path, {j.key for j in plan.jobs})
        await asyncio.to_thread(write_summaries, kept, out)
        raise EvalAborted(
            f"stopped: {aborted[0]}. Every episode would fail the same way; "
            + (f"the {len(kept)} finished episode(s) are kept in {rows_path}" if kept else "no episode finished")
            + f" (fix the cause, then continue with: {resume_command(out)})"
        )
    rows = read_rows(rows_path, {j.key for j in plan.jobs})
    await asyncio.to_thread(write_summaries, rows, out)
    return rows
