"""The options several commands share, declared once, and the checks that turn them into a config."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from mhrc.cli.names import SCHEDULES, check_protocol, check_scene, check_task, unknown_team
from mhrc.core.aids import NOISE
from mhrc.core.aids import describe as describe_aids
from mhrc.core.deadlines import TOKEN_DEADLINE
from mhrc.core.lifeline import PARENT_ENV

if TYPE_CHECKING:  # pragma: no cover
    from mhrc.core.security import Credentials  # the wire's models and cryptography: imported when a file is read
    from mhrc.run.config import EpisodeConfig  # imports the bus: the commands import it when they run

__all__ = ["SCHEDULES"]  # (and the options below) SCHEDULES: the world's, mhrc.world.schedules

ABLATIONS = ["none", "no_feedback", "no_history", "no_mobile"]
AIDS_HELP = (
    "Make the episode easier than the paper's (off by default; recorded in the trace and every result row): "
    "a comma-separated list of aids, or all. " + describe_aids()
)
NOISE_HELP = (
    "The world's motion noise: mhrc's calibration, not the paper's (recorded in the trace and every result row). "
    + " ".join(f"{k}: {v}." for k, v in NOISE.items())
    + " The exact_motion aid has no noise either, and also sets released objects down without physics."
)
SCHEDULE_HELP = (
    "The world's time policy: lockstep (every robot plans on the same state, the tick closes when all have acted), "
    "sequential (the paper's Algorithm 1: the robots plan and act one at a time, each on the world the earlier ones left) or "
    "async (not the paper's: no step barrier, each robot acts at its own pace and each action takes simulated time; "
    "the horizon is a budget of HORIZON x 8 simulated seconds and TS is the makespan in such steps)."
)
VIDEO_HELP = "Render the episode's video to FILE (.mp4 or .gif) with PyBullet's CPU renderer: a few frames per step, each captioned with every robot's action."


def _video_size(ctx: click.Context, param: click.Parameter, value: str) -> tuple[int, int]:
    """WIDTHxHEIGHT, checked before anything runs."""
    width, sep, height = value.lower().partition("x")
    if not (sep and width.isdigit() and height.isdigit()) or min(int(width), int(height)) < 64:
        raise click.BadParameter(f"expected WIDTHxHEIGHT, each at least 64 (e.g. 1280x960), got {value!r}")
    return int(width), int(height)


VIDEO_SIZE = click.option(
    "--video-size",
    default="640x480",
    show_default=True,
    metavar="WxH",
    callback=_video_size,
    help="The video's frame size. At 640x480 the whole house fits and an object is a few pixels wide; 1280x960 "
    "shows the objects clearly, at about four times the render time (even numbers for .mp4).",
)
TIME_SCALE_HELP = "With --schedule async: simulated seconds per wall second (1: real time); 0: as fast as possible."
EVENTS_HELP = (
    "A scenario: a JSON list of events the world applies during the episode, each with the tick it fires at and a kind "
    "(relocate, breakdown, new_target, close): a file's path, or the name of a shipped one (mhrc scenarios lists them; "
    "an existing file wins); checked before anything starts."
)
TOKEN_DEADLINE_HELP = (
    "Seconds an agent has, once the world accepted its attach, to show its liveliness token (mhrc/RUN/alive/robot/ROBOT) "
    "before the world detaches its robot. mhrc's agents declare the token before they attach, so this only bounds how long "
    "an agent frozen or killed while attaching, or a hand-written one that skips the token, can hold up the episode."
)
HISTORY_CAP_HELP = "Bound each LLM prompt to CHARS characters, shortening older history (for small-context models); default: whole histories, as the paper."
LLM_HELP = (
    "Drive the robots with a model: provider:model (openai:gpt-4o, ollama:llama3.1:8b, vllm:M, lmstudio:M, llamacpp:M), "
    'gguf:PATH (a local GGUF file served in-process by llama.cpp; needs pip install -e ".[local]"), or per robot '
    "alice=SPEC,bob=SPEC,david=SPEC (a bare SPEC among them drives the rest; without one the rest play the heuristic "
    "policy); SPEC@URL names a spec's own server. Default: the heuristic policy."
)


def _check_events(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
    """--events as given (a shipped name travels as a name), once it is known to name a scenario."""
    if value is not None:
        from mhrc.world.scenario import ScenarioError, resolve_scenario  # pydantic: only when --events is given

        try:
            resolve_scenario(value)
        except ScenarioError as exc:
            raise click.UsageError(str(exc), ctx=ctx) from None
    return value


def events_option(help: str = EVENTS_HELP) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """--events FILE|NAME: a scenario file or a shipped scenario's name (mhrc.world.scenario.resolve_scenario)."""
    return click.option("--events", default=None, metavar="FILE|NAME", callback=_check_events, help=help)


def llm_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """The model options `up`, `agent` and `eval` share, with the same meaning in each."""
    opts = [
        click.option("--llm", default=None, metavar="SPEC", help=LLM_HELP),
        click.option(
            "--base-url",
            default=None,
            help="OpenAI-compatible server URL for --llm specs without their own, e.g. http://127.0.0.1:8000/v1.",
        ),
        click.option(
            "--llm-timeout",
            default=None,
            type=float,
            help="Seconds to the first token of an LLM reply (the server's prompt processing included; with --no-stream, to the whole reply); "
            "a timeout is retried once. A reply that keeps producing tokens is not cut by it: --max-tokens and --step-deadline bound that. "
            "Default: 120 (3x the slowest first token measured with 3 robots on a 2-core CPU), and 600 for gguf: models.",
        ),
        click.option(
            "--llm-idle-timeout",
            default=None,
            type=float,
            metavar="SECONDS",
            help="Seconds a streamed LLM reply may go without a token before the call is abandoned (and retried once). Default: 30.",
        ),
        click.option(
            "--stream/--no-stream",
            default=True,
            show_default=True,
            help="Stream LLM replies; --no-stream for servers that cannot (then --llm-timeout bounds the whole reply).",
        ),
        click.option(
            "--max-tokens",
            default=1024,
            show_default=True,
            type=int,
            help="Completion tokens per LLM call, sent on every request.",
        ),
        click.option(
            "--llm-seed",
            default=None,
            type=int,
            help="Sampling seed sent on every LLM request (honoured by llama.cpp, vLLM, Ollama, OpenAI).",
        ),
        click.option(
            "--structured",
            is_flag=True,
            help="Ask for JSON decisions that follow a schema of each step's valid actions (response_format "
            "json_schema; Ollama's format). Not the paper's: its free text is the default.",
        ),
        click.option(
            "--step-deadline",
            default=None,
            type=float,
            metavar="SECONDS",
            help="Bound one robot's whole LLM step, retries included; past it the robot waits that step (and its call is abandoned). "
            "At least --llm-timeout. Default: none, as slow is not down: a stream that stalls ends after --llm-idle-timeout, "
            "one that keeps producing tokens at --max-tokens.",
        ),
        click.option(
            "--prompts",
            type=click.Path(file_okay=False, exists=True, path_type=Path),
            default=None,
            help="Directory of your own prompt templates for --llm: ROBOT_system.txt, ROBOT_user.txt (one robot) "
            "or KIND_system.txt, KIND_user.txt (every robot of a kind); a missing file falls back to the shipped one "
            "(docs/llm.md).",
        ),
        click.option("--history-cap", type=int, default=None, metavar="CHARS", help=HISTORY_CAP_HELP),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


RERUN_HELP = (
    "Also make a Rerun recording of the episode (pip install 'mhrc[rerun]'): OUT.rrd, a file; `serve`, Rerun's "
    "web viewer on 127.0.0.1 (its address is printed); `spawn`, the native viewer."
)


def rerun_option(
    help: str = RERUN_HELP, metavar: str = "OUT.rrd|serve|spawn", directory: bool = False
) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """--rerun: a Rerun recording (mhrc.viewer.rerun), checked before anything starts (rerun-sdk installed,
    the file or, with `directory`, the directory writable) into a Target; a bad one is one line."""

    def check(ctx: click.Context, param: click.Parameter, value: str | None) -> Any:
        if value is None:
            return None
        from mhrc.viewer.rerun import RerunError, parse_target

        try:
            return parse_target(value, directory=directory)
        except RerunError as exc:
            raise click.UsageError(str(exc)) from None

    return click.option("--rerun", "rerun", default=None, metavar=metavar, callback=check, help=help)


LOG_LEVEL = click.option(
    "--log-level",
    default="warning",
    show_default=True,
    type=click.Choice(["debug", "info", "warning", "error"]),
    help="How much of the participants' log to print on stderr (structlog lines with run, robot and tick): "
    "debug and info also show each step's inner workings; default: only what went wrong. $MHRC_LOG_LEVEL sets it "
    "for commands without the option.",
)
INSECURE_HELP = "The open tcp bus: no TLS, no login, no access control (anyone can act as any robot)."


def credentials_option(help: str) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """--credentials: a credentials file, default $MHRC_CREDENTIALS; `help` says whose."""
    return click.option(
        "--credentials",
        type=click.Path(dir_okay=False, path_type=Path),
        default=None,
        envvar="MHRC_CREDENTIALS",
        help=help,
    )


TEAM_HELP = (
    "The robots: a shipped team's name (mhrc teams), a TOML or JSON file (robots with name, kind, optional "
    "start and llm; docs/teams.md), or inline: alice=mobile_manipulator,bob=tabletop_arm,lucy=drone. "
    "Default: paper (Alice, Bob and David)."
)


def _team(ctx: click.Context, param: click.Parameter, value: str | None) -> Any:
    """--team read into a TeamSpec before anything starts; a bad one is one line naming the problem."""
    if value is None:
        return None
    if (refused := unknown_team(value)) is not None:  # before the teams' registry imports the simulator
        raise click.UsageError(refused)
    from mhrc.core.team import TeamError
    from mhrc.run.teams import resolve_team

    try:
        return resolve_team(value)
    except TeamError as exc:
        raise click.UsageError(str(exc)) from None


def team_option(f: Callable[..., Any]) -> Callable[..., Any]:
    return click.option("--team", default=None, metavar="TEAM", callback=_team, help=TEAM_HELP)(f)


PROTOCOL_HELP = (
    "How the team decides, a coordination protocol (mhrc protocols; docs/protocols.md): mhrc, the paper's (each robot "
    "its own agent); centralized (one planner drives every robot); leader (an elected leader allocates by auction). "
    "Not the paper's unless mhrc: recorded in the trace and every result row."
)


def protocol_option(f: Callable[..., Any]) -> Callable[..., Any]:
    return click.option(
        "--protocol", default="mhrc", show_default=True, metavar="NAME", callback=check_protocol, help=PROTOCOL_HELP
    )(f)


def episode_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """The episode options `up` and `world` share (task, scene, seed, horizon, schedule, ...)."""
    opts: list[Callable[[Callable[..., Any]], Callable[..., Any]]] = [
        click.option("--task", default="pack_objects", show_default=True, callback=check_task, help="Task id."),
        click.option("--scene", default="kitchen", show_default=True, callback=check_scene, help="Scene layout."),
        click.option("--seed", default=0, show_default=True, type=int, help="Episode generator seed."),
        click.option("--objects", "n_objects", default=4, show_default=True, type=int, help="Target objects, 3-6."),
        click.option(
            "--horizon", default=50, show_default=True, type=int, help="Temporal steps before the episode ends."
        ),
        click.option("--run", default=None, help="Run id ([a-z0-9_-]+); default: a new random one."),
        click.option("--host", default="127.0.0.1", show_default=True, help="Address the world listens on."),
        click.option("--port", default=0, type=int, help="Port the world listens on; default: a free one."),
        click.option(
            "--trace",
            type=click.Path(dir_okay=False, path_type=Path),
            default=None,
            help="JSONL trace of every bus message; default runs/RUN/trace.jsonl.",
        ),
        click.option("--gui", is_flag=True, help="Show the PyBullet GUI (needs a display)."),
        click.option(
            "--ablation",
            default="none",
            show_default=True,
            type=click.Choice(ABLATIONS),
            help="Paper ablation: no_mobile leaves out the robots that only navigate (the paper's David); "
            "no_feedback / no_history change LLM prompts.",
        ),
        team_option,
        protocol_option,
        click.option("--aids", default=None, metavar="NAMES", help=AIDS_HELP),
        click.option("--noise", default="on", show_default=True, type=click.Choice(list(NOISE)), help=NOISE_HELP),
        click.option(
            "--schedule", default="lockstep", show_default=True, type=click.Choice(SCHEDULES), help=SCHEDULE_HELP
        ),
        click.option("--time-scale", default=0.0, show_default=True, type=float, help=TIME_SCALE_HELP),
        click.option(
            "--token-deadline",
            default=TOKEN_DEADLINE,
            show_default=True,
            type=float,
            metavar="SECONDS",
            help=TOKEN_DEADLINE_HELP,
        ),
        events_option(),
        LOG_LEVEL,
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


OPEN_BUS = "insecure: the open tcp bus (no TLS, no login, no access control)"  # what a participant on it says


def load_credentials(path: Path | None, insecure: bool, connect: str | None = None) -> Credentials | None:
    """The participant's credentials (mhrc.core.security.Credentials) from --credentials or
    $MHRC_CREDENTIALS; None on the open bus (`open_bus_notice` says so, once the rest of the
    command line is accepted). A tls/ `connect` without credentials is a usage error: it cannot work."""
    if insecure:
        return None
    if path is None:
        if connect is not None and connect.startswith("tls/"):
            raise click.UsageError(
                f"--credentials: {connect} is a secured world (tls/); pass this participant's credentials file "
                "(e.g. runs/RUN/credentials/<robot>.json, or DIR/<robot>.json of mhrc credentials) or set $MHRC_CREDENTIALS"
            )
        return None
    from mhrc.core.security import SecurityError, load

    try:
        return load(path)
    except SecurityError as exc:
        raise click.UsageError(f"--credentials: {exc}") from None


def open_bus_notice(insecure: bool) -> None:
    """On stderr: this participant is on the open bus (said after its options are checked, so a
    refused command line ends with its error alone)."""
    if not insecure:
        click.echo(
            "no credentials (--credentials or $MHRC_CREDENTIALS): the open tcp bus, as with --insecure", err=True
        )
    elif not os.environ.get(PARENT_ENV):  # a child of mhrc up --processes or eval: its parent said it once
        click.echo(OPEN_BUS, err=True)


def episode_config(**values: Any) -> EpisodeConfig:
    """The episode's config from the options given; a bad value is a usage error naming its option."""
    from mhrc.run.config import ConfigError, EpisodeConfig

    values = {k: v for k, v in values.items() if v is not None}
    if values.get("gui") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise click.UsageError("--gui needs a display (DISPLAY is not set); run without --gui, or under xvfb-run")
    try:
        return EpisodeConfig.build(**values).resolved()
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None


OVERWRITE = click.option(
    "--overwrite",
    is_flag=True,
    help="Replace the trace (and its report, trace.html) of an earlier episode at the same --run or --trace; "
    "without it, such a run is refused and the earlier trace kept.",
)


def fresh_trace(command: str, cfg: EpisodeConfig, overwrite: bool, given_trace: bool) -> None:
    """Refuse (one line, exit 2) a run whose trace file exists already, so that a reused --run never
    destroys an earlier episode; with --overwrite, remove that trace and the report made of it."""
    trace = cfg.trace
    if trace is None or not trace.is_file() or trace.stat().st_size == 0:
        return  # nothing there, an empty file, or a device (/dev/null, /dev/full) or pipe: no trace to lose
    if not overwrite:
        option = f"--trace {trace}" if given_trace else f"--run {cfg.run}"
        click.echo(
            f"mhrc {command}: {option}: {trace} holds an earlier episode's trace; choose another "
            + ("--trace" if given_trace else "--run (or leave it out for a new one)")
            + ", or pass --overwrite to replace it",
            err=True,
        )
        raise SystemExit(2)
    for stale in (trace, trace.with_suffix(".html")):  # the report of the replaced trace describes nothing any more
        stale.unlink(missing_ok=True)
