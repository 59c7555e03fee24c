"""`mhrc up`: a whole episode (the world and every robot's agent), then its metrics.

The world, the agents and the console are imported inside the command: `mhrc --help` and the
bus tools stay light.
"""

from __future__ import annotations

import functools
import json
import sys
from pathlib import Path
from typing import Any

import click

from mhrc.cli.options import (
    OPEN_BUS,
    OVERWRITE,
    VIDEO_HELP,
    VIDEO_SIZE,
    episode_config,
    episode_options,
    fresh_trace,
    llm_options,
    rerun_option,
)
from mhrc.cli.rerun_view import both, close_live, keep_serving, start_live
from mhrc.cli.running import run_command
from mhrc.core.deadlines import ATTACH_TIMEOUT


@click.command()
@episode_options
@click.option("--processes", is_flag=True, help="Run the world and each agent as separate OS processes.")
@click.option(
    "--external",
    multiple=True,
    metavar="ROBOT",
    help="Do not start an agent for this robot (a robot of --team): attach your own with `mhrc agent` (repeatable).",
)
@click.option("--quiet", "-q", is_flag=True, help="Print only the final summary table (errors still go to stderr).")
@click.option(
    "--start-timeout",
    type=float,
    default=None,
    help="Start with the robots attached after this many seconds (fail if none is); default: wait for all of them.",
)
@click.option(
    "--attach-timeout",
    type=float,
    default=None,
    help="Seconds each agent waits for the world to answer its attach, at the start and whenever the world falls "
    f"silent, before it gives up on it [default: {ATTACH_TIMEOUT:g}].",
)
@click.option(
    "--secure/--insecure",
    "secure",
    default=True,
    show_default=True,
    help="--secure (the default): fresh credentials in runs/RUN/credentials/ (TLS, a login per participant, "
    "access control: an agent can act only as its own robot); --insecure: the open tcp bus, for loopback experiments.",
)
@click.option(
    "--json",
    "as_json",
    is_flag=True,
    help="Print the run id, the trace path, why the episode ended and the final metrics as one JSON object on stdout "
    "(docs/quickstart.md names every key).",
)
@click.option("--tick-delay", default=0.0, type=float, help="Seconds to pause between ticks (to watch with --gui).")
@click.option(
    "--video",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help=VIDEO_HELP + " Rendered from the trace when the episode ends, so the run itself is not slowed.",
)
@rerun_option()
@VIDEO_SIZE
@OVERWRITE
@llm_options
def up(
    processes: bool,
    external: tuple[str, ...],
    quiet: bool,
    as_json: bool,
    log_level: str,
    video: Path | None,
    video_size: tuple[int, int],
    secure: bool,
    rerun: Any,
    overwrite: bool,
    **values: Any,
) -> None:
    """Run one episode: the world and the three robot agents, then print the metrics."""  # noqa: D401
    from mhrc.core import logs  # structlog: imported once the command line is accepted

    logs.configure(log_level)
    cfg = episode_config(**values)  # a value refused here costs no import of the bus, the trace or the console
    from rich.console import Console

    from mhrc.core.endpoints import ListenError, check_listen
    from mhrc.core.protocol.events import DEFAULT_PROTOCOL
    from mhrc.core.trace import TraceWriteError
    from mhrc.run.config import ConfigError, ModelServerDown, check_model_servers
    from mhrc.run.console import ProgressPrinter, summary_table
    from mhrc.run.coordinated import check_seating
    from mhrc.run.errors import ProcessFailed
    from mhrc.run.inprocess import up_in_process
    from mhrc.world.service_config import NobodyAttached

    if unknown := [r for r in external if r not in cfg.robots]:
        raise click.BadParameter(
            f"{', '.join(unknown)} not in this episode's team (robots: {', '.join(cfg.robots)})",
            param_hint="--external",
        )
    if external and cfg.coordination().whole_team:
        raise click.BadParameter(
            f"protocol {cfg.protocol!r} drives every robot from one planner: none can be external (mhrc protocols)",
            param_hint="--external",
        )
    if video is not None and video.suffix.lower() not in (".mp4", ".gif"):
        raise click.BadParameter(f"{video.name}: the video must be a .mp4 or .gif file", param_hint="--video")
    robots = tuple(r for r in cfg.robots if r not in external)
    try:
        check_seating(cfg, robots)  # a whole-team protocol drives every robot from here: none external
    except ConfigError as exc:  # the command line asks for what the protocol cannot seat: a usage error
        raise click.UsageError(str(exc)) from None
    try:
        check_model_servers(cfg, robots)  # before anything is written or started
        cfg.check_replays(robots)
    except (ModelServerDown, ConfigError) as exc:
        click.echo(f"mhrc up: {exc}", err=True)
        sys.exit(2)
    fresh_trace("up", cfg, overwrite, values.get("trace") is not None)  # before the credentials are made anew
    try:  # a port taken is one line before anything is announced or written (credentials included)
        check_listen(cfg.host, cfg.port, "tls" if secure else "tcp")
    except ListenError as exc:
        click.echo(f"mhrc: {exc}", err=True)
        sys.exit(2)
    if not secure:
        click.echo(OPEN_BUS, err=True)
    else:
        cfg = cfg.with_credentials()
        if not quiet:
            click.echo(f"credentials in {cfg.credentials} (TLS, one login per participant, access control)", err=True)
    console = Console(highlight=False, stderr=as_json, soft_wrap=True)
    printer = (
        None if quiet else ProgressPrinter(console, summary=False)
    )  # the table is printed below, once the run returned
    if not quiet:
        console.print(f"world on {cfg.endpoint}, run {cfg.run}, trace {cfg.trace}")
    if external:  # needed to go on at all: said with --quiet too, on stderr
        click.echo(
            "attach the external robots with: "
            + "; ".join(
                f"mhrc agent --robot {r} --run {cfg.run} --connect {cfg.endpoint}"
                + (f" --protocol {cfg.protocol}" if cfg.protocol != DEFAULT_PROTOCOL else "")
                + (f" --credentials {cfg.credentials_file(r)}" if cfg.credentials else "")
                for r in external
            ),
            err=quiet or as_json,
        )
    if processes:
        from mhrc.run.processes import up_processes

        runner: Any = functools.partial(up_processes, quiet=quiet)
    else:
        runner = up_in_process
    live = None if rerun is None else start_live(rerun, cfg.run, "up")  # fed from the bus as the episode runs
    observe = both(None if printer is None else printer.attach, None if live is None else live.observe)
    from mhrc.agents.agent import AgentError
    from mhrc.agents.llm import LLMError
    from mhrc.agents.replay import ReplayMismatch
    from mhrc.core.team import TeamError

    try:
        done = run_command(
            lambda: runner(cfg, observe=observe, robots=robots),
            interrupted=lambda: _interrupted(cfg.trace, printer),
        )
    except (
        AgentError,
        LLMError,
        ReplayMismatch,
        TeamError,
    ) as exc:  # an agent could not play (its model, its replay, the world), or the layout cannot place the team
        click.echo(f"mhrc up: {exc}", err=True)
        sys.exit(2)
    except (NobodyAttached, TraceWriteError) as exc:
        click.echo(f"mhrc up: {exc}", err=True)
        sys.exit(1)
    except ProcessFailed as exc:
        if exc.returncode <= 0:  # killed, or gone without a word (a positive code: the process said why on stderr)
            click.echo(f"mhrc up: {exc}", err=True)
        sys.exit(exc.returncode if exc.returncode > 0 else 1)
    finally:
        if live is not None:
            close_live(live, "up")
    if printer is not None:
        printer.close()  # what arrived late for its tick, then nothing more: the table is the last line
    recovery = _recovery(cfg.trace) if cfg.events is not None else None
    console.print(summary_table(done, recovery, _lost(cfg.trace), protocol=cfg.protocol))
    if video is not None and cfg.trace is not None:
        from mhrc.cli.viewer import render_video_to

        path = render_video_to(cfg.trace, video, video_size)
        if not quiet:
            console.print(f"video {path}")
    if as_json:  # the metrics, and which run and trace they are of (docs/quickstart.md lists every key)
        trace = None if cfg.trace is None else str(cfg.trace)
        head = {"run": done.run, "reason": done.reason, "trace": trace}
        if cfg.protocol != DEFAULT_PROTOCOL:  # the paper's own run prints what it always printed
            head["protocol"] = cfg.protocol
        click.echo(json.dumps({**head, **done.metrics.model_dump()}))
    if live is not None:
        keep_serving(live.viewer)


def _interrupted(trace: Path | None, printer: Any) -> str:
    """The one line of an interrupted `mhrc up`: the last tick the world closed, and where its trace is."""
    from mhrc.core.protocol import EpisodeStarted, TickClosed
    from mhrc.core.records import messages, read_records

    if printer is not None:
        printer.mute()  # what the episode's end still sends (robots leaving) is not news after Ctrl-C
    try:
        records = read_records(trace) if trace is not None else []
    except (ValueError, OSError):
        records = []
    if not messages(records, EpisodeStarted):
        when = "before the episode started"
    else:
        when = f"at tick {max((t.tick for t in messages(records, TickClosed)), default=-1) + 1}"
    where = f"the trace is at {trace}" if trace is not None and trace.exists() else "no trace was written"
    return f"interrupted {when}, {where}"


def _recovery(trace: Path | None) -> list[dict[str, Any]] | None:
    """A scenario's events as the metrics score them (mhrc.analysis.metrics), read back from the trace."""
    from mhrc.analysis.metrics import from_trace
    from mhrc.core.records import read_records

    if trace is None or not trace.exists():
        return None
    try:
        return from_trace(read_records(trace)).recovery
    except (
        ValueError,
        OSError,
    ):  # a trace the metrics cannot read (TraceError, bad JSON): the table goes without the row
        return None


def _lost(trace: Path | None) -> list[Any]:
    """The robots lost mid-episode (mhrc.run.console.lost_robots), read back from the trace."""
    from mhrc.core.records import read_records
    from mhrc.run.console import lost_robots

    if trace is None or not trace.is_file():
        return []
    try:
        return lost_robots(read_records(trace))
    except (ValueError, OSError):  # a trace that cannot be read: the table goes without the row
        return []
