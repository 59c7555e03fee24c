"""`mhrc agent`: one robot's agent (heuristic or LLM policy), attached to a running world.

The agent, the bus and the model clients are imported inside the command: `mhrc --help` stays light.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import click

from mhrc.cli.options import (
    ABLATIONS,
    AIDS_HELP,
    INSECURE_HELP,
    LOG_LEVEL,
    credentials_option,
    episode_config,
    llm_options,
    load_credentials,
    open_bus_notice,
    team_option,
)
from mhrc.cli.running import run_command
from mhrc.core import logs
from mhrc.core.security import SecurityError


@click.command()
@click.option(
    "--robot", required=True, help="The robot this agent drives (a robot of --team; the paper's alice, bob, david)."
)
@click.option("--connect", required=True, help="The world's endpoint, e.g. tcp/127.0.0.1:7447.")
@click.option("--run", default=None, help="Run id of the world; default: the only world alive at --connect.")
@click.option("--attach-timeout", default=30.0, show_default=True, type=float, help="Seconds to wait for the world.")
@llm_options
@click.option(
    "--ablation", default="none", show_default=True, type=click.Choice(ABLATIONS), help="LLM prompt ablation."
)
@team_option
@click.option(
    "--protocol",
    default=None,
    metavar="NAME",
    help="The episode's coordination protocol (default mhrc, the paper's): under one whose robots each have "
    "their own policy (leader), this robot's.",
)
@click.option(
    "--aids",
    default=None,
    metavar="NAMES",
    help="Agent-side aids (reach_labels, prompt_hints, feedback_advice: its unreadable-reply "
    "half); the world's aids are set on the world. " + AIDS_HELP,
)
@LOG_LEVEL
@credentials_option(
    "This participant's credentials file (runs/RUN/credentials/<user>.json, written by `mhrc up`); "
    "default $MHRC_CREDENTIALS. The bus is then TLS with a login and the world's access control."
)
@click.option("--insecure", is_flag=True, help=INSECURE_HELP)
def agent(
    robot: str,
    connect: str,
    run: str | None,
    attach_timeout: float,
    log_level: str,
    credentials: Path | None,
    insecure: bool,
    **values: Any,
) -> None:
    """Attach one robot's agent (heuristic or LLM policy) to a running world."""
    from mhrc.run.attach import attach_agent

    logs.configure(log_level)
    creds = load_credentials(credentials, insecure, connect)
    cfg = episode_config(**values)
    if robot not in cfg.robots:
        raise click.BadParameter(
            f"{robot!r} is not in this episode's team (robots: {', '.join(cfg.robots)}; --team names the team)",
            param_hint="--robot",
        )
    from mhrc.agents.llm.model_spec import LLMSpecError
    from mhrc.run.config import ConfigError
    from mhrc.run.coordinated import seat

    try:
        seats = seat(cfg, (robot,))  # the protocol's policy of this robot (none for the paper's)
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
    except LLMSpecError as exc:  # a gguf: file, which only `mhrc up` serves for a protocol's policies
        raise click.UsageError(f"--llm: {exc} (under --protocol {cfg.protocol})") from None
    if creds is None:
        open_bus_notice(insecure)
    spec = cfg.robot_specs().get(robot)
    options = cfg.policy_options(spec)
    from mhrc.agents.agent import AgentError
    from mhrc.agents.llm import LLMFatalError
    from mhrc.core.lifeline import PARENT_ENV

    if not os.environ.get(PARENT_ENV):  # said by hand only: a child of mhrc up --processes has its parent's lines
        click.echo(f"waiting for the world at {connect} (up to {attach_timeout:g} s)", err=True)
    try:
        done = run_command(
            lambda: attach_agent(
                robot,
                connect,
                run,
                attach_timeout,
                spec,
                cfg.base_url,
                cfg.client_options(spec),
                security=creds,
                policy=seats.get(robot),
                **options,
            )
        )
    except (
        AgentError,
        LLMFatalError,
        SecurityError,
        ConfigError,
    ) as exc:  # the world, the model or the setup: one line, exit 2
        click.echo(f"mhrc agent {robot}: {exc}", err=True)
        sys.exit(2)
    except Exception as exc:  # anything else: say what happened, exit 1
        raise click.ClickException(f"{type(exc).__name__}: {exc}") from None
    if done is not None:
        m = done.metrics
        click.echo(
            f"{robot}: episode {done.run} ended ({done.reason}): success={m.success} placed={m.placed}/{m.total} TS={m.temporal_steps}"
        )
