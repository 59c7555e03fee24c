"""`mhrc credentials`: one run's credentials (a CA, the world's TLS certificate, a login per
participant) for a world and agents started by hand or in containers."""

from __future__ import annotations

import ipaddress
import math
import shutil
from pathlib import Path

import click

from mhrc.cli.options import team_option
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
