"""`mhrc bus list|echo`: look at a running bus (mhrc.cli.bustools); `mhrc doctor` shares its
runner and its --credentials option."""

from __future__ import annotations

import sys
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

import click

from mhrc.cli.bustools import BusToolError
from mhrc.cli.bustools import bus_echo as run_echo
from mhrc.cli.bustools import bus_list as run_list
from mhrc.cli.options import credentials_option
from mhrc.cli.running import run_command


@click.group("bus")
def bus_group() -> None:
    """Look at a running bus: who is alive (`list`), every message on a key (`echo`)."""


def run_tool(name: str, coro_fn: Callable[[], Coroutine[Any, Any, int]]) -> None:
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
    run_tool("bus list", lambda: run_list(connect, as_json=as_json, credentials=credentials, write=click.echo))


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
    run_tool(
        "bus echo",
        lambda: run_echo(
            connect, keyexpr, as_json=as_json, count=count, timeout=timeout, credentials=credentials, write=click.echo
        ),
    )
