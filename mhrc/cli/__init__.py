"""The `mhrc` command: run an episode, a world alone, an agent, or a router."""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import shlex
import shutil
import signal
import sys
import time
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import click

from mhrc.core import logs
from mhrc.run.episode import ROBOTS, SCHEDULES, ConfigError, EpisodeConfig
from mhrc.core.fidelity import describe as describe_aids
from mhrc.run.lifeline import PARENT_ENV

ABLATIONS = ["none", "no_feedback", "no_history", "no_mobile"]
AIDS_HELP = (
    "Make the episode easier than the paper's (off by default; recorded in the trace and every result row): "
    "a comma-separated list of aids, or all. " + describe_aids()
)
SCHEDULE_HELP = (
    "The world's time policy: lockstep (every robot plans on the same state, the tick closes when all have acted), "
    "sequential (the paper's Algorithm 1: the robots plan and act one at a time, each on the world the earlier ones left) or "
    "async (not the paper's: no step barrier, each robot acts at its own pace and each action takes simulated time; "
    "the horizon is a budget of HORIZON x 8 simulated seconds and TS is the makespan in such steps)."
)
VIDEO_HELP = "Render the episode's video to FILE (.mp4 or .gif) with PyBullet's CPU renderer: a few frames per step, each captioned with every robot's action."
TIME_SCALE_HELP = "With --schedule async: simulated seconds per wall second (1: real time); 0: as fast as possible."
HISTORY_CAP_HELP = "Bound each LLM prompt to CHARS characters, shortening older history (for small-context models); default: whole histories, as the paper."
LLM_HELP = (
    "Drive the robots with a model: provider:model (openai:gpt-4o, ollama:llama3.1:8b, vllm:M, lmstudio:M, llamacpp:M), "
    "gguf:PATH (a local GGUF file served in-process by llama.cpp; needs pip install -e \".[local]\"), or per robot "
    "alice=SPEC,bob=SPEC,david=SPEC (a bare SPEC among them drives the rest; without one the rest play the heuristic "
    "policy); SPEC@URL names a spec's own server. Default: the heuristic policy."
)


def _llm_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """The model options `up`, `agent` and `eval` share, with the same meaning in each."""
    opts = [
        click.option("--llm", default=None, metavar="SPEC", help=LLM_HELP),
        click.option("--base-url", default=None, help="OpenAI-compatible server URL for --llm specs without their own, e.g. http://127.0.0.1:8000/v1."),
        click.option("--llm-timeout", default=None, type=float,
                     help="Seconds to the first token of an LLM reply (the server's prompt processing included; with --no-stream, to the whole reply); "
                          "a timeout is retried once. A reply that keeps producing tokens is not cut by it: --max-tokens and --step-deadline bound that. "
                          "Default: 120 (3x the slowest first token measured with 3 robots on a 2-core CPU), and 600 for gguf: models."),
        click.option("--llm-idle-timeout", default=None, type=float, metavar="SECONDS",
                     help="Seconds a streamed LLM reply may go without a token before the call is abandoned (and retried once). Default: 30."),
        click.option("--stream/--no-stream", default=True, show_default=True,
                     help="Stream LLM replies; --no-stream for servers that cannot (then --llm-timeout bounds the whole reply)."),
        click.option("--max-tokens", default=1024, show_default=True, type=int, help="Completion tokens per LLM call, sent on every request."),
        click.option("--llm-seed", default=None, type=int, help="Sampling seed sent on every LLM request (honoured by llama.cpp, vLLM, Ollama, OpenAI)."),
        click.option("--structured", is_flag=True,
                     help="Ask for JSON decisions that follow a schema of each step's valid actions (response_format json_schema; Ollama's format). Not the paper's: its free text is the default."),
        click.option("--step-deadline", default=None, type=float, metavar="SECONDS",
                     help="Bound one robot's whole LLM step, retries included; past it the robot waits that step (and its call is abandoned). "
                          "At least --llm-timeout. Default: none, as slow is not down: a stream that stalls ends after --llm-idle-timeout, "
                          "one that keeps producing tokens at --max-tokens."),
        click.option("--prompts", type=click.Path(file_okay=False, exists=True, path_type=Path), default=None,
                     help="Directory of your own prompt templates (ROBOT_system.txt, ROBOT_user.txt) for --llm."),
        click.option("--history-cap", type=int, default=None, metavar="CHARS", help=HISTORY_CAP_HELP),
    ]  # fmt: skip
    for opt in reversed(opts):
        f = opt(f)
    return f

T = TypeVar("T")


def _quit(code: int = 130) -> NoReturn:
    """Quit at once (os._exit: no `finally`, no waiting on threads)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def _quit_now(signum: int, frame: Any) -> None:
    """A signal while the run winds down: it is over anyway, so quit at once (130, as Ctrl-C)."""
    _quit(130)


def _plain_signals(loop: asyncio.AbstractEventLoop) -> None:
    """Take SIGINT and SIGTERM back from the event loop before it closes. asyncio closes its
    self-pipe before it removes its signal handlers; a signal landing in between (a parent's
    SIGTERM right after the group's Ctrl-C) printed "Exception ignored when trying to write to
    the signal wakeup fd" and a traceback."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.remove_signal_handler(sig)  # also clears the wakeup fd once none is left
        signal.signal(sig, _quit_now)


def _run(coro_fn: Callable[[], Coroutine[Any, Any, T]], *, stopping: str | Callable[[], str] | None = None) -> T:
    """Run a coroutine; SIGTERM cancels it like Ctrl-C, so every session closes in `finally`.
    A child of `mhrc up --processes` or `mhrc eval` gets SIGTERM when its parent dies.

    The first Ctrl-C cancels the run (saying `stopping`, what is being done, when given: a
    callable is asked at that moment); a second one quits at once: the children go with this
    process (mhrc.run.lifeline), never a hang."""
    from mhrc.run.lifeline import die_with_parent

    die_with_parent()

    async def main() -> T:
        task = asyncio.current_task()
        loop = asyncio.get_running_loop()
        if task is not None:
            loop.add_signal_handler(signal.SIGTERM, task.cancel)
            interrupts = 0

            def on_interrupt() -> None:
                nonlocal interrupts
                interrupts += 1
                if interrupts > 1:
                    sys.stderr.write("interrupted again: quitting at once\n")
                    _quit(130)
                said = stopping() if callable(stopping) else stopping
                if said:
                    sys.stderr.write(f"\ninterrupted: {said} (Ctrl-C again to quit at once)\n")
                    sys.stderr.flush()
                task.cancel()

            loop.add_signal_handler(signal.SIGINT, on_interrupt)
        try:
            return await coro_fn()
        finally:
            if task is not None:
                _plain_signals(loop)

    from mhrc.core.bus import BusError

    before = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        return asyncio.run(main())
    except (KeyboardInterrupt, asyncio.CancelledError):
        click.echo("interrupted", err=True)
        sys.exit(130)
    except BusError as exc:  # the bus cannot start (port taken, refused): one line that says what to do
        click.echo(f"mhrc: {exc}", err=True)
        sys.exit(2)
    finally:
        for sig, handler in before.items():  # what the caller had (a test's CliRunner, a later _run)
            signal.signal(sig, handler)


def _episode_options(f: Callable[..., Any]) -> Callable[..., Any]:
    opts = [
        click.option("--task", default="pack_objects", show_default=True, help="Task id."),
        click.option("--scene", default="kitchen", show_default=True, help="Scene layout."),
        click.option("--seed", default=0, show_default=True, type=int, help="Episode generator seed."),
        click.option("--objects", "n_objects", default=4, show_default=True, type=int, help="Target objects, 3-6."),
        click.option("--horizon", default=50, show_default=True, type=int, help="Temporal steps before the episode ends."),
        click.option("--run", default=None, help="Run id ([a-z0-9_-]+); default: a new random one."),
        click.option("--host", default="127.0.0.1", show_default=True, help="Address the world listens on."),
        click.option("--port", default=0, type=int, help="Port the world listens on; default: a free one."),
        click.option("--trace", type=click.Path(dir_okay=False, path_type=Path), default=None,
                     help="JSONL trace of every bus message; default runs/RUN/trace.jsonl."),
        click.option("--gui", is_flag=True, help="Show the PyBullet GUI (needs a display)."),
        click.option("--ablation", default="none", show_default=True, type=click.Choice(ABLATIONS),
                     help="Paper ablation: no_mobile leaves David out; no_feedback / no_history change LLM prompts."),
        click.option("--aids", default=None, metavar="NAMES", help=AIDS_HELP),
        click.option("--schedule", default="lockstep", show_default=True, type=click.Choice(SCHEDULES), help=SCHEDULE_HELP),
        click.option("--time-scale", default=0.0, show_default=True, type=float, help=TIME_SCALE_HELP),
        click.option("--log-level", default="warning", show_default=True, type=click.Choice(["debug", "info", "warning", "error"])),
    ]  # fmt: skip
    for opt in reversed(opts):
        f = opt(f)
    return f


def _credentials(path: Path | None, insecure: bool, connect: str | None = None) -> Any:
    """The participant's credentials (mhrc.core.security.Credentials) from --credentials or
    $MHRC_CREDENTIALS; None (and a warning on stderr) on the open bus. A tls/ `connect`
    without credentials is a usage error: it cannot work."""
    from mhrc.core.security import SecurityError, load

    if insecure:
        if not os.environ.get(PARENT_ENV):  # a child of mhrc up --processes or eval: its parent said it once
            click.echo("insecure: the open tcp bus (no TLS, no login, no access control)", err=True)
        return None
    if path is None:
        if connect is not None and connect.startswith("tls/"):
            raise click.UsageError(
                f"--credentials: {connect} is a secured world (tls/); pass this participant's credentials file "
                "(e.g. runs/RUN/credentials/<robot>.json, or DIR/<robot>.json of mhrc credentials) or set $MHRC_CREDENTIALS"
            )
        click.echo("no credentials (--credentials or $MHRC_CREDENTIALS): the open tcp bus, as with --insecure", err=True)
        return None
    try:
        return load(path)
    except SecurityError as exc:
        raise click.UsageError(f"--credentials: {exc}") from None


def _config(**values: Any) -> EpisodeConfig:
    values = {k: v for k, v in values.items() if v is not None}
    if values.get("gui") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise click.UsageError("--gui needs a display (DISPLAY is not set); run without --gui, or under xvfb-run")
    try:
        return EpisodeConfig.build(**values).resolved()
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="mhrc")
def main() -> None:
    """Heterogeneous robots, each driven by its own agent, collaborate on household tasks in a
    PyBullet world; the world and every agent talk over a Zenoh bus.

    Start with `mhrc up`: one Pack Objects episode with Alice (mobile manipulator), Bob (arm on
    table_0) and David (mobile robot) driven by the built-in heuristic policy.
    """
    logs.configure(os.environ.get("MHRC_LOG_LEVEL", "warning"))  # a command's --log-level overrides it


@main.command()
@_episode_options
@click.option("--processes", is_flag=True, help="Run the world and each agent as separate OS processes.")
@click.option("--external", multiple=True, type=click.Choice(ROBOTS),
              help="Do not start an agent for this robot: attach your own with `mhrc agent` (repeatable).")
@click.option("--quiet", "-q", is_flag=True, help="Print only the final summary table (errors still go to stderr).")
@click.option("--start-timeout", type=float, default=None,
              help="Start with the robots attached after this many seconds (fail if none is); default: wait for all of them.")
@click.option("--secure/--insecure", "secure", default=True, show_default=True,
              help="--secure (the default): fresh credentials in runs/RUN/credentials/ (TLS, a login per participant, "
                   "access control: an agent can act only as its own robot); --insecure: the open tcp bus, for loopback experiments.")
@click.option("--json", "as_json", is_flag=True, help="Print the final metrics as JSON on stdout.")
@click.option("--tick-delay", default=0.0, type=float, help="Seconds to pause between ticks (to watch with --gui).")
@click.option("--video", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help=VIDEO_HELP + " Rendered from the trace when the episode ends, so the run itself is not slowed.")
@_llm_options
def up(
    processes: bool, external: tuple[str, ...], quiet: bool, as_json: bool, log_level: str, video: Path | None, secure: bool, **values: Any
) -> None:
    """Run one episode: the world and the three robot agents, then print the metrics."""  # noqa: D401
    import functools

    from rich.console import Console

    from mhrc.world.service import NobodyAttached

    from mhrc.run.episode import ModelServerDown, ProcessFailed, check_model_servers, up_in_process, up_processes
    from mhrc.run.console import ProgressPrinter, summary_table

    logs.configure(log_level)
    cfg = _config(**values)
    if video is not None and video.suffix.lower() not in (".mp4", ".gif"):
        raise click.BadParameter(f"{video.name}: the video must be a .mp4 or .gif file", param_hint="--video")
    robots = tuple(r for r in cfg.robots if r not in external)
    try:
        check_model_servers(cfg, robots)  # before anything is written or started
    except ModelServerDown as exc:
        click.echo(f"mhrc up: {exc}", err=True)
        sys.exit(2)
    if not secure:
        click.echo("insecure: the open tcp bus (no TLS, no login, no access control)", err=True)
    else:
        cfg = cfg.with_credentials()
        if not quiet:
            click.echo(f"credentials in {cfg.credentials} (TLS, one login per participant, access control)", err=True)
    console = Console(highlight=False, stderr=as_json, soft_wrap=True)
    printer = None if quiet else ProgressPrinter(console, summary=False)  # the table is printed below, once the run returned
    if not quiet:
        console.print(f"world on {cfg.endpoint}, run {cfg.run}, trace {cfg.trace}")
    if external:  # needed to go on at all: said with --quiet too, on stderr
        click.echo("attach the external robots with: " + "; ".join(
            f"mhrc agent --robot {r} --run {cfg.run} --connect {cfg.endpoint}"
            + (f" --credentials {cfg.credentials_file(r)}" if cfg.credentials else "") for r in external), err=quiet or as_json)
    runner = functools.partial(up_processes, quiet=quiet) if processes else up_in_process
    from mhrc.agents.agent import AgentError
    from mhrc.agents.llm import LLMError
    from mhrc.agents.replay import ReplayMismatch

    try:
        done = _run(lambda: runner(cfg, observe=None if printer is None else printer.attach, robots=robots))
    except (AgentError, LLMError, ReplayMismatch) as exc:  # an agent could not play (its model, its replay, the world): one line
        click.echo(f"mhrc up: {exc}", err=True)
        sys.exit(2)
    except NobodyAttached as exc:
        click.echo(f"mhrc up: {exc}", err=True)
        sys.exit(1)
    except ProcessFailed as exc:
        if exc.returncode <= 0:  # killed, or gone without a word (a positive code: the process said why on stderr)
            click.echo(f"mhrc up: {exc}", err=True)
        sys.exit(exc.returncode if exc.returncode > 0 else 1)
    if printer is not None:
        printer.close()  # what arrived late for its tick, then nothing more: the table is the last line
    console.print(summary_table(done))
    if video is not None and cfg.trace is not None:
        path = _render_video(cfg.trace, video)
        if not quiet:
            console.print(f"video {path}")
    if as_json:
        click.echo(json.dumps(done.metrics.model_dump()))


def _serve_world(cfg: EpisodeConfig, observe: Callable[[Any, str], None] | None = None) -> None:
    """`mhrc world`'s run: one line and exit 1 when no robot attached within --start-timeout."""
    from mhrc.world.service import NobodyAttached

    from mhrc.run.episode import serve_world

    try:
        _run(lambda: serve_world(cfg, observe=observe))
    except NobodyAttached as exc:
        click.echo(f"mhrc world: {exc}", err=True)
        sys.exit(1)


@main.command()
@_episode_options
@click.option("--start-timeout", type=float, default=None,
              help="Start with the robots attached after this many seconds (fail if none is); default: wait for all three.")
@click.option("--tick-delay", default=0.0, type=float, help="Seconds to pause between ticks (to watch with --gui).")
@click.option("--quiet", "-q", is_flag=True, help="Print nothing but errors.")
@click.option("--credentials", type=click.Path(dir_okay=False, path_type=Path), default=None, envvar="MHRC_CREDENTIALS",
              help="This participant's credentials file (runs/RUN/credentials/<user>.json, written by `mhrc up`); "
                   "default $MHRC_CREDENTIALS. The bus is then TLS with a login and the world's access control.")
@click.option("--insecure", is_flag=True, help="The open tcp bus: no TLS, no login, no access control (anyone can act as any robot).")
def world(log_level: str, start_timeout: float | None, quiet: bool, credentials: Path | None, insecure: bool, **values: Any) -> None:
    """Run the world alone and wait for agents to attach (`mhrc agent`)."""
    from mhrc.run.console import ProgressPrinter

    logs.configure(log_level)
    creds = _credentials(credentials, insecure)
    if creds is not None:
        from mhrc.core.zenoh_log import watch_refusals

        watch_refusals()  # a refused login is said here too, not only on the refused agent's side
        if values.get("run") is None:
            values["run"] = creds.run
    cfg = _config(start_timeout=start_timeout, credentials=credentials if creds is not None else None, **values)
    if quiet:
        _serve_world(cfg)
        return
    printer = ProgressPrinter(verbose=False)

    def listening(bus: Any, run: str) -> None:  # said once the world listens, not before
        click.echo(f"world listening on {cfg.endpoint}, run {cfg.run}; attach agents with:", err=True)
        for r in ROBOTS:
            login = "" if creds is None else f" --credentials {_login_of(creds, r)}"
            click.echo(f"  mhrc agent --robot {r} --run {cfg.run} --connect {cfg.endpoint}{login}", err=True)
        printer.attach(bus, run)

    _serve_world(cfg, listening)


def _login_of(world: Any, user: str) -> str:
    """Where `user`'s credentials file lies beside the world's (`mhrc credentials` flat or
    --split, `mhrc up`'s runs/RUN/credentials/), or a placeholder naming it."""
    if world.path is not None:
        here = world.path.parent
        for candidate in (here / f"{user}.json", here.parent / user / f"{user}.json"):
            if candidate.is_file():
                return shlex.quote(str(candidate))
    return f"<{user}'s credentials file>"


@main.command()
@click.option("--robot", required=True, type=click.Choice(ROBOTS), help="The robot this agent drives.")
@click.option("--connect", required=True, help="The world's endpoint, e.g. tcp/127.0.0.1:7447.")
@click.option("--run", default=None, help="Run id of the world; default: the only world alive at --connect.")
@click.option("--attach-timeout", default=30.0, show_default=True, type=float, help="Seconds to wait for the world.")
@_llm_options
@click.option("--ablation", default="none", show_default=True, type=click.Choice(ABLATIONS), help="LLM prompt ablation.")
@click.option("--aids", default=None, metavar="NAMES", help="Agent-side aids (reach_labels, prompt_hints); the world's aids are set on the world. " + AIDS_HELP)
@click.option("--log-level", default="warning", show_default=True, type=click.Choice(["debug", "info", "warning", "error"]))
@click.option("--credentials", type=click.Path(dir_okay=False, path_type=Path), default=None, envvar="MHRC_CREDENTIALS",
              help="This participant's credentials file (runs/RUN/credentials/<user>.json, written by `mhrc up`); "
                   "default $MHRC_CREDENTIALS. The bus is then TLS with a login and the world's access control.")
@click.option("--insecure", is_flag=True, help="The open tcp bus: no TLS, no login, no access control (anyone can act as any robot).")
def agent(
    robot: str, connect: str, run: str | None, attach_timeout: float, log_level: str, credentials: Path | None, insecure: bool, **values: Any
) -> None:
    """Attach one robot's agent (heuristic or LLM policy) to a running world."""
    from mhrc.run.episode import attach_agent

    logs.configure(log_level)
    creds = _credentials(credentials, insecure, connect)
    cfg = _config(**values)
    spec = cfg.robot_specs().get(robot) if cfg.llm else None
    options = cfg.policy_options(spec)
    from mhrc.agents.agent import AgentError
    from mhrc.agents.llm import LLMFatalError

    from mhrc.core.security import SecurityError

    try:
        done = _run(lambda: attach_agent(
            robot, connect, run, attach_timeout, spec, cfg.base_url, cfg.client_options(spec), security=creds, **options))  # fmt: skip
    except (AgentError, LLMFatalError, SecurityError, ConfigError) as exc:  # the world, the model or the setup: one line, exit 2
        click.echo(f"mhrc agent {robot}: {exc}", err=True)
        sys.exit(2)
    except Exception as exc:  # anything else: say what happened, exit 1
        raise click.ClickException(f"{type(exc).__name__}: {exc}") from None
    if done is not None:
        m = done.metrics
        click.echo(f"{robot}: episode {done.run} ended ({done.reason}): success={m.success} placed={m.placed}/{m.total} TS={m.temporal_steps}")


@main.command()
def scenes() -> None:
    """List the scene layouts (world/scenes/*.json; `--scene FILE.json` loads your own)."""
    from mhrc.world.scene import LAYOUTS

    for layout in LAYOUTS.values():
        names = ", ".join(f"{f.name} ({f.kind})" if f.kind != f.name.split("_")[0] else f.name for f in layout.furniture)
        click.echo(f"{layout.name}: {layout.description}\n  furniture: {names}\n  file: {layout.source}")


@main.command()
@click.option("--scene", "scenes_", multiple=True, help="Scene layout or layout .json file (repeatable; default: every built-in layout).")
@click.option("--task", default="pack_objects", show_default=True, help="Task whose fixtures and objects are shown.")
@click.option("--seed", default=0, show_default=True, type=int, help="Episode whose objects are shown.")
@click.option("--objects", "n_objects", default=6, show_default=True, type=int)
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("renders"), show_default=True)
def render(scenes_: tuple[str, ...], task: str, seed: int, n_objects: int, out: Path) -> None:
    """Write top-down and perspective PNGs of each scene (CPU renderer, no display needed):
    OUT/<scene>_top.png and OUT/<scene>_perspective.png."""
    from mhrc.world.render import render_scene
    from mhrc.world.scene import LAYOUTS
    from mhrc.world.sim import check_episode

    try:
        for scene in scenes_ or tuple(LAYOUTS):
            check_episode(task=task, scene=scene, n_objects=n_objects)
        for scene in scenes_ or tuple(LAYOUTS):
            for path in render_scene(scene, out, seed=seed, n_objects=n_objects, task=task):
                click.echo(str(path))
    except ValueError as exc:
        raise click.UsageError(str(exc)) from None


def _csv(kind: type, text: str | None) -> tuple[Any, ...] | None:
    if text is None:
        return None
    try:
        return tuple(kind(x.strip()) for x in text.split(",") if x.strip())
    except ValueError:
        raise click.BadParameter(f"expected a comma-separated list, got {text!r}") from None


MAX_DAYS = 36500  # a certificate's end date must be a date: 100 years is plenty and far from datetime's year 9999


def _days(_ctx: click.Context, _param: click.Parameter, value: float) -> float:
    """--days: a finite number of days in (0, MAX_DAYS]; checked before anything is written."""
    if not (math.isfinite(value) and 0 < value <= MAX_DAYS):
        raise click.BadParameter(f"must be more than 0 and at most {MAX_DAYS} (got {value:g})")
    return value


def _cert_hosts(_ctx: click.Context, _param: click.Parameter, value: tuple[str, ...]) -> tuple[str, ...]:
    """--host: each a name or address a certificate can hold (ASCII, no spaces), checked before anything is written."""
    for h in value:
        if _is_ip(h):
            continue
        if not h or not h.isascii() or any(c.isspace() or c in "/:@" for c in h):
            raise click.BadParameter(f"{h!r} is not a host name or address (a name outside ASCII goes in its xn-- form)")
    return value


def _is_ip(text: str) -> bool:
    import ipaddress

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


@main.command("eval")
@_llm_options
@click.option("--tasks", default=None, help="Comma-separated task ids; default: every registered task.")
@click.option("--scenes", default=None, help="Comma-separated layouts; default: every built-in layout.")
@click.option("--objects", default=None, show_default="3,4,5,6", help="Comma-separated object counts (each scene runs every count).")
@click.option("--trials", default=1, show_default=True, type=int,
              help="Episodes per task, scene and object count in each repeat (the paper: 1).")
@click.option("--repeats", default=1, show_default=True, type=int,
              help="Run the grid this many times; an episode's seed is repeat x trials + trial, so repeat r of the paper grid uses seed r.")
@click.option("--ablation", default="none", show_default=True, type=click.Choice(ABLATIONS))
@click.option("--horizon", default=50, show_default=True, type=int)
@click.option("--aids", default=None, metavar="NAMES", help=AIDS_HELP)
@click.option("--schedule", default="sequential", show_default=True, type=click.Choice(SCHEDULES),
              help=SCHEDULE_HELP + " The paper's figures are shown beside sequential runs only.")
@click.option("--time-scale", default=0.0, show_default=True, type=float, help=TIME_SCALE_HELP)
@click.option("--workers", default=None, type=int, show_default="the number of cores",
              help="Local worker processes (not with --ray: the cluster's resources decide).")
@click.option("--concurrency", default=None, type=int,
              help="Episodes each local worker runs at once (with --ray: an LLM episode takes 1/concurrency of a CPU). Default: 1 for the "
                   "heuristic (CPU-bound), replays and gguf: models; with a model server, enough episodes to fill its slots "
                   "(llama.cpp's /props), else 12 for openai and vllm, 1 for ollama and lmstudio.")
@click.option("--ray", "ray_address", default=None, metavar="ADDRESS",
              help="Run every episode as a task on this Ray cluster: auto (a node of the cluster), HOST:PORT (the head, e.g. "
                   "10.0.0.5:6379) or ray://HOST:10001. Needs the extra: pip install -e \".[ray]\".")
@click.option("--shared-out", is_flag=True,
              help="With --ray: --out is the same path on every node (a shared file system), so tasks write their traces there "
                   "instead of sending them back through the object store.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None, help="Output directory; default runs/eval-<time>.")
@click.option("--resume", is_flag=True, help="Continue the evaluation in --out, skipping finished episodes.")
@click.option("--dry-run", is_flag=True, help="Print the episodes the grid holds (key, repeat, seed) and exit.")
@click.option("--log-level", default="warning", show_default=True, type=click.Choice(["debug", "info", "warning", "error"]))
def eval_(tasks: str | None, scenes: str | None, objects: str | None, trials: int, repeats: int, ablation: str, horizon: int,
          aids: str | None, schedule: str, time_scale: float, workers: int | None, concurrency: int | None, ray_address: str | None,
          shared_out: bool, out: Path | None, resume: bool, dry_run: bool, log_level: str, **llm: Any) -> None:  # fmt: skip
    """Run the paper's benchmark and write, to --out, one trace per episode, episodes.jsonl
    (every metric of every episode, its fidelity and the LLM failures that shaped it) and
    summary.md / summary.csv (tables shaped like the paper's Table I and II with 95% bootstrap
    intervals, the paper's figures beside a matching configuration, TS next to its lower bound)
    and summary.html (the tables, plots, a link to each episode's report).

    The default grid is the paper's: per task, 3 scenes x one episode each with 3, 4, 5 and 6
    objects (12 per task, 36 in all); --repeats N runs it N times with other seeds, --objects and
    --trials build larger grids. Without --llm the heuristic policy plays. Episodes run in
    --workers processes of this machine, or with --ray ADDRESS as tasks on a Ray cluster
    (`ray start --head` on one host, `ray start --address HEAD:6379` on the others; see
    docker/README.md). An interrupted run continues with --resume --out DIR."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from mhrc.world.scene import LAYOUTS
    from mhrc.world.tasks import TASKS

    from mhrc.eval.engine import EvalAborted, EvalSpec, Tally, check_out, evaluate
    from mhrc.core.fidelity import AidsError, parse_aids
    from mhrc.eval.report import PAPER_OBJECTS, SUMMARY_FILES, summary_markdown

    logs.configure(log_level)
    if ray_address is not None and workers is not None:
        raise click.UsageError("--workers: not with --ray (the Ray cluster's resources say how many episodes run at once)")
    if shared_out and ray_address is None:
        raise click.UsageError("--shared-out: only with --ray (a local run writes into --out anyway)")
    if workers is not None and workers < 1:
        raise click.BadParameter(f"must be at least 1 (got {workers})", param_hint="--workers")
    workers = workers or os.cpu_count() or 1
    try:
        aid_names = parse_aids(aids)
    except AidsError as exc:
        raise click.UsageError(str(exc)) from None
    prompts = llm.pop("prompts")
    spec = EvalSpec(
        tasks=_csv(str, tasks) or tuple(TASKS), scenes=_csv(str, scenes) or tuple(LAYOUTS),
        objects=PAPER_OBJECTS if objects is None else (_csv(int, objects) or ()), trials=trials, repeats=repeats,
        ablation=ablation, horizon=horizon, prompts=str(prompts) if prompts else None, aids=aid_names, schedule=schedule,
        time_scale=time_scale, **llm,
    )  # fmt: skip
    if concurrency is not None and concurrency < 1:
        raise click.BadParameter(f"must be at least 1 (got {concurrency})", param_hint="--concurrency")
    out = out or Path("runs") / time.strftime("eval-%Y%m%d-%H%M%S")
    console = Console(stderr=True)
    progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn(), console=console)
    bar = progress.add_task("episodes", total=None)

    def hook(t: Tally, row: dict[str, Any] | None) -> None:
        # the whole grid: with --resume, the episodes an earlier run finished count too
        rate = f"{t.before_succeeded + t.succeeded}/{t.before + t.done} solved" + (f", {t.errors} errors" if t.errors else "")
        rate += f", {t.invalid} invalid" if t.invalid else ""
        if t.before:
            rate += " (all from before)" if t.total == 0 else f" ({t.before} from before)"
        progress.update(bar, total=t.before + t.total, completed=t.before + t.done, description=f"{spec.method} [{rate}]")
        if row is not None and not row.get("valid", True):
            progress.console.print(f"[red]invalid[/]: {row['key']} ({row.get('invalid_reason')}); left out of the summary")
        elif row is not None and not row["success"]:
            progress.console.print(f"[yellow]not solved[/]: {row['key']} (PS {row['partial_success']:.2f}, TS {row['temporal_steps']})")

    try:
        spec.validate()
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
    n_jobs = len(spec.jobs())
    if dry_run:
        for job in spec.jobs():
            click.echo(f"{job.key} repeat={job.repeat} trial={job.trial} seed={job.config['seed']}")
        click.echo(f"{n_jobs} episodes ({spec.fidelity} fidelity)")
        return
    try:
        check_out(out, spec, resume)  # before the model server is asked or a worker starts
        if ray_address is not None:  # a missing extra, an old Ray, an address nothing answers at: one line, now
            from mhrc.eval.cluster import import_ray, probe

            import_ray()
            probe(ray_address)
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
    rows_path = out / "episodes.jsonl"

    def stopping() -> str:
        """What the first Ctrl-C says: where the finished episodes are, only if one has finished."""
        kept = rows_path.exists() and rows_path.stat().st_size > 0
        where = f"every finished episode is kept in {rows_path}" if kept else "no episode has finished yet"
        return f"stopping the workers; {where} (continue with --resume --out {out})"

    if concurrency is None:
        from mhrc.agents.llm import episodes_at_once

        specs = EpisodeConfig.build(**spec.jobs()[0].config).robot_specs().values() if spec.llm else [None]
        concurrency = asyncio.run(episodes_at_once(list(specs), spec.base_url))
    where = f"on the Ray cluster at {ray_address}" if ray_address else f"with {workers} worker(s)"
    console.print(
        f"evaluating {spec.method} (ablation {ablation}, fidelity {spec.fidelity}, {spec.mode} replies) on {n_jobs} episodes "
        f"into {out} {where}, {concurrency} episode(s) at once each"
    )
    t0 = time.perf_counter()
    with progress:
        try:
            rows = _run(
                lambda: evaluate(spec, out, workers=1 if ray_address else workers, resume=resume, progress=hook, concurrency=concurrency,
                                 ray=ray_address, shared_out=shared_out),
                stopping=stopping,
            )
        except ConfigError as exc:
            raise click.UsageError(str(exc)) from None
        except EvalAborted as exc:
            raise click.ClickException(str(exc)) from None
    written = [p for p in (rows_path, *(out / name for name in SUMMARY_FILES)) if p.exists()]
    errors = out / "errors.jsonl"
    console.print(
        f"done in {time.perf_counter() - t0:.1f} s: "
        + (", ".join(map(str, written)) if rows else "no episode finished")
        + (f" (episodes given up: {errors})" if errors.exists() else "")
    )
    if rows:
        click.echo(summary_markdown(rows))


@main.command("report")
@click.argument("dirs", nargs=-1, required=True, type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="FILE.md",
              help="Write the markdown to FILE.md instead of stdout, FILE.csv and FILE.html beside it; the files written are named on stderr.")
@click.option("--resamples", default=2000, show_default=True, type=click.IntRange(min=1), help="Bootstrap resamples per 95% confidence interval.")
@click.option("--seed", default=0, show_default=True, type=int, help="Seed of the bootstrap (the same rows and seed give the same intervals).")
def report(dirs: tuple[Path, ...], out: Path | None, resamples: int, seed: int) -> None:
    """Merge `mhrc eval` directories into one comparison (markdown on stdout): Succ, PS, TS
    and AS per task with 95% bootstrap confidence intervals, grouped by method, ablation and
    fidelity, and the paper's Table I / II figures beside the settings that match its
    configuration. Invalid episodes (model unreachable throughout) are left out and listed.
    With --out FILE.md, the markdown goes there instead, with FILE.csv and FILE.html (tables,
    plots, a link to each episode's report) beside it."""
    from mhrc.eval.report import merge_runs, summary_csv, summary_markdown
    from mhrc.core.trace import unwritable

    if out is not None:
        files = [out, out.with_suffix(".csv"), out.with_suffix(".html")]
        if len(set(files)) < len(files):
            raise click.BadParameter(f"{out} would be overwritten by the CSV or HTML beside it; name a .md file", param_hint="--out")
        for f in files:
            if why := unwritable(f):
                raise click.BadParameter(why, param_hint="--out")
    try:
        rows = merge_runs(list(dirs))
    except ConfigError as exc:
        raise click.UsageError(str(exc)) from None
    if not rows:
        raise click.UsageError("no finished episodes in " + ", ".join(map(str, dirs)))
    text = summary_markdown(rows, resamples=resamples, seed=seed)
    if out is None:
        click.echo(text)
        return
    from mhrc.eval.html import write_report_html

    md, csv, html = files
    md.write_text(text, encoding="utf-8")
    csv.write_text(summary_csv(rows, resamples=resamples, seed=seed), encoding="utf-8")
    write_report_html(list(dirs), html, resamples=resamples, seed=seed)
    click.echo(f"wrote {md}, {csv}, {html}", err=True)


@main.command("schema")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Write one <Payload>.json per bus payload and index.json into this directory; default: print one JSON document.")
def schema_(out: Path | None) -> None:
    """The JSON Schema of every bus payload, for agents in any language (README, "Attaching your own agent")."""
    from mhrc.core import schema as schema_mod

    if out is None:
        click.echo(json.dumps(schema_mod.document(), indent=2))
        return
    for path in schema_mod.write(out):
        click.echo(str(path))


@main.command("credentials")
@click.option("--out", required=True, type=click.Path(file_okay=False, path_type=Path), help="The directory to write them into (created 0700).")
@click.option("--run", default=None, help="The run id they are for; default: a new random one (the world and agents take it from them).")
@click.option("--host", "hosts", multiple=True, metavar="NAME",
              callback=_cert_hosts,
              help="A name or address the agents reach the world by, besides 127.0.0.1 and localhost (repeatable): "
                   "e.g. world, the compose service. The world's certificate names it.")
@click.option("--days", default=7.0, show_default=True, type=float, callback=_days,
              help=f"How long the CA and the world's certificate stay valid from now: more than 0, at most {MAX_DAYS} (fractions allowed: 0.5 is 12 hours).")
@click.option("--split", is_flag=True, help="One directory per participant (DIR/world/, DIR/alice/, ...), each for that participant's container only.")
@click.option("--force", is_flag=True, help="Replace credentials already in DIR (a world running with the old ones refuses the new).")
def credentials_(out: Path, run: str | None, hosts: tuple[str, ...], days: float, split: bool, force: bool) -> None:
    """Issue one run's credentials for a world and agents started by hand or in containers
    (`mhrc up` makes its own): a CA, the world's TLS certificate, one login per participant.
    Start the world with --credentials DIR/world.json and each agent with its own file."""
    from mhrc.core.keys import check_id, new_run_id
    from mhrc.core.security import SecurityError, make_run_credentials

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
        files = make_run_credentials(run, ROBOTS, out, days=days, hosts=hosts, split=split)
    except (SecurityError, ValueError, OSError) as exc:
        if created is not None:  # nothing left behind: what this command created goes again
            shutil.rmtree(created, ignore_errors=True)
        if isinstance(exc, OSError):
            raise click.UsageError(f"--out: cannot write the credentials into {out}: {exc.strerror or exc}") from None
        raise click.UsageError(str(exc)) from None
    click.echo(f"run {run}: credentials in {out} (valid {days:g} days; keep them private)", err=True)
    for user, path in files.items():
        click.echo(f"  {user}: {path}", err=True)


@main.group("bus")
def bus_group() -> None:
    """Look at a running bus: who is alive (`list`), every message on a key (`echo`)."""


def _bus_tool(name: str, coro_fn: Callable[[], Coroutine[Any, Any, int]]) -> None:
    """Run a bus tool: its exit code, or one clear line on stderr and exit 1 (mhrc.core.bustools)."""
    from mhrc.core.bustools import BusToolError

    try:
        code = _run(coro_fn)
    except BusToolError as exc:
        click.echo(f"mhrc {name}: {exc}", err=True)
        sys.exit(1)
    sys.exit(code)


CREDENTIALS_OPT = click.option(
    "--credentials", type=click.Path(dir_okay=False, path_type=Path), default=None, envvar="MHRC_CREDENTIALS",
    help="A login of a secured run, with a tls/ endpoint: the observer's (runs/RUN/credentials/observer.json, or "
         "DIR/observer.json of mhrc credentials) reads the whole run and asks the world's state; a robot's sees only its own keys.",
)  # fmt: skip


@bus_group.command("list")
@click.option("--connect", required=True, help="Endpoint of a world or router, e.g. tcp/127.0.0.1:7447.")
@click.option("--json", "as_json", is_flag=True, help="One JSON object: the endpoint and every run or evaluation alive.")
@CREDENTIALS_OPT
def bus_list(connect: str, as_json: bool, credentials: Path | None) -> None:
    """The runs alive (from liveliness): which have a world, which robots are attached."""
    from mhrc.core.bustools import bus_list as run_list

    _bus_tool("bus list", lambda: run_list(connect, as_json=as_json, credentials=credentials, write=click.echo))


@bus_group.command("echo")
@click.argument("keyexpr")
@click.option("--connect", required=True, help="Endpoint of a world or router, e.g. tcp/127.0.0.1:7447.")
@click.option("--json", "as_json", is_flag=True, help="One JSON object per message (a trace line: t, key, kind, msg).")
@click.option("--count", type=click.IntRange(min=1), default=None, help="Exit after N messages.")
@click.option("--timeout", type=click.FloatRange(min=0), default=None, help="Exit after this many seconds (exit 1 if --count was not reached).")
@CREDENTIALS_OPT
def bus_echo(keyexpr: str, connect: str, as_json: bool, count: int | None, timeout: float | None, credentials: Path | None) -> None:
    """Print every message on KEYEXPR (e.g. 'mhrc/**' or 'mhrc/RUN/robot/*/action/result'),
    decoded with the protocol, one line each: time, key, kind, summary."""
    from mhrc.core.bustools import bus_echo as run_echo

    _bus_tool("bus echo", lambda: run_echo(connect, keyexpr, as_json=as_json, count=count, timeout=timeout, credentials=credentials, write=click.echo))


@main.command()
@click.option("--connect", required=True, help="Endpoint to check, e.g. tcp/127.0.0.1:7447.")
@CREDENTIALS_OPT
def doctor(connect: str, credentials: Path | None) -> None:
    """Check a bus endpoint: is a zenoh router or world there, which runs are alive, which
    protocol version each world speaks. Exit code 0 healthy, 1 not."""
    from mhrc.core.bustools import doctor as run_doctor

    _bus_tool("doctor", lambda: run_doctor(connect, credentials=credentials, write=click.echo))


@main.command()
@click.argument("run_or_trace", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="The HTML file to write; default: beside the trace, with .html (with --video: only when --out is given).")
@click.option("--video", type=click.Path(dir_okay=False, path_type=Path), default=None, help=VIDEO_HELP)
def show(run_or_trace: Path, out: Path | None, video: Path | None) -> None:
    """Write one self-contained HTML report of an episode (map, robot lanes, messages, failures)
    from RUN_OR_TRACE: a trace file, or a run directory holding trace.jsonl. Prints its path.
    With --video, render the episode's video instead (or as well, with --out)."""
    from mhrc.viewer.load import NotATrace
    from mhrc.viewer.show import write_report

    if video is None or out is not None:
        try:
            path, warnings = write_report(run_or_trace, out)
        except NotATrace as exc:
            click.echo(f"mhrc show: {exc}", err=True)
            sys.exit(2)
        except OSError as exc:
            click.echo(f"mhrc show: cannot read or write: {exc}", err=True)
            sys.exit(1)
        if warnings:
            click.echo("mhrc show: warning: " + "; ".join(warnings), err=True)
        click.echo(str(path))
    if video is not None:
        trace = run_or_trace / "trace.jsonl" if run_or_trace.is_dir() else run_or_trace
        click.echo(str(_render_video(trace, video)))


def _render_video(trace: Path, video: Path) -> Path:
    """Render `trace` to `video` with a progress bar; one clear line and exit 2 on a bad input."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from mhrc.viewer.video import render_video

    with Progress(TextColumn("video"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(), console=Console(stderr=True)) as bar:
        task = bar.add_task("frames", total=None)
        try:
            info = render_video(trace, video, progress=lambda done, total: bar.update(task, completed=done, total=total))
        except (ValueError, OSError) as exc:  # VideoError is a ValueError
            bar.stop()
            click.echo(f"mhrc show: {exc}", err=True)
            sys.exit(2)
    click.echo(f"{info.frames} frames in {info.render_seconds:.1f} s ({info.bytes / 1e6:.2f} MB)", err=True)
    return info.path


@main.command()
@click.option("--host", default="127.0.0.1", show_default=True)
@click.option("--port", default=7447, show_default=True, type=int)
def router(host: str, port: int) -> None:
    """Run a Zenoh router that worlds and agents on several hosts can all connect to."""
    from mhrc.core.bus import Bus, endpoint

    async def serve() -> None:
        bus = await Bus.open(mode="router", listen=[endpoint(host, port)])
        try:
            click.echo(f"router listening on {endpoint(host, port)}; Ctrl-C to stop", err=True)
            await asyncio.Event().wait()
        finally:
            await bus.close()

    _run(serve)


if __name__ == "__main__":
    main()
