"""`mhrc teams`: the shipped teams (issue 33), each named for what it tests, and the robot kinds
a team file may use."""

from __future__ import annotations

import click

from mhrc.core.team import TeamError


@click.command("teams")
@click.argument("team", required=False, metavar="[TEAM]")
@click.option("--kinds", is_flag=True, help="List the robot kinds instead: id, skills and what the body is.")
def teams(team: str | None, kinds: bool) -> None:
    """List the shipped teams, one a line: name, robots (name:kind, in execution order) and purpose.

    With TEAM (a shipped team's name, a team file or robots inline) print that team in full, with
    each robot's kind, skills and part (finisher, fetcher, scout) and the team's digest (result
    rows record it). Run one with `mhrc up --team NAME` (or `world`, `eval`). Docs: docs/teams.md."""
    from mhrc.run.teams import resolve_team, shipped_teams
    from mhrc.world.briefs import role_of
    from mhrc.world.kinds import KINDS

    if kinds:
        width = max(len(k) for k in KINDS)
        for k in KINDS.values():
            click.echo(f"{k.id:<{width}}  {', '.join(k.skills)}  ({k.model})")
        return
    if team is None:
        shipped = shipped_teams()
        width = max(len(n) for n in shipped)
        for name, spec in shipped.items():
            robots = " ".join(f"{r.name}:{r.kind}" for r in spec.robots)
            click.echo(f"{name:<{width}}  {len(spec.robots)}  {spec.purpose}")
            click.echo(f"{'':<{width}}     {robots}")
        return
    try:
        spec = resolve_team(team)
    except TeamError as exc:
        raise click.UsageError(str(exc).replace("--team", "TEAM", 1)) from None
    click.echo(
        f"{spec.name} (digest {spec.digest()}), {len(spec.robots)} robots"
        + (f": {spec.purpose}" if spec.purpose else "")
    )
    for r in spec.robots:
        kind = KINDS.get(r.kind)
        if kind is None:
            click.echo(f"  {r.name}: {r.kind} (unknown kind; mhrc teams --kinds)")
            continue
        part = role_of(kind.finishes_task, kind.mobile, kind.has_arm)
        extra = (f", starts at {r.start}" if r.start else "") + (f", model {r.llm}" if r.llm else "")
        click.echo(f"  {r.name}: {kind.id}, the {part} ({', '.join(kind.skills)}){extra}")
