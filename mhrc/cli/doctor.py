"""`mhrc doctor`: is a zenoh router or world at an endpoint, which runs are alive there, which
protocol version each world speaks (mhrc.cli.bustools)."""

from __future__ import annotations

from pathlib import Path

import click

from mhrc.cli.bus import CREDENTIALS_OPT, run_tool
from mhrc.cli.bustools import doctor as run_doctor


@click.command()
@click.option("--connect", required=True, help="Endpoint to check, e.g. tcp/127.0.0.1:7447.")
@CREDENTIALS_OPT
def doctor(connect: str, credentials: Path | None) -> None:
    """Check a bus endpoint: is a zenoh router or world there, which runs are alive, which
    protocol version each world speaks. Exit code 0 healthy, 1 not."""
    run_tool("doctor", lambda: run_doctor(connect, credentials=credentials, write=click.echo))
