"""`mhrc schema`: the JSON Schema of every bus payload, for agents in any language."""

from __future__ import annotations

import json
from pathlib import Path

import click

from mhrc.core import schema as schema_mod


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
