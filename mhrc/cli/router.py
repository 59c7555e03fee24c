"""`mhrc router`: a Zenoh router that worlds and agents on several hosts can all connect to."""

from __future__ import annotations

import asyncio

import click

from mhrc.cli.running import run_command
from mhrc.core.bus import Bus
from mhrc.core.endpoints import endpoint


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
