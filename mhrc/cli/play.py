"""`mhrc play`: a person drives one robot from a browser page beside the AI teammates.

The page's server and the episode are imported inside the command: `mhrc --help` stays light.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from mhrc.cli.options import (
    INSECURE_HELP,
    OVERWRITE,
    credentials_option,
    episode_config,
    episode_options,
    fresh_trace,
    llm_options,
    load_credentials,
    open_bus_notice,
)
from mhrc.cli.running import run_command


def _page_port_not_world_port(f: Callable[..., Any]) -> Callable[..., Any]:
    """`mhrc up`'s episode options, with the world's --port as --world-port: --port is the page's."""
    f = episode_options(f)
    f.__click_params__ = [p for p in f.__click_params__ if p.name != "port"]  # type: ignore[attr-defined]
    return click.option(
        "--world-port", "world_port", default=0, type=int, help="Port the world listens on; default: a free one."
    )(f)


@click.command()
@click.option("--robot", required=True, help="The robot you drive (a robot of --team; the paper's alice, bob, david).")
@click.option("--port", "page_port", default=0, type=int, help="Port of the page on 127.0.0.1; default: a free one.")
@click.option("--no-browser", is_flag=True, help="Print the page's address, do not open the default browser.")
@click.option(
    "--connect",
    default=None,
    metavar="ENDPOINT",
    help="Drive the robot of a world started elsewhere (mhrc up --external ROBOT, mhrc world) at this endpoint, "
    "e.g. tls/127.0.0.1:7447; the episode options are then that world's, not these.",
)
@credentials_option(
    "With --connect: the robot's credentials file (runs/RUN/credentials/<robot>.json); default $MHRC_CREDENTIALS."
)
@click.option(
    "--secure/--insecure",
    "secure",
    default=True,
    show_default=True,
    help="Without --connect: fresh credentials in runs/RUN/credentials/ (as mhrc up), or the open tcp bus. "
    "With --connect, --insecure: " + INSECURE_HELP,
)
@click.option("--quiet", "-q", is_flag=True, help="Print only the page's address and the final summary.")
@click.option(
    "--tick-delay", default=0.0, type=float, help="Seconds the world pauses between ticks (to follow your teammates)."
)
@_page_port_not_world_port
@OVERWRITE
@llm_options
def play(
    robot: str,
    page_port: int,
    no_browser: bool,
    connect: str | None,
    credentials: Path | None,
    secure: bool,
    quiet: bool,
    tick_delay: float,
    log_level: str,
    world_port: int,
    overwrite: bool,
    **values: Any,
) -> None:
    """Drive one robot yourself from a browser page, beside the AI teammates (heuristic, or --llm)."""
    from rich.console import Console

    from mhrc.agents.agent import AgentError
    from mhrc.core import logs  # structlog: imported once the command line is accepted
    from mhrc.play.app import PortInUse, bind
    from mhrc.play.gate import Gate, launcher

    logs.configure(log_level)
    console = Console(highlight=False, soft_wrap=True)
    creds = None
    cfg = None
    if connect is not None:
        creds = load_credentials(credentials, not secure, connect)
    else:
        cfg = episode_config(port=world_port, tick_delay=tick_delay, **values)
        if robot not in cfg.robots:
            raise click.BadParameter(
                f"{robot!r} is not in this episode's team (robots: {', '.join(cfg.robots)}; --team names the team)",
                param_hint="--robot",
            )
        _check_protocol(cfg, robot)
    try:
        sock = bind(page_port)  # before anything is written or started
    except PortInUse as exc:
        click.echo(f"mhrc play: {exc}", err=True)
        sys.exit(2)
    if cfg is not None:
        try:  # an earlier episode's trace at this --run is kept (refused) or, with --overwrite, removed
            fresh_trace("play", cfg, overwrite, values.get("trace") is not None)
        except SystemExit:
            sock.close()
            raise
    if cfg is not None and secure:
        cfg = cfg.with_credentials()
    if connect is not None and creds is None:
        open_bus_notice(not secure)
    gate = Gate("127.0.0.1", sock.getsockname()[1])  # the page's secret: in the address below, never logged
    url = gate.url

    launched: list[Path] = []

    def ready() -> None:
        click.echo(f"play {robot} at {url}", err=False)
        sys.stdout.flush()
        if not no_browser:
            import webbrowser

            launched.append(launcher(url))  # the browser opens a private file, not the secret on its command line
            webbrowser.open(launched[-1].as_uri())

    if cfg is not None:
        from mhrc.run.config import ModelServerDown, check_model_servers

        try:
            check_model_servers(
                cfg, [r for r in cfg.robots if r != robot]
            )  # the teammates' models, before anything starts
        except ModelServerDown as exc:
            click.echo(f"mhrc play: {exc}", err=True)
            sys.exit(2)
    from mhrc.agents.llm import LLMError
    from mhrc.core.security import SecurityError
    from mhrc.core.team import TeamError
    from mhrc.core.trace import TraceWriteError
    from mhrc.run.config import ConfigError
    from mhrc.world.service_config import NobodyAttached

    try:
        if cfg is not None:
            from mhrc.play.runner import play_here

            if not quiet:
                console.print(f"world on {cfg.endpoint}, run {cfg.run}, trace {cfg.trace}")
            done = run_command(lambda: play_here(cfg, robot, sock, gate, on_ready=ready))
        else:
            assert connect is not None
            done = run_command(lambda: _there(robot, connect, values.get("run"), sock, gate, creds, ready))
    except (AgentError, LLMError, TeamError, SecurityError, ConfigError) as exc:  # as mhrc up and mhrc agent say them
        click.echo(f"mhrc play: {exc}", err=True)
        sys.exit(2)
    except (NobodyAttached, TraceWriteError) as exc:
        click.echo(f"mhrc play: {exc}", err=True)
        sys.exit(1)
    finally:
        for page in launched:
            page.unlink(missing_ok=True)
    from mhrc.run.console import summary_table

    console.print(summary_table(done, protocol=cfg.protocol if cfg is not None else None))
    trace = cfg.trace if cfg is not None else None
    if trace is not None and trace.is_file():
        from mhrc.play.contribution import from_trace_file

        try:
            shares = from_trace_file(trace)
        except (ValueError, OSError):
            return
        console.print("contribution: " + "; ".join(c.line(you=c.robot == robot) for c in shares))


async def _there(
    robot: str, connect: str, run: str | None, sock: Any, gate: Any, creds: Any, ready: Callable[[], None]
) -> Any:
    from mhrc.core.bus import open_client
    from mhrc.play.runner import play_there
    from mhrc.run.attach import find_run

    if run is None and creds is not None:
        run = creds.run
    if run is None:
        bus = await open_client(connect, 30.0)
        try:
            run = await find_run(bus)
        finally:
            await bus.close()
    return await play_there(robot, connect, run, sock, gate, security=creds, on_ready=ready)


def _check_protocol(cfg: Any, robot: str) -> None:
    """The teammates' protocol can seat them beside a person: a whole-team protocol (one planner
    for every robot) cannot, since the person drives one of the robots, nor a spoken one (leader),
    whose teammates wait for the person's bid and reports in its own sentences; one line before
    anything starts."""
    from mhrc.run.config import ConfigError
    from mhrc.run.coordinated import check_seating

    if cfg.coordination().whole_team:
        raise click.BadParameter(
            f"protocol {cfg.protocol!r} drives every robot from one planner: it cannot leave {robot} to you "
            "(play under mhrc)",
            param_hint="--protocol",
        )
    if cfg.coordination().spoken:
        raise click.BadParameter(
            f"protocol {cfg.protocol!r} runs its stages in fixed sentences every robot must send (bids, "
            f"reports): a person cannot take {robot}'s part (play under mhrc)",
            param_hint="--protocol",
        )
    try:
        check_seating(cfg, tuple(r for r in cfg.robots if r != robot))
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
