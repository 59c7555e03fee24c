"""`mhrc protocols`: the coordination protocols (issue 45), one a line: how each team decides."""

from __future__ import annotations

import click


@click.command("protocols")
def protocols() -> None:
    """List the coordination protocols, one a line: name, how the team decides, and its forms
    (heuristic: the expert, no network; llm: with --llm).

    Choose one with `--protocol NAME` on `mhrc up`, `mhrc world`, `mhrc agent`, `mhrc play` and
    `mhrc eval` (repeatable there: an axis like --team); `mhrc` (the paper's) is the default.
    Docs: docs/protocols.md."""
    from mhrc.agents.protocols import PROTOCOLS

    for p in PROTOCOLS.values():
        click.echo(p.line())
