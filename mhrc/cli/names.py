"""The shipped names an option is checked against before anything heavy is imported (tasks,
scenes, teams, coordination protocols), each refusal with its near matches, as click gives them for option names.

The registries cost more than a typo should: the tasks' (their generators and the furniture, some
30 ms), the teams' (pydantic models) and the protocols' (the model clients, their LLM forms). So
their names are listed here too, and tests/test_cli_light.py keeps the lists equal to the
registries. Scenes are the layout files' names (mhrc.world.scene_files: no layout is read). None of this
imports the simulator, the bus or a model client: a typo is refused in a fraction of a second
(tests/test_cli_light.py checks which modules a refused command imports)."""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from pathlib import Path

import click

from mhrc.world.scene_files import scene_files
from mhrc.world.schedules import SCHEDULES as SCHEDULES  # the world's, without the schedulers

TASKS = ("pack_objects", "sort_solids", "make_sandwich")  # mhrc.world.tasks.TASKS, in its order
TEAMS = (
    "paper",
    "no_mobile",
    "two_fetchers",
    "drone_scout",
    "scout_and_drone",
    "large",
    "full_house",
)  # world/teams.py
PROTOCOLS = (
    "mhrc",
    "centralized",
    "leader",
)  # mhrc.agents.protocols.PROTOCOLS, in its order (it imports the model clients)


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """'did you mean X?' for the known names close to `name` (difflib, as click does for options), else ''."""
    close = difflib.get_close_matches(name, list(known), n=2, cutoff=0.6)
    return f"did you mean {' or '.join(repr(c) for c in close)}?" if close else ""


def near(name: str, known: Iterable[str]) -> str:
    """' (did you mean X?)', or '' when no known name is close."""
    hint = did_you_mean(name, known)
    return f" ({hint})" if hint else ""


def check_task(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """--task: a registered task's id, else one line naming them and the nearest."""
    if value is None:
        return None
    if value not in TASKS:
        raise click.BadParameter(f"unknown task {value!r}{near(value, TASKS)}; known tasks: {', '.join(TASKS)}")
    return value


def check_scene(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """--scene: a shipped layout's name or a .json file (checked later, when it is loaded)."""
    if value is None or value.endswith(".json") or value in scene_files():
        return value
    from mhrc.world.layouts import LAYOUTS  # a layout a test put in; else the refusal's names

    if value not in LAYOUTS:
        raise click.BadParameter(
            f"unknown scene {value!r}{near(value, LAYOUTS)}; known scenes: {', '.join(LAYOUTS)} "
            "(or a path to a layout .json file)"
        )
    return value


def check_protocol(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """--protocol: a registered coordination protocol's name, else one line naming them and the nearest."""
    if value is None:
        return None
    if value not in PROTOCOLS:
        raise click.BadParameter(
            f"unknown protocol {value!r}{near(value, PROTOCOLS)}; the protocols: {', '.join(PROTOCOLS)} (mhrc protocols)"
        )
    return value


def unknown_team(value: str) -> str | None:
    """The one line refusing `--team VALUE`, when it can be neither a shipped team, a file nor
    robots inline (mhrc.run.teams.resolve_team reads those); None when it may be one of them."""
    text = value.strip()
    if text in TEAMS or text.startswith("{") or "=" in text or text.lower().endswith((".toml", ".json")):
        return None
    if Path(text).is_file():
        return None
    hint = did_you_mean(text, TEAMS)
    return (
        f"--team {text!r}: not a shipped team ({', '.join(TEAMS)}; mhrc teams), "
        "a .toml or .json file, or robots inline (alice=mobile_manipulator,bob=tabletop_arm)"
        + (f"; {hint}" if hint else "")
    )
