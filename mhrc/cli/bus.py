"""The bus's own commands: `mhrc credentials`, `mhrc bus list|echo`, `mhrc doctor`,
`mhrc router` and `mhrc schema`."""

from __future__ import annotations

import asyncio
import ipaddress
import json
import math
import shutil
import sys
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

import click

from mhrc.cli.bustools import BusToolError
from mhrc.cli.bustools import bus_echo as run_echo
from mhrc.cli.bustools import bus_list as run_list
from mhrc.cli.bustools import doctor as run_doctor
from mhrc.cli.options import credentials_option, team_option
from mhrc.cli.running import run_command
from mhrc.core import schema as schema_mod
from mhrc.core.bus import Bus
from mhrc.core.endpoints import endpoint
from mhrc.core.keys import check_id, new_run_id
from mhrc.core.plural import counted
from mhrc.core.security import MIN_DAYS, SecurityError, make_run_credentials
from mhrc.core.team import PAPER_TEAM, TeamSpec

MAX_DAYS = 36500  # a certificate's end date must be a date: 100 years is plenty and far from datetime's year 9999


def _days(_ctx: click.Context, _param: click.Parameter, value: float) -> float:
    """--days: a finite number of days in [a minute, MAX_DAYS]; checked before anything is written."""
    if not (math.isfinite(value) and MIN_DAYS <= value <= MAX_DAYS):
        raise click.BadParameter(f"must be at least a minute ({MIN_DAYS:.6f}) and at most {MAX_DAYS} (got {value:g})")
    return value


def _cert_hosts(_ctx: click.Context, _param: click.Parameter, value: tuple[str, ...]) -> tuple[str, ...]:
    """--host: each a name or address a certificate can hold (ASCII, no spaces), checked before anything is written."""
    for h in value:
        if _is_ip(h):
            continue
        if not h or not h.isascii() or any(c.isspace() or c in "/:@" for c in h):
            raise click.BadParameter(
                f"{h!r} is not a host name or address (a name outside ASCII goes in its xn-- form)"
            )
    return value


def _is_ip(text: str) -> bool:
    try:
        ipaddress.ip_address(text)
    except ValueError:
        return False
    return True


def _first_missing(path: Path) -> Path | None:
    """The outermost directory of `path` that does not exist yet (None if `path` exists): what creating it would add."""
    missing = None
    for p in (path, *path.parents):
        if p.exists():
            break
        missing = p
    return missing


@click.command("schema")
@click.option(
    "--out",
    type=click.Path(file_okay=False, path_type=Path),
    default=None,
    help="Write one <Payload>.json per bus payload and index.json into this directory; default: print one JSON document.",
)
def schema_(out: Path | None) -> None:
    """The JSON Schema of every bus payload, for agents in any language (README, "Attaching your own agent")."""
    if out is None:
        click.echo(json.dumps(schema_mod.document(), indent=2))
        return
    for path in schema_mod.write(out):
        click.echo(str(path))


@click.command("credentials")
@click.option(
    "--out",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="The directory to write them into (created 0700).",
)
@click.option(
    "--run",
    default=None,
    help="The run id they are for; default: a new random one (the world and agents take it from them).",
)
@click.option(
    "--host",
    "hosts",
    multiple=True,
    metavar="NAME",
    callback=_cert_hosts,
    help="A name or address the agents reach the world by, besides 127.0.0.1 and localhost (repeatable): "
    "e.g. world, the compose service. The world's certificate names it.",
)
@click.option(
    "--days",
    default=7.0,
    show_default=True,
    type=float,
    callback=_days,
    help=f"How long the CA and the world's certificate stay valid from now: more than 0, at most {MAX_DAYS} (fractions allowed: 0.5 is 12 hours).",
)
@click.option(
    "--split",
    is_flag=True,
    help="One directory per participant (DIR/world/, DIR/alice/, ...), each for that participant's container only.",
)
@click.option(
    "--force",
    is_flag=True,
    help="Replace credentials already in DIR (a world running with the old ones refuses the new).",
)
@team_option
def credentials_(
    out: Path, run: str | None, hosts: tuple[str, ...], days: float, split: bool, force: bool, team: TeamSpec | None
) -> None:
    """Issue one run's credentials for a world and agents started by hand or in containers
    (`mhrc up` makes its own): a CA, the world's TLS certificate, one login per participant.
    Start the world with --credentials DIR/world.json and each agent with its own file."""
    existing = out.is_dir() and (any(out.glob("*.json")) or any(out.glob("*/*.json")))
    if existing and not force:
        raise click.UsageError(f"--out: {out} already holds credentials; pass --force to replace them")
    run = run or new_run_id()
    try:
        check_id(run, "run id")
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--run") from None
    created = _first_missing(out)
    try:
        files = make_run_credentials(run, (team or PAPER_TEAM).names, out, days=days, hosts=hosts, split=split)
    except (SecurityError, ValueError, OSError) as exc:
        if created is not None:  # nothing left behind: what this command created goes again
            shutil.rmtree(created, ignore_errors=True)
        if isinstance(exc, OSError):
            raise click.UsageError(f"--out: cannot write the credentials into {out}: {exc.strerror or exc}") from None
        raise click.UsageError(str(exc)) from None
    click.echo(f"run {run}: credentials in {out} (valid {counted(days, 'day')}; keep them private)", err=True)
    for user, path in files.items():
        click.echo(f"  {user}: {path}", err=True)


@click.group("bus")
def bus_group() -> None:
    """Look at a running bus: who is alive (`list`), every message on a key (`echo`)."""


def _bus_tool(name: str, coro_fn: Callable[[], Coroutine[Any, Any, int]]) -> None:
    """Run a bus tool: its exit code, or one clear line on stderr and exit 1 (mhrc.cli.bustools)."""
    try:
        code = run_command(coro_fn)
    except BusToolError as exc:
        click.echo(f"mhrc {name}: {exc}", err=True)
        sys.exit(1)
    sys.exit(code)


CREDENTIALS_OPT = credentials_option(
    "A login of a secured run, with a tls/ endpoint: the observer's (runs/RUN/credentials/observer.json, or "
    "DIR/observer.json of mhrc credentials) reads the whole run and asks the world's state; a robot's sees only its own keys."
)


@bus_group.command("list")
@click.option("--connect", required=True, help="Endpoint of a world or router, e.g. tcp/127.0.0.1:7447.")
@click.option(
    "--json", "as_json", is_flag=True, help="One JSON object: the endpoint and every run or evaluation alive."
)
@CREDENTIALS_OPT
def bus_list(connect: str, as_json: bool, credentials: Path | None) -> None:
    """The runs alive (from liveliness): which have a world, which robots are attached."""
    _bus_tool("bus list", lambda: run_list(connect, as_json=as_json, credentials=credentials, write=click.echo))


@bus_group.command("echo")
@click.argument("keyexpr")
@click.option("--connect", required=True, help="Endpoint of a world or router, e.g. tcp/127.0.0.1:7447.")
@click.option("--json", "as_json", is_flag=True, help="One JSON object per message (a trace line: t, key, kind, msg).")
@click.option("--count", type=click.IntRange(min=1), default=None, help="Exit after N messages.")
@click.option(
    "--timeout",
    type=click.FloatRange(min=0),
    default=None,
    help="Exit after this many seconds (exit 1 if --count was not reached).",
)
@CREDENTIALS_OPT
def bus_echo(
    keyexpr: str, connect: str, as_json: bool, count: int | None, timeout: float | None, credentials: Path | None
) -> None:
    """Print every message on KEYEXPR (e.g. 'mhrc/**' or 'mhrc/RUN/robot/*/action/result'),
    decoded with the protocol, one line each: time, key, kind, summary."""
    _bus_tool(
        "bus echo",
        lambda: run_echo(
            connect, keyexpr, as_json=as_json, count=count, timeout=timeout, credentials=credentials, write=click.echo
        ),
    )


@click.command()
@click.option("--connect", required=True, help="Endpoint to check, e.g. tcp/127.0.0.1:7447.")
@CREDENTIALS_OPT
def doctor(connect: str, credentials: Path | None) -> None:
    """Check a bus endpoint: is a zenoh router or world there, which runs are alive, which
    protocol version each world speaks. Exit code 0 healthy, 1 not."""
    _bus_tool("doctor", lambda: run_doctor(connect, credentials=credentials, write=click.echo))


@click.command()
@click.option("--host", default="127.0.0.1", show_default=True)
@click.option("--port", default=7447, show_default=True, type=int)
def router(host: str, port: int) -> None:
    """Run a Zenoh router that worlds and agents on several hosts can all connect to."""

    async def serve() -> None:
        bus = await Bus.open(mode="router", listen=[endpoint(host, port)])
        try:
            click.echo(f"router listening on {endpoint(host, port)}; Ctrl-C to stop", err=True)
            await asyncio.Event().wait()
        finally:
            await bus.close()

    run_command(serve)
