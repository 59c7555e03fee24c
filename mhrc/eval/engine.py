"""`mhrc eval`: the paper's benchmark grid as one command, episodes spread over processes of this
machine or over a Ray cluster, results as traces, `episodes.jsonl` and summary tables.

Where episodes run is an executor's business: by default a pool of worker processes of this
machine (mhrc.eval.pool: `--workers` processes, each up to `--concurrency` episodes at once);
with `--ray ADDRESS` each episode is a Ray task on that cluster (mhrc.eval.cluster, the `ray`
extra), with Ray's retries for a worker or node that dies. Either way an episode runs whole in
one process (its world and its agents, mhrc.eval.episode) and only its trace comes back.

Each episode's metrics and failure diagnostics (`diag_*` columns) are computed here, by the
driver, from the trace (`mhrc.core.metrics`, `mhrc.core.diagnostics`), so a row means the same thing
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
import zlib
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import structlog

from mhrc.core.diagnostics import diagnose
from mhrc.agents.llm import DEFAULT_MAX_TOKENS
from mhrc.run.config import ConfigError, EpisodeConfig
from mhrc.eval.episode import EpisodeResult, Job
from mhrc.core.fidelity import label
from mhrc.core.metrics import Invalid, TraceError, from_trace
from mhrc.eval.paper import PAPER_OBJECTS
from mhrc.eval.report import summary_csv, summary_markdown
from mhrc.eval.rows import merge_runs, read_rows
from mhrc.eval.summaries import write_summaries
from mhrc.core.trace import read_trace, unwritable
from mhrc.world.scenario import load_scenario

__all__ = ["EvalAborted", "EvalSpec", "Job", "Tally", "check_out", "evaluate", "merge_runs", "summary_csv", "summary_markdown", "write_summaries"]

log = structlog.get_logger("mhrc.eval")


class EvalAborted(RuntimeError):
    """The evaluation cannot go on (an error every episode would hit); finished rows are kept."""


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
    llm_timeout: float | None = None  # None: per spec (mhrc.run.config.EpisodeConfig.timeout_for)
    llm_idle_timeout: float | None = None  # None: mhrc.run.config.IDLE_TIMEOUT
    stream: bool = True  # False: --no-stream
    prompts: str | None = None
    repeats: int = 1  # the grid, run this many times with other seeds
    aids: tuple[str, ...] = ()  # mhrc.core.fidelity names; () is the paper's fidelity
    noise: str = "on"  # the world's motion noise (mhrc.core.fidelity.NOISE): on, the calibration, or off
    history_cap: int | None = None
    max_tokens: int = DEFAULT_MAX_TOKENS
    llm_seed: int | None = None
    structured: bool = False  # JSON decisions (not the paper's free text)
    step_deadline: float | None = None
    schedule: str = "sequential"  # the world's time policy (mhrc.run.config.SCHEDULES); the paper's loop by default
    time_scale: float = 0.0  # async: simulated seconds per wall second, 0 as fast as possible
    # a scenario (world/scenario.py), applied to every episode: a file's path, or a shipped scenario's name, which
    # travels to the workers as the name so that each (a Ray node too) reads the copy installed with its own package
    events: str | None = None

    def scenario(self) -> tuple[str, str] | tuple[None, None]:
        """The scenario's short name and sha256 (None, None without one): what rows record of it."""
        if self.events is None:
            return None, None
        sc = load_scenario(self.events)
        return sc.name, sc.sha256

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
            "method": self.method, "ablation": self.ablation, "horizon": self.horizon, "fidelity": self.fidelity, "noise": self.noise,
            "history_cap": self.history_cap, "prompts": self.prompts, "mode": self.mode,
            "max_tokens": self.max_tokens if self.llm else None, "llm_seed": self.llm_seed, "schedule": self.schedule,
            "time_scale": self.time_scale, "scenario": self.scenario()[1],
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
                                "aids": list(self.aids) or None, "noise": None if self.noise == "on" else self.noise,
                                "history_cap": self.history_cap,
                                "max_tokens": self.max_tokens, "llm_seed": self.llm_seed, "structured": self.structured or None,
                                "step_deadline": self.step_deadline, "schedule": self.schedule,
                                "time_scale": self.time_scale or None, "events": self.events,
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
                try:
                    EpisodeConfig.build(**c)
                except ConfigError as exc:  # a scenario is checked against every task and scene of the grid: say which
                    raise ConfigError(f"{exc} (in {c['task']}/{c['scene']})" if self.events else str(exc)) from None


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


STOP_GRACE = 2.0  # s episodes told to stop (an interrupt) have before their processes are killed: Ctrl-C exits within 3 s
RETRIES = 1  # an episode that fails (not fatally) is run this many more times before it is given up
# invalid episodes whose cause is the machine's, as an error is: run again like one (RETRIES); one still so after that
# is written as an invalid row, which every summary leaves out (mhrc.eval.report)
RETRIED = frozenset({Invalid.NOT_PLAYED})


class Executor(Protocol):
    """Where episodes run: mhrc.eval.pool.PoolExecutor (this machine) or mhrc.eval.cluster.RayExecutor."""

    async def __aenter__(self) -> Executor: ...
    async def __aexit__(self, *exc: object) -> None: ...
    def submit(self, job: Job) -> None: ...
    async def next(self) -> EpisodeResult: ...
    async def stop(self, grace: float) -> list[EpisodeResult]: ...


def _episode_report(trace: Path) -> None:
    """The episode's HTML report beside its trace (summary.html links it); a report that cannot
    be drawn costs a warning, never the episode's row."""
    from mhrc.viewer.show import write_report

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
            before = {"fidelity": "paper", "noise": "on", "history_cap": None, "prompts": None, "mode": "free", "max_tokens": None, "llm_seed": None,
                      "schedule": "lockstep", "time_scale": 0.0, "scenario": None}
            before |= old.get("identity") or {}
            if before != spec.identity():
                raise ConfigError(
                    f"--out: {out} holds an evaluation of {before}, not {spec.identity()}; --resume needs the same --llm, "
                    "--ablation, --horizon, --aids, --noise, --history-cap, --prompts, --structured, --max-tokens, --llm-seed, --schedule, --time-scale and --events"
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
    progress: ProgressHook | None = None,
    concurrency: int = 1,
    ray: str | None = None,
    shared_out: bool = False,
) -> list[dict[str, Any]]:
    """Run the grid; returns every row of DIR/episodes.jsonl (old ones too, with --resume).

    Locally, `workers` processes of this machine each run up to `concurrency` episodes at once
    (mhrc.eval.pool). With `ray` (an address as ray.init takes it) every episode is a Ray task
    on that cluster instead (mhrc.eval.cluster); `shared_out`: DIR is the same path on every node,
    so tasks write their traces there rather than send them back. Either way each row is
    computed here, from the episode's trace, and appended to DIR/episodes.jsonl as it arrives:
    an interrupt (cancellation) keeps every finished row."""
    if concurrency < 1:
        raise ConfigError(f"--concurrency: must be at least 1 (got {concurrency})")
    if ray is not None and workers != 1:
        raise ConfigError("--workers: the Ray cluster's resources say how many episodes run at once; drop --workers with --ray")
    if shared_out and ray is None:
        raise ConfigError("--shared-out: only with --ray (a local run writes into --out anyway)")
    if workers < 1:
        raise ConfigError(f"--workers: must be at least 1 (got {workers})")
    spec.validate()
    executor: Executor
    if ray is not None:
        from mhrc.eval.cluster import RayExecutor, import_ray, probe, shared

        import_ray()  # before --out is touched: a missing extra or an address nothing listens at leaves nothing behind
        await asyncio.to_thread(probe, ray)
        executor = RayExecutor(ray, concurrency=concurrency, llm=spec.llm is not None, traces=shared(out) if shared_out else None)
    else:
        from mhrc.eval.pool import PoolExecutor

        executor = PoolExecutor(workers, concurrency)
    async with executor:  # joins a Ray cluster before --out is touched: a cluster that refuses us leaves nothing behind
        return await _drive(spec, out, resume, executor, progress)


async def _drive(spec: EvalSpec, out: Path, resume: bool, executor: Executor, progress: ProgressHook | None) -> list[dict[str, Any]]:
    """Run the jobs of `spec` not yet in `out` on `executor`, writing each row as it arrives."""
    finished = prepare_out(out, spec, resume)
    todo = [j for j in spec.jobs() if j.key not in finished]
    earlier = [finished[j.key] for j in spec.jobs() if j.key in finished]
    tally = Tally(total=len(todo), before=len(earlier), before_succeeded=sum(bool(r.get("success")) for r in earlier))
    rows_path = out / "episodes.jsonl"
    scenario, scenario_sha256 = spec.scenario()  # every row says which scenario it ran (rows of different ones are never averaged)
    jobs = {j.key: j for j in todo}
    attempts: dict[str, int] = defaultdict(int)
    aborted: list[str] = []

    def take(res: EpisodeResult) -> tuple[Job | None, bool, dict[str, Any] | None]:
        """Write the row of a finished episode (or count a given-up one): the job to run again, if any,
        whether the episode was counted, and its row. Blocking (trace, metrics, HTML): off the loop."""
        job = jobs[res.key]
        row: dict[str, Any] | None = None
        if res.fatal:
            aborted.append(f"{res.key}: {res.error}")
            return None, False, None
        trace_path = out / "traces" / (res.key.replace("/", "_") + ".jsonl")
        if res.error is None:
            if res.trace_file is None:
                trace_path.write_bytes(zlib.decompress(res.trace_z))
            try:
                trace_rows = read_trace(trace_path)
                m = from_trace(trace_rows)
                diag = diagnose(trace_rows)
            except (TraceError, OSError) as exc:
                res.error = f"{type(exc).__name__}: {exc}"
            else:
                if m.invalid_code in RETRIED and attempts[res.key] <= RETRIES:
                    log.warning("episode invalid, running it again", key=res.key, code=m.invalid_code, reason=m.invalid_reason)
                    return job, False, None
                _episode_report(trace_path)
        if res.error is not None:
            if attempts[res.key] <= RETRIES:
                return job, False, None
            tally.errors += 1
            with (out / "errors.jsonl").open("a", encoding="utf-8") as f:
                f.write(json.dumps({"key": res.key, "worker": res.worker, "error": res.error}) + "\n")
        else:
            row = {
                "key": res.key, "method": spec.method, "ablation": spec.ablation, "repeat": job.repeat, "trial": job.trial,
                **m.as_dict(), "aids": list(spec.aids), "history_cap": spec.history_cap, "mode": spec.mode,
                "max_tokens": spec.max_tokens if spec.llm else None, "llm_seed": spec.llm_seed, "schedule": spec.schedule,
                "time_scale": spec.time_scale, "scenario": scenario, "scenario_sha256": scenario_sha256,
                "prompts": spec.prompts, "base_url": spec.base_url,  # whether the paper's figures may stand beside it (mhrc.eval.paper)
                "worker": res.worker, "trace": str(trace_path.relative_to(out)),
                **diag.columns(),
            }  # fmt: skip
            with rows_path.open("a", encoding="utf-8") as f:
                f.write(json.dumps(row) + "\n")
            tally.succeeded += bool(m.success)
            tally.invalid += not m.valid
        tally.done += 1
        return None, True, row

    def told(taken: tuple[Job | None, bool, dict[str, Any] | None]) -> Job | None:
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
        kept = read_rows(rows_path)
        await asyncio.to_thread(write_summaries, kept, out)
        raise EvalAborted(
            f"stopped: {aborted[0]}. Every episode would fail the same way; "
            + (f"the {len(kept)} finished episode(s) are kept in {rows_path}" if kept else "no episode finished")
            + f" (fix the cause, then continue with --resume --out {out})"
        )
    rows = read_rows(rows_path)
    await asyncio.to_thread(write_summaries, rows, out)
    return rows
