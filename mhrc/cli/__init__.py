"""The `mhrc` command: one module per command group, registered on one click group here.

- `participants`: `up`, `world`, `agent`
- `eval`: `eval`, `report`
- `viewer`: `scenes`, `render`, `show`
- `scenarios`: `scenarios` (the shipped scenarios of `--events`)
- `teams`: `teams` (the shipped teams of `--team`, the robot kinds)
- `play`: `play` (a person drives one robot from a browser page)
- `bus`: `credentials`, `bus list|echo`, `doctor`, `router`, `schema`
- `options` (shared options, declared once), `running` (signals and Ctrl-C)
"""

from __future__ import annotations

import os

import click

from mhrc.cli import bus, participants, play, scenarios, teams, viewer
from mhrc.cli import eval as eval_cmd
from mhrc.core import logs

__all__ = ["main"]


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="mhrc")
def main() -> None:
    """Heterogeneous robots, each driven by its own agent, collaborate on household tasks in a
    PyBullet world; the world and every agent talk over a Zenoh bus.

    Start with `mhrc up`: one Pack Objects episode with Alice (mobile manipulator), Bob (arm on
    table_0) and David (mobile robot) driven by the built-in heuristic policy.
    """
    logs.configure(os.environ.get("MHRC_LOG_LEVEL", "warning"))  # a command's --log-level overrides it


for command in (
    participants.up,
    participants.world,
    participants.agent,
    viewer.scenes,
    viewer.render,
    eval_cmd.eval_,
    eval_cmd.report,
    bus.schema_,
    bus.credentials_,
    bus.bus_group,
    bus.doctor,
    viewer.show,
    bus.router,
    scenarios.scenarios,
    teams.teams,
    play.play,
):
    main.add_command(command)

up, world, agent = participants.up, participants.world, participants.agent  # the commands, for callers that invoke one

if __name__ == "__main__":
    main()
