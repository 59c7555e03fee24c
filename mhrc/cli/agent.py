"""`mhrc agent`: one robot's agent (heuristic or LLM policy), attached to a running world.

The agent, the bus and the model clients are imported inside the command: `mhrc --help` stays light.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from mhrc.cli.options import (
    ABLATIONS,
    AIDS_HELP,
    INSECURE_HELP,
    LOG_LEVEL,
    episode_config,
    llm_options,
    load_credentials,
    open_bus_notice,
    protocol_option,
    team_option,
)
from mhrc.cli.running import run_command
from mhrc.core.deadlines import ATTACH_TIMEOUT

if TYPE_CHECKING:  # pragma: no cover
    from mhrc.core.security import Credentials  # cryptography: imported once the command line is accepted


@click.command()
@click.option(
    "--robot",
    "robots",
    required=True,
    multiple=True,
    help="The robot this agent drives (a robot of --team; the paper's alice, bob, david). Repeat it under a "
    "whole-team protocol (--protocol centralized): one planner acting for every robot of the team, each robot "
    "with its own session and login (a --credentials for each).",
)
@click.option("--connect", required=True, help="The world's endpoint, e.g. tcp/127.0.0.1:7447.")
@click.option("--run", default=None, help="Run id of the world; default: the only world alive at --connect.")
@click.option(
    "--attach-timeout", default=ATTACH_TIMEOUT, show_default=True, type=float, help="Seconds to wait for the world."
)
@llm_options
@click.option(
    "--ablation", default="none", show_default=True, type=click.Choice(ABLATIONS), help="LLM prompt ablation."
)
@team_option
@protocol_option
@click.option(
    "--aids",
    default=None,
    metavar="NAMES",
    help="Agent-side aids (reach_labels, prompt_hints, feedback_advice: its unreadable-reply "
    "half); the world's aids are set on the world. " + AIDS_HELP,
)
@LOG_LEVEL
@click.option(
    "--credentials",
    "credential_files",  # not EpisodeConfig's credentials (a run's directory, or one file)
    type=click.Path(dir_okay=False, path_type=Path),
    multiple=True,
    envvar="MHRC_CREDENTIALS",
    help="This participant's credentials file (runs/RUN/credentials/<user>.json, written by `mhrc up`); "
    "default $MHRC_CREDENTIALS. The bus is then TLS with a login and the world's access control. A planner of "
    "several robots takes one file per robot (repeat it): it may act for exactly those robots.",
)
@click.option("--insecure", is_flag=True, help=INSECURE_HELP)
def agent(
    robots: tuple[str, ...],
    connect: str,
    run: str | None,
    attach_timeout: float,
    log_level: str,
    credential_files: tuple[Path, ...],
    insecure: bool,
    **values: Any,
) -> None:
    """Attach one robot's agent (heuristic or LLM policy) to a running world; under a whole-team
    protocol, one planner for every robot of the team."""
    from mhrc.core import logs  # structlog: imported once the command line is accepted
    from mhrc.run.attach import attach_agent

    logs.configure(log_level)
    logins = [load_credentials(path, insecure, connect) for path in credential_files] or [
        load_credentials(None, insecure, connect)
    ]
    cfg = episode_config(**values)
    if unknown := [r for r in robots if r not in cfg.robots]:
        raise click.BadParameter(
            f"{', '.join(map(repr, unknown))} not in this episode's team (robots: {', '.join(cfg.robots)}; "
            "--team names the team)",
            param_hint="--robot",
        )
    security = _logins(robots, logins, cfg.protocol)
    from mhrc.agents.agent import AgentError
    from mhrc.agents.llm import LLMFatalError
    from mhrc.agents.llm.model_spec import LLMSpecError
    from mhrc.core.lifeline import PARENT_ENV
    from mhrc.core.security import SecurityError
    from mhrc.run.config import ConfigError
    from mhrc.run.coordinated import attach_seated, check_seating

    try:
        p = check_seating(cfg, robots)  # a whole-team protocol's planner is given every robot, or refused here
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
    if len(robots) > 1 and not p.whole_team:
        raise click.BadParameter(
            f"one robot per agent under protocol {p.name!r} (got {', '.join(robots)}); only a whole-team protocol's "
            "planner drives several (mhrc protocols)",
            param_hint="--robot",
        )
    if logins[0] is None:
        open_bus_notice(insecure)
    robot = robots[0]
    who = robot if len(robots) == 1 else f"{p.name} planner"
    spec = cfg.robot_specs().get(robot)
    options = cfg.policy_options(spec)

    if not os.environ.get(PARENT_ENV):  # said by hand only: a child of mhrc up --processes has its parent's lines
        click.echo(f"waiting for the world at {connect} (up to {attach_timeout:g} s)", err=True)
    try:
        if p.build is None:  # the paper's protocol: the robot's agent builds its own policy, as it always did
            done = run_command(
                lambda: attach_agent(
                    robot,
                    connect,
                    run,
                    attach_timeout,
                    spec,
                    cfg.base_url,
                    cfg.client_options(spec),
                    security=security[robot],
                    **options,
                )
            )
        else:
            done = run_command(lambda: attach_seated(cfg, robots, connect, run, attach_timeout, security))
    except (
        AgentError,
        LLMFatalError,
        LLMSpecError,  # e.g. a gguf: file under a protocol, which only `mhrc up` serves for a protocol's policies
        SecurityError,
        ConfigError,
    ) as exc:  # the world, the model or the setup: one line, exit 2
        click.echo(f"mhrc agent {who}: {exc}", err=True)
        sys.exit(2)
    except Exception as exc:  # anything else: say what happened, exit 1
        raise click.ClickException(f"{type(exc).__name__}: {exc}") from None
    if done is not None:
        m = done.metrics
        click.echo(
            f"{who}: episode {done.run} ended ({done.reason}): success={m.success} placed={m.placed}/{m.total} TS={m.temporal_steps}"
        )


def _logins(robots: tuple[str, ...], logins: list[Credentials | None], protocol: str) -> dict[str, Credentials | None]:
    """Each robot's login. One robot takes the one --credentials file (checked to be that robot's
    when the agent logs in, as it always was); a planner of several robots one file per robot,
    each naming its robot as its user: a robot without one, or a file of a user it does not drive,
    is a usage error (on the secured bus a planner may act only for the robots it was given)."""
    if len(robots) == 1:
        if len(logins) > 1:
            raise click.BadParameter("one credentials file for one robot", param_hint="--credentials")
        return {robots[0]: logins[0]}
    given = [c for c in logins if c is not None]
    if not given:  # the open bus: nobody logs in
        return dict.fromkeys(robots)
    by_user = {c.user: c for c in given}
    if strangers := [u for u in by_user if u not in robots]:
        raise click.BadParameter(
            f"credentials of {', '.join(map(repr, strangers))}, not a robot this planner drives ({', '.join(robots)})",
            param_hint="--credentials",
        )
    if missing := [r for r in robots if r not in by_user]:
        raise click.BadParameter(
            f"the {protocol} planner has no credentials for {', '.join(missing)}: give each robot's file "
            f"(--credentials runs/RUN/credentials/{missing[0]}.json)",
            param_hint="--credentials",
        )
    return {r: by_user[r] for r in robots}
