"""`mhrc world`: the world alone, waiting for agents to attach (`mhrc agent`).

The world and the console are imported inside the command: `mhrc --help` stays light.
"""

from __future__ import annotations

import shlex
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from mhrc.cli.options import (
    INSECURE_HELP,
    OVERWRITE,
    credentials_option,
    episode_config,
    episode_options,
    fresh_trace,
    load_credentials,
    open_bus_notice,
)
from mhrc.cli.running import run_command

if TYPE_CHECKING:  # pragma: no cover
    from mhrc.run.config import EpisodeConfig  # the bus and the model clients: imported when a command runs


def _serve_world(cfg: EpisodeConfig, observe: Callable[[Any, str], None] | None = None) -> None:
    """`mhrc world`'s run: one line and exit 1 when no robot attached within --start-timeout."""
    from mhrc.core.trace import TraceWriteError
    from mhrc.run.serve import serve_world
    from mhrc.world.service_config import NobodyAttached

    try:
        run_command(lambda: serve_world(cfg, observe=observe))
    except (NobodyAttached, TraceWriteError) as exc:
        click.echo(f"mhrc world: {exc}", err=True)
        sys.exit(1)


@click.command()
@episode_options
@click.option(
    "--start-timeout",
    type=float,
    default=None,
    help="Start with the robots attached after this many seconds (fail if none is); default: wait for all three.",
)
@click.option("--tick-delay", default=0.0, type=float, help="Seconds to pause between ticks (to watch with --gui).")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but errors.")
@credentials_option(
    "This participant's credentials file (runs/RUN/credentials/<user>.json, written by `mhrc up`); "
    "default $MHRC_CREDENTIALS. The bus is then TLS with a login and the world's access control."
)
@click.option("--insecure", is_flag=True, help=INSECURE_HELP)
@OVERWRITE
def world(
    log_level: str,
    start_timeout: float | None,
    quiet: bool,
    credentials: Path | None,
    insecure: bool,
    overwrite: bool,
    **values: Any,
) -> None:
    """Run the world alone and wait for agents to attach (`mhrc agent`)."""
    from mhrc.core import logs  # structlog: imported once the command line is accepted
    from mhrc.core.protocol.events import DEFAULT_PROTOCOL
    from mhrc.run.console import ProgressPrinter

    logs.configure(log_level)
    creds = load_credentials(credentials, insecure)
    if creds is not None:
        from mhrc.core.zenoh_log import watch_refusals

        watch_refusals()  # a refused login is said here too, not only on the refused agent's side
        if values.get("run") is None:
            values["run"] = creds.run
    cfg = episode_config(start_timeout=start_timeout, credentials=credentials if creds is not None else None, **values)
    fresh_trace("world", cfg, overwrite, values.get("trace") is not None)
    if creds is None:
        open_bus_notice(insecure)
    if quiet:
        _serve_world(cfg)
        return
    printer = ProgressPrinter(verbose=False)

    def listening(bus: Any, run: str) -> None:  # said once the world listens, not before
        click.echo(f"world listening on {cfg.endpoint}, run {cfg.run}; attach agents with:", err=True)
        protocol = "" if cfg.protocol == DEFAULT_PROTOCOL else f" --protocol {cfg.protocol}"
        groups = [cfg.robots] if cfg.coordination().whole_team else [(r,) for r in cfg.robots]
        for group in groups:  # a whole-team protocol's planner: one agent for every robot, with each one's login
            robots = "".join(f" --robot {r}" for r in group)
            login = "" if creds is None else "".join(f" --credentials {_login_of(creds, r)}" for r in group)
            click.echo(f"  mhrc agent{robots} --run {cfg.run} --connect {cfg.endpoint}{protocol}{login}", err=True)
        printer.attach(bus, run)

    _serve_world(cfg, listening)


def _login_of(world: Any, user: str) -> str:
    """Where `user`'s credentials file lies beside the world's (`mhrc credentials` flat or
    --split, `mhrc up`'s runs/RUN/credentials/), or a placeholder naming it."""
    if world.path is not None:
        here = world.path.parent
        for candidate in (here / f"{user}.json", here.parent / user / f"{user}.json"):
            if candidate.is_file():
                return shlex.quote(str(candidate))
    return f"<{user}'s credentials file>"
