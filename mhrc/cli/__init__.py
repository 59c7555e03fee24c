"""The `mhrc` command: one module per command group, named after it, registered on one click group here.

- `up`, `world`, `agent`: an episode, the world alone, one robot's agent
- `eval`: `eval`; `report`: `report`
- `viewer`: `scenes`, `render`, `show`
- `scenarios`: `scenarios` (the shipped scenarios of `--events`)
- `teams`: `teams` (the shipped teams of `--team`, the robot kinds)
- `protocols`: `protocols` (the coordination protocols of `--protocol`)
- `play`: `play` (a person drives one robot from a browser page)
- `bus`: `bus list|echo` (over `bustools`); `doctor`, `router`, `schema`, `credentials`: each its own
- `options` (shared options, declared once), `running` (signals and Ctrl-C), `names` (the
  shipped names a typo is checked against, without the world)

A command's module is imported only when that command runs (`LazyGroup`), so a mistyped command
or option is refused before the bus, the simulator or a model client is imported.
"""

from __future__ import annotations

import difflib
import importlib
import os

import click

from mhrc.core import logs

__all__ = ["main"]

# command name -> (module of mhrc.cli, attribute): imported when the command is looked up
COMMANDS: dict[str, tuple[str, str]] = {
    "up": ("up", "up"),
    "world": ("world", "world"),
    "agent": ("agent", "agent"),
    "scenes": ("viewer", "scenes"),
    "render": ("viewer", "render"),
    "eval": ("eval", "eval_"),
    "report": ("report", "report"),
    "schema": ("schema", "schema_"),
    "credentials": ("credentials", "credentials_"),
    "bus": ("bus", "bus_group"),
    "doctor": ("doctor", "doctor"),
    "show": ("viewer", "show"),
    "router": ("router", "router"),
    "scenarios": ("scenarios", "scenarios"),
    "teams": ("teams", "teams"),
    "protocols": ("protocols", "protocols"),
    "play": ("play", "play"),
}


def _load(name: str) -> click.Command:
    module, attr = COMMANDS[name]
    command = getattr(importlib.import_module(f"mhrc.cli.{module}"), attr)
    assert isinstance(command, click.Command)
    return command


class LazyGroup(click.Group):
    """A click group whose commands are imported when looked up, and whose unknown command names
    get the near matches click gives unknown options."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        return _load(cmd_name) if cmd_name in COMMANDS else None

    def resolve_command(
        self, ctx: click.Context, args: list[str]
    ) -> tuple[str | None, click.Command | None, list[str]]:
        name = args[0] if args else ""
        if name and name not in COMMANDS and not name.startswith("-"):
            close = difflib.get_close_matches(name, COMMANDS, n=3)
            hint = f" Did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
            ctx.fail(f"No such command {name!r}.{hint} The commands: {', '.join(sorted(COMMANDS))}.")
        return super().resolve_command(ctx, args)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="mhrc")
def main() -> None:
    """Heterogeneous robots, each driven by its own agent, collaborate on household tasks in a
    PyBullet world; the world and every agent talk over a Zenoh bus.

    Start with `mhrc up`: one Pack Objects episode with Alice (mobile manipulator), Bob (arm on
    table_0) and David (mobile robot) driven by the built-in heuristic policy.
    """
    logs.configure(os.environ.get("MHRC_LOG_LEVEL", "warning"))  # a command's --log-level overrides it


if __name__ == "__main__":
    main()
