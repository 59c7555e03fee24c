"""`mhrc scenarios`: the scenarios shipped with the package (issue 25), so that a paper can cite
"scenario busy_house" (with its hash) rather than a file, and `--events NAME` can run one."""

from __future__ import annotations

import click

from mhrc.world.scenario import Scenario, ScenarioError, describe, load_scenario, shipped_scenarios


def _short(scenario: Scenario) -> str:
    return ", ".join(f"{ev.kind}@{ev.tick}" for ev in scenario.events) or "(no events)"


@click.command("scenarios")
@click.argument("name", required=False, metavar="[NAME]")
def scenarios(name: str | None) -> None:
    """List the shipped scenarios, one a line: name, events (kind@tick) and the first 12 hex
    digits of the file's sha256 (result rows record the name and the whole hash).

    With NAME (a shipped scenario's name or a scenario file's path) print that scenario's events
    in full, each with what it does. Run one with `mhrc up --events NAME` (or `world`, `eval`).
    What scenarios are and how they are scored: docs/scenarios.md."""
    if name is None:
        loaded = [load_scenario(path) for path in shipped_scenarios().values()]
        width = max((len(s.name) for s in loaded), default=0)
        events = max((len(_short(s)) for s in loaded), default=0)
        for s in loaded:
            click.echo(f"{s.name:<{width}}  {_short(s):<{events}}  {s.sha256[:12]}")
        return
    try:
        scenario = load_scenario(name)
    except ScenarioError as exc:
        raise click.UsageError(str(exc).replace("--events", "NAME", 1)) from None
    click.echo(f"{scenario.name} (sha256 {scenario.sha256}), {len(scenario.events)} event(s):")
    for i, ev in enumerate(scenario.events):
        click.echo(f"  [{i}] tick {ev.tick}: {ev.kind}: {describe(ev)}")
