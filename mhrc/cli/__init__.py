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

import click

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

# command name -> its one-line help, as `mhrc --help` lists it without importing the command's module
# (tests/test_cli_light.py keeps each equal to the command's own short help)
SUMMARIES: dict[str, str] = {
    "up": "Run one episode: the world and the three robot agents, then print the metrics.",
    "world": "Run the world alone and wait for agents to attach (`mhrc agent`).",
    "agent": (
        "Attach one robot's agent (heuristic or LLM policy) to a running world; under a whole-team protocol, "
        "one planner for every robot of the team."
    ),
    "scenes": "List the scene layouts (world/scenes/*.json; `--scene FILE.json` loads your own).",
    "render": (
        "Write top-down and perspective PNGs of each scene (CPU renderer, no display needed): "
        "OUT/<scene>_top.png and OUT/<scene>_perspective.png."
    ),
    "eval": (
        "Run the paper's benchmark and write, to --out, one trace per episode, episodes.jsonl (every metric "
        "of every episode, its fidelity and the LLM failures that shaped it) and summary.md / summary.csv "
        "(tables shaped like the paper's Table I and II with 95% bootstrap intervals, the paper's figures "
        "beside a matching configuration, TS next to its lower bound) and summary.html (the tables, plots, a "
        "link to each episode's report)."
    ),
    "report": (
        "Merge `mhrc eval` directories into one comparison (markdown on stdout): Succ, PS, TS and AS per task"
        " with 95% bootstrap confidence intervals, grouped by method, ablation and fidelity, and the paper's "
        "Table I / II figures beside the settings that match its configuration."
    ),
    "schema": 'The JSON Schema of every bus payload, for agents in any language (README, "Attaching your own agent").',
    "credentials": (
        "Issue one run's credentials for a world and agents started by hand or in containers (`mhrc up` makes"
        " its own): a CA, the world's TLS certificate, one login per participant."
    ),
    "bus": "Look at a running bus: who is alive (`list`), every message on a key (`echo`).",
    "doctor": (
        "Check a bus endpoint: is a zenoh router or world there, which runs are alive, which protocol version"
        " each world speaks."
    ),
    "show": (
        "Write one self-contained HTML report of an episode (map, robot lanes, messages, failures) from "
        "RUN_OR_TRACE: a trace file, or a run directory holding trace.jsonl."
    ),
    "router": "Run a Zenoh router that worlds and agents on several hosts can all connect to.",
    "scenarios": (
        "List the shipped scenarios, one a line: name, events (kind@tick) and the first 12 hex digits of the "
        "file's sha256 (result rows record the name and the whole hash)."
    ),
    "teams": "List the shipped teams, one a line: name, robots (name:kind, in execution order) and purpose.",
    "protocols": (
        "List the coordination protocols, one a line: name, how the team decides, and its forms (heuristic: "
        "the expert, no network; llm: with --llm)."
    ),
    "play": "Drive one robot yourself from a browser page, beside the AI teammates (heuristic, or --llm).",
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

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The commands and their one-line help, as click lists them, from SUMMARIES: `mhrc --help`
        imports none of the commands' modules."""
        names = self.list_commands(ctx)
        limit = formatter.width - 6 - max(len(n) for n in names)
        with formatter.section("Commands"):
            # a bare command holding the summary shortens it as click shortens the real one's help
            formatter.write_dl([(n, click.Command(n, help=SUMMARIES[n]).get_short_help_str(limit)) for n in names])

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
    # structlog is set up (MHRC_LOG_LEVEL, else warning) by mhrc.core.logs when a command's modules import it;
    # a command's --log-level overrides it. Parsing and refusing a command line imports neither.


if __name__ == "__main__":
    main()
