"""`mhrc eval`: the paper's benchmark on this machine or a Ray cluster (`mhrc report` is beside it)."""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from mhrc.cli.names import TASKS, check_protocol, check_scene, check_task, unknown_team
from mhrc.cli.options import (
    ABLATIONS,
    AIDS_HELP,
    EVENTS_HELP,
    LOG_LEVEL,
    NOISE_HELP,
    SCHEDULE_HELP,
    SCHEDULES,
    TEAM_HELP,
    TIME_SCALE_HELP,
    events_option,
    llm_options,
    rerun_option,
)
from mhrc.cli.running import run_command
from mhrc.core.aids import NOISE
from mhrc.core.plural import counted
from mhrc.run.errors import ConfigError, ModelServerDown  # the bus and the model clients: imported in eval_

if TYPE_CHECKING:
    from mhrc.eval.records import EvalRow


def _csv(kind: type, text: str | None) -> tuple[Any, ...] | None:
    if text is None:
        return None
    try:
        return tuple(kind(x.strip()) for x in text.split(",") if x.strip())
    except ValueError:
        raise click.BadParameter(f"expected a comma-separated list, got {text!r}") from None


def _each(check: Callable[[click.Context, click.Parameter, str], object]) -> Callable[..., str | None]:
    """A comma-separated list's callback: each name checked as `check` checks one (mhrc.cli.names),
    before anything heavy is imported; the list itself is returned as given."""

    def callback(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
        for name in (value or "").split(","):
            if name.strip():
                check(ctx, param, name.strip())
        return value

    return callback


def _teams(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> Any:
    """Each --team read into a TeamSpec before anything starts; a bad one is one line naming it
    (a name that is no team, file or inline team before the teams' registry is imported)."""
    for v in value:
        if why := unknown_team(v):
            raise click.UsageError(why)
    from mhrc.core.team import TeamError
    from mhrc.run.teams import resolve_team

    try:
        return tuple(resolve_team(v) for v in value)
    except TeamError as exc:
        raise click.UsageError(str(exc)) from None


def _protocols(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> tuple[str, ...]:
    """Each --protocol (repeatable, or a comma-separated list) a protocol's name, before anything
    heavy is imported; the names in the order given."""
    names = tuple(n.strip() for v in value for n in v.split(",") if n.strip())
    for name in names:
        check_protocol(ctx, param, name)
    return names


def _setting(spec: Any) -> str:
    """The fidelity, the noise when off, the schedule and the scenario: what sets the grid apart from the paper's."""
    scenario = spec.scenario()[0]
    return (
        f"fidelity {spec.fidelity}"
        + (", noise off" if spec.noise == "off" else "")
        + f", {spec.schedule} schedule"
        + (f", scenario {scenario}: not the paper's" if scenario else "")
    )


def _ended(row: EvalRow | None, t: Any) -> str:
    """One episode that ended, in a line: its key and result (a row), or the last one given up (no row)."""
    if row is None:
        return f"{t.given_up[-1]}: given up (errors.jsonl)"
    m = row.metrics
    if not m.valid:
        return f"{row.key}: invalid ({m.invalid_reason}), left out of the summary"
    result = "solved" if m.success else f"not solved (PS {m.partial_success:.2f})"
    return f"{row.key}: {result}, TS {m.temporal_steps}"


@click.command("eval")
@llm_options
@click.option(
    "--tasks",
    default=None,
    callback=_each(check_task),
    help="Comma-separated task ids; default: every registered task.",
)
@click.option(
    "--scenes",
    default=None,
    callback=_each(check_scene),
    help="Comma-separated layouts; default: every built-in layout.",
)
@click.option(
    "--objects",
    default=None,
    show_default="3,4,5,6",
    help="Comma-separated object counts (each scene runs every count).",
)
@click.option(
    "--trials",
    default=1,
    show_default=True,
    type=int,
    help="Episodes per task, scene and object count in each repeat (the paper: 1).",
)
@click.option(
    "--repeats",
    default=1,
    show_default=True,
    type=int,
    help="Run the grid this many times; an episode's seed is repeat x trials + trial, so repeat r of the paper grid uses seed r.",
)
@click.option(
    "--team",
    "teams",
    multiple=True,
    metavar="TEAM",
    callback=_teams,
    help=TEAM_HELP.removesuffix("Default: paper (Alice, Bob and David).")
    + "Repeat it to compare teams: the team is an axis of the grid, like the task and the scene; summaries never "
    "average across teams. Default: paper (Alice, Bob and David) only.",
)
@click.option(
    "--protocol",
    "protocols",
    multiple=True,
    metavar="NAME",
    callback=_protocols,
    help="How the team decides, a coordination protocol (mhrc protocols; docs/protocols.md). Repeat it (or give a "
    "comma-separated list) to compare protocols: an axis of the grid like --team, every team running the same "
    "episodes under each; rows record it and summaries never average across protocols. Default: mhrc, the paper's, only.",
)
@click.option("--ablation", default="none", show_default=True, type=click.Choice(ABLATIONS))
@click.option("--horizon", default=50, show_default=True, type=int)
@click.option("--aids", default=None, metavar="NAMES", help=AIDS_HELP)
@click.option(
    "--noise",
    default="on",
    show_default=True,
    type=click.Choice(list(NOISE)),
    help=NOISE_HELP + " Rows and summaries keep --noise off apart from the default.",
)
@click.option(
    "--schedule",
    default="sequential",
    show_default=True,
    type=click.Choice(SCHEDULES),
    help=SCHEDULE_HELP + " The paper's figures are shown beside sequential runs only.",
)
@click.option("--time-scale", default=0.0, show_default=True, type=float, help=TIME_SCALE_HELP)
@events_option(
    EVENTS_HELP
    + " Applied to every episode of the grid; rows record the scenario, and summaries never average different ones."
)
@click.option(
    "--workers",
    default=None,
    type=int,
    show_default="the number of cores",
    help="Local worker processes (not with --ray: the cluster's resources decide).",
)
@click.option(
    "--concurrency",
    default=None,
    type=int,
    help="Episodes each local worker runs at once (with --ray: an LLM episode takes 1/concurrency of a CPU). Default: 1 for the "
    "heuristic (CPU-bound), replays and gguf: models; with a model server, enough episodes to fill its slots "
    "(llama.cpp's /props), else 12 for openai and vllm, 1 for ollama and lmstudio.",
)
@click.option(
    "--ray",
    "ray_address",
    default=None,
    metavar="ADDRESS",
    help="Run every episode as a task on this Ray cluster: auto (a node of the cluster), HOST:PORT (the head, e.g. "
    '10.0.0.5:6379) or ray://HOST:10001. Needs the extra: pip install -e ".[ray]".',
)
@click.option(
    "--shared-out",
    is_flag=True,
    help="With --ray: --out is the same path on every node (a shared file system), so tasks write their traces there "
    "instead of sending them back through the object store.",
)
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Output directory; default runs/eval-<time>.",
)
@click.option("--resume", is_flag=True, help="Continue the evaluation in --out, skipping finished episodes.")
@click.option("--dry-run", is_flag=True, help="Print the episodes the grid holds (key, repeat, seed) and exit.")
@rerun_option(
    help="Write one Rerun recording per episode into DIR, at its trace's place (DIR = --out: beside each trace); "
    "pip install 'mhrc[rerun]'.",
    metavar="DIR",
    directory=True,
)
@LOG_LEVEL
def eval_(
    tasks: str | None,
    scenes: str | None,
    objects: str | None,
    trials: int,
    repeats: int,
    teams: tuple[Any, ...],
    protocols: tuple[str, ...],
    ablation: str,
    horizon: int,
    aids: str | None,
    noise: str,
    schedule: str,
    time_scale: float,
    events: str | None,
    workers: int | None,
    concurrency: int | None,
    ray_address: str | None,
    shared_out: bool,
    out: Path | None,
    resume: bool,
    dry_run: bool,
    rerun: Any,
    log_level: str,
    **llm: Any,
) -> None:
    """Run the paper's benchmark and write, to --out, one trace per episode, episodes.jsonl
    (every metric of every episode, its fidelity and the LLM failures that shaped it) and
    summary.md / summary.csv (tables shaped like the paper's Table I and II with 95% bootstrap
    intervals, the paper's figures beside a matching configuration, TS next to its lower bound)
    and summary.html (the tables, plots, a link to each episode's report).

    The default grid is the paper's: per task, 3 scenes x one episode each with 3, 4, 5 and 6
    objects (12 per task, 36 in all); --repeats N runs it N times with other seeds, --objects and
    --trials build larger grids, --team (repeatable) runs the grid for each team and --protocol
    (repeatable) for each coordination protocol. Without --llm the heuristic policy plays. Episodes run in
    --workers processes of this machine, or with --ray ADDRESS as tasks on a Ray cluster
    (`ray start --head` on one host, `ray start --address HEAD:6379` on the others; see
    docker/README.md). An interrupted run continues with --resume --out DIR."""
    from mhrc.core import logs  # structlog: imported once the command line is accepted
    from mhrc.core.aids import AidsError, parse_aids
    from mhrc.eval.paper import PAPER_OBJECTS
    from mhrc.eval.spec import EvalSpec, RunOptions
    from mhrc.world.scene_files import scene_files

    logs.configure(log_level)
    try:  # every option checked once, here: the engine and the workers take what these checks made
        options = RunOptions(workers=workers, concurrency=concurrency, ray=ray_address, shared_out=shared_out)
        aid_names = parse_aids(aids)
    except (ConfigError, AidsError) as exc:
        raise click.UsageError(str(exc)) from None
    prompts = llm.pop("prompts")
    spec = EvalSpec(
        tasks=_csv(str, tasks) or TASKS,  # the registry's, in its order (cli.names; a test keeps them equal)
        scenes=_csv(str, scenes) or tuple(scene_files()),
        objects=PAPER_OBJECTS if objects is None else (_csv(int, objects) or ()),
        trials=trials,
        repeats=repeats,
        ablation=ablation,
        horizon=horizon,
        prompts=str(prompts) if prompts else None,
        aids=aid_names,
        noise=noise,
        schedule=schedule,
        time_scale=time_scale,
        events=events,
        **({"teams": teams} if teams else {}),
        **({"protocols": protocols} if protocols else {}),
        **llm,
    )
    out = out or Path("runs") / time.strftime("eval-%Y%m%d-%H%M%S")
    if resume:  # the grid and every setting are the directory's (eval.json); options given beside must agree
        from mhrc.eval.resume import SPEC_OPTIONS, resumed_spec

        ctx = click.get_current_context()
        given = {
            name
            for name in SPEC_OPTIONS
            if ctx.get_parameter_source(name) not in (None, click.core.ParameterSource.DEFAULT)
        }
        try:
            spec = resumed_spec(out, spec, given)
        except ConfigError as exc:
            raise click.UsageError(str(exc)) from None
    try:
        plan = spec.validate()
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
    # the command line is accepted: now the engine (the runner, the bus, the summaries) and the console
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from mhrc.eval.engine import EvalAborted, Tally, preflight, resume_command, run
    from mhrc.eval.summaries import SUMMARY_FILES

    console = Console(stderr=True)
    console.soft_wrap = not console.is_terminal  # a log file's lines are not cut at 80 columns
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        disable=not console.is_terminal,  # off a terminal: one line per episode (hook), never a bar
    )
    bar = progress.add_task("episodes", total=None)

    def hook(t: Tally, row: EvalRow | None) -> None:
        # the whole grid: with --resume, the episodes an earlier run finished count too
        rate = f"{t.before_succeeded + t.succeeded}/{t.before + t.done} solved" + (
            f", {t.errors} errors" if t.errors else ""
        )
        rate += f", {t.invalid} invalid" if t.invalid else ""
        if t.before:
            rate += " (all from before)" if t.total == 0 else f" ({t.before} from before)"
        progress.update(
            bar, total=t.before + t.total, completed=t.before + t.done, description=f"{spec.method} [{rate}]"
        )
        if not console.is_terminal:  # CI, nohup, | tee: no bar to watch, so one line per finished episode
            if row is None and not t.done and t.before:  # the first call of a resume: what was done before
                progress.console.print(f"{spec.method} [{rate}]", markup=False)
            if row is not None or t.done:  # (the first call, before any episode ended, has neither)
                progress.console.print(f"{_ended(row, t)} ({t.before + t.done}/{t.before + t.total})", markup=False)
        elif row is not None and not row.metrics.valid:
            progress.console.print(
                f"[red]invalid[/]: {row.key} ({row.metrics.invalid_reason}); left out of the summary"
            )
        elif row is not None and not row.metrics.success:
            m = row.metrics
            progress.console.print(
                f"[yellow]not solved[/]: {row.key} (PS {m.partial_success:.2f}, TS {m.temporal_steps})"
            )

    n_jobs = len(plan.jobs)
    if dry_run:
        for job in plan.jobs:
            click.echo(f"{job.key} repeat={job.repeat} trial={job.trial} seed={job.config.seed}")
        click.echo(f"{counted(n_jobs, 'episode')} ({_setting(spec)})")
        return
    try:  # --out first, nothing created (a mistyped --resume path must not start, and pay for, a whole grid), then
        preflight(plan, out, options, resume)  # the model servers and the Ray cluster: what evaluate checks too
    except ModelServerDown as exc:  # one line now, as mhrc up says it, not after every episode's retries
        click.echo(f"mhrc eval: {exc}", err=True)
        sys.exit(2)
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
    rows_path = out / "episodes.jsonl"

    advice = resume_command(out, ray=ray_address, shared_out=shared_out)

    def stopping() -> str:
        """What the first Ctrl-C says, once: the bar stops first, so no stale bar is drawn after it."""
        progress.stop()
        return "stopping the workers"

    def interrupted() -> str:
        """The last line, once the workers are stopped: where the finished episodes are, and the command
        that finishes the grid (without the word "interrupted", which the first line said)."""
        progress.stop()
        kept = rows_path.is_file() and rows_path.stat().st_size > 0
        where = f"every finished episode is kept in {rows_path}" if kept else "no episode finished"
        return f"stopped: {where}; finish the grid with: {advice}"

    if concurrency is None:
        from mhrc.agents.llm import episodes_at_once

        specs = plan.jobs[0].config.robot_specs().values() if spec.llm else [None]
        import asyncio

        concurrency = asyncio.run(episodes_at_once(list(specs), spec.base_url))
        options = dataclasses.replace(options, concurrency=concurrency)
    where = f"on the Ray cluster at {ray_address}" if ray_address else f"with {counted(options.processes, 'worker')}"
    console.print(
        f"evaluating {spec.method} (ablation {ablation}, {_setting(spec)}, {spec.mode} replies"
        f"{'' if not teams else ', teams ' + ', '.join(t.name for t in spec.teams)}"
        f"{'' if not protocols else ', protocols ' + ', '.join(spec.protocols)}) on {counted(n_jobs, 'episode')} "
        f"into {out} {where}, {counted(concurrency, 'episode')} at once each"
    )
    t0 = time.perf_counter()
    with progress:
        try:
            rows = run_command(
                lambda: run(plan, out, options, resume=resume, progress=hook),
                stopping=stopping,
                interrupted=interrupted,
            )
        except ConfigError as exc:
            raise click.UsageError(str(exc)) from None
        except EvalAborted as exc:
            raise click.ClickException(str(exc)) from None
    written = [p for p in (rows_path, *(out / name for name in SUMMARY_FILES)) if p.exists()]
    errors = out / "errors.jsonl"
    console.print(
        f"done in {time.perf_counter() - t0:.1f} s: "
        + (", ".join(map(str, written)) if rows else "no episode finished")
        + (f" (episodes given up: {errors})" if errors.exists() else "")
    )
    if rerun is not None and rows:
        from mhrc.cli.rerun_view import eval_recordings

        made = eval_recordings(
            (out / r.trace for r in rows if r.trace), rerun.path, out
        )  # validated rows: traces/ files
        console.print(f"{len(made)} rerun recording(s) in {rerun.path}")
    if rows:
        click.echo((out / "summary.md").read_text(encoding="utf-8"))  # the summary written, not computed again
