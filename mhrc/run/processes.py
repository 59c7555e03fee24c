"""`mhrc up --processes`: the world and each agent as separate OS processes (`mhrc world`,
`mhrc agent`) that die with this one."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from mhrc.core.bus import open_client
from mhrc.core.deadlines import ATTACH_TIMEOUT
from mhrc.core.endpoints import check_listen
from mhrc.core.keys import Keys
from mhrc.core.lifeline import child_env
from mhrc.core.logs import get_logger
from mhrc.core.protocol import EpisodeDone, EpisodeStarted, ProtocolError, decode_event
from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.core.records import messages, read_records
from mhrc.core.team import PAPER_TEAM
from mhrc.run.attach import local_models
from mhrc.run.config import EpisodeConfig
from mhrc.run.errors import ProcessFailed as ProcessFailed  # defined apart: mhrc up catches it without this module
from mhrc.run.serve import EventHook
from mhrc.run.teams import team_argument

log = get_logger("mhrc.run.processes")


def _child_env() -> dict[str, str]:
    env = child_env()  # the world and agents die with this process, even after a SIGKILL
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def _child_stdout() -> int | None:
    """Children print to this process's stderr: stdout is for `--json` output alone."""
    try:
        return sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        return None


def team_args(cfg: EpisodeConfig) -> list[str]:
    """`--team` for a child process; nothing for the paper's team (its argv as it always was)."""
    return [] if cfg.team == PAPER_TEAM else ["--team", team_argument(cfg.team)]


def world_command(cfg: EpisodeConfig) -> list[str]:
    cmd = [
        sys.executable,
        "-m",
        "mhrc",
        "world",
        "--task",
        cfg.task,
        "--scene",
        cfg.scene,
        "--seed",
        str(cfg.seed),
        "--objects",
        str(cfg.n_objects),
        "--horizon",
        str(cfg.horizon),
        "--run",
        cfg.run,
        "--host",
        cfg.host,
        "--port",
        str(cfg.port),
        "--quiet",
        "--ablation",
        cfg.ablation,
        "--schedule",
        cfg.schedule,
        "--token-deadline",
        str(cfg.token_deadline),
    ]
    if cfg.trace is not None:
        cmd += ["--trace", str(cfg.trace)]
    cmd += team_args(cfg) + protocol_args(cfg)
    if cfg.aids:
        cmd += ["--aids", ",".join(cfg.aids)]
    if cfg.noise != "on":
        cmd += ["--noise", cfg.noise]
    if cfg.tick_delay:
        cmd += ["--tick-delay", str(cfg.tick_delay)]
    if cfg.start_timeout is not None:
        cmd += ["--start-timeout", str(cfg.start_timeout)]
    if cfg.time_scale:
        cmd += ["--time-scale", str(cfg.time_scale)]
    if cfg.events is not None:
        cmd += ["--events", str(cfg.events)]
    if cfg.credentials is not None:
        cmd += ["--credentials", str(cfg.credentials_file("world"))]
    else:  # said, so that a $MHRC_CREDENTIALS of another run is not picked up
        cmd += ["--insecure"]
    return cmd


def participants(cfg: EpisodeConfig, robots: tuple[str, ...]) -> list[tuple[str, ...]]:
    """The robots of each agent process: one each, or all in one under a whole-team protocol (a
    central planner: one participant acting for every robot, with each robot's login)."""
    if robots and cfg.coordination().whole_team:
        return [robots]
    return [(r,) for r in robots]


def protocol_args(cfg: EpisodeConfig) -> list[str]:
    """`--protocol` for a child process; nothing for the paper's (its argv as it always was)."""
    return [] if cfg.protocol == DEFAULT_PROTOCOL else ["--protocol", cfg.protocol]


def agent_command(robot: str | tuple[str, ...], cfg: EpisodeConfig, spec: str | None = None) -> list[str]:
    """`mhrc agent` for `robot` (or, under a whole-team protocol, one planner for several robots:
    a --robot and a --credentials for each), driven by `spec` (its model, already resolved: no
    gguf; a planner's is its first robot's) or the heuristic policy."""
    group = (robot,) if isinstance(robot, str) else robot
    robot = group[0]
    cmd = [sys.executable, "-m", "mhrc", "agent"]
    for r in group:
        cmd += ["--robot", r]
    cmd += ["--run", cfg.run, "--connect", cfg.endpoint]
    cmd += team_args(cfg) + protocol_args(cfg)
    cmd += ["--attach-timeout", str(cfg.attach_timeout)] if cfg.attach_timeout != ATTACH_TIMEOUT else []
    if cfg.credentials is not None:
        for r in group:
            cmd += ["--credentials", str(cfg.credentials_file(r))]
    else:  # said, so that a $MHRC_CREDENTIALS of another run is not picked up
        cmd += ["--insecure"]
    if spec is not None:
        cmd += ["--llm", spec, "--ablation", cfg.ablation] + (["--base-url", cfg.base_url] if cfg.base_url else [])
        cmd += ["--prompts", str(cfg.prompts)] if cfg.prompts else []
        cmd += ["--llm-timeout", str(cfg.timeout_for(cfg.robot_specs()[robot])), "--max-tokens", str(cfg.max_tokens)]
        cmd += ["--llm-seed", str(cfg.llm_seed)] if cfg.llm_seed is not None else []
        cmd += ["--llm-idle-timeout", str(cfg.llm_idle_timeout)] if cfg.llm_idle_timeout else []
        cmd += [] if cfg.stream else ["--no-stream"]
        cmd += ["--structured"] if cfg.structured else []
        cmd += ["--step-deadline", str(cfg.step_deadline)] if cfg.step_deadline else []
        cmd += ["--history-cap", str(cfg.history_cap)] if cfg.history_cap else []
        cmd += ["--aids", ",".join(cfg.aids)] if cfg.aids else []
    elif cfg.ablation != "none":  # the episode's robots (no_mobile: without David), which a planner must all be given
        cmd += ["--ablation", cfg.ablation]
    return cmd


def wait_for_port(host: str, port: int, timeout: float, proc: subprocess.Popen[bytes] | None = None) -> None:
    """Block until something accepts TCP connections on host:port."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"the world process exited early with code {proc.returncode}")
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.2)
            if s.connect_ex((host, port)) == 0:
                return
        time.sleep(0.1)
    raise TimeoutError(f"nothing listened on {host}:{port} within {timeout:.0f} s")


async def up_processes(
    cfg: EpisodeConfig, *, observe: EventHook | None = None, robots: tuple[str, ...] | None = None, quiet: bool = False
) -> EpisodeDone:
    """The world and each agent as separate OS processes; this process only observes (and
    serves the local models that gguf specs name, for the agents to share). With `quiet` the
    children's own output (an agent's closing line) is dropped; their errors still show."""
    robots = cfg.robots if robots is None else robots
    async with local_models({r: cfg.robot_specs()[r] for r in robots}, cfg.llm_seed) as specs:
        return await _run_processes(cfg, specs, observe=observe, robots=robots, quiet=quiet)


async def _run_processes(
    cfg: EpisodeConfig,
    specs: dict[str, str | None],
    *,
    observe: EventHook | None,
    robots: tuple[str, ...],
    quiet: bool = False,
) -> EpisodeDone:
    stdout = subprocess.DEVNULL if quiet else _child_stdout()
    procs: list[subprocess.Popen[bytes]] = []
    bus = None
    try:
        check_listen(
            cfg.host, cfg.port, cfg.endpoint.split("/", 1)[0]
        )  # a port taken is one line now, not a world process failing behind a client that waits
        world = subprocess.Popen(world_command(cfg), env=_child_env(), stdout=stdout)
        procs.append(world)
        try:
            await asyncio.to_thread(wait_for_port, cfg.host, cfg.port, 60.0, world)
        except RuntimeError:  # the world ended before it listened (a trace it cannot write): it said why itself
            if world.returncode is None:
                raise
            raise ProcessFailed("the world process", world.returncode, "started") from None
        bus = await open_client(cfg.endpoint, 10.0, security=cfg.participant("observer"))
        done_fut: asyncio.Future[EpisodeDone] = asyncio.get_running_loop().create_future()
        started = asyncio.Event()

        def on_event(sample: object) -> None:
            try:
                ev = decode_event(sample.payload)  # type: ignore[attr-defined]
            except ProtocolError:
                return
            if isinstance(ev, EpisodeStarted):
                started.set()
            elif isinstance(ev, EpisodeDone) and not done_fut.done():
                done_fut.set_result(ev)

        bus.subscribe(Keys(cfg.run).world_event, on_event)
        if observe is not None:
            observe(bus, cfg.run)
        exits: dict[asyncio.Future[Any], str] = {
            asyncio.ensure_future(asyncio.to_thread(world.wait)): "the world process"
        }
        groups = participants(cfg, robots)
        for group in groups:
            agent = subprocess.Popen(agent_command(group, cfg, specs[group[0]]), env=_child_env(), stdout=stdout)
            procs.append(agent)
            exits[asyncio.ensure_future(asyncio.to_thread(agent.wait))] = _who(group, cfg)
        watched: set[asyncio.Future[Any]] = {done_fut, *exits}
        unheard = False  # the end was read from the world's trace, not heard on the bus
        while not done_fut.done():
            finished, watched = await asyncio.wait(watched, return_when=asyncio.FIRST_COMPLETED)
            for fut in finished - {done_fut}:
                code, who = fut.result(), exits[fut]
                if fut is next(iter(exits)) and not done_fut.done():
                    if code == 0:  # it ended the episode: its last event may still be on the way
                        with contextlib.suppress(TimeoutError):
                            await asyncio.wait_for(asyncio.shield(done_fut), 5.0)
                    if not done_fut.done() and code == 0 and (heard := _end_in_trace(cfg.trace)) is not None:
                        done_fut.set_result(
                            heard
                        )  # this observer lost the world (it was paused): its own record of the end
                        unheard = True
                    if not done_fut.done():
                        raise ProcessFailed(who, code, "ended")
                if (
                    code != 0 and not started.is_set() and not done_fut.done()
                ):  # as up_in_process: its robot would be waited for forever
                    raise ProcessFailed(who, code, "started")
        done = done_fut.result()
        await asyncio.to_thread(_wait_or_kill, world, 20.0)
        if (
            world.returncode != 0
        ):  # it ended the episode and then failed (its trace could not be written): said on its stderr
            raise ProcessFailed("the world process", world.returncode, None)
        for p in procs:
            await asyncio.to_thread(_wait_or_kill, p, 20.0)
        if (
            done.reason == "no_agents" and not unheard
        ):  # as up_in_process: every agent gone, with an error, is the run's failure
            # (not when this observer lost the world too: the agents gave up on a world that was paused, and its end says so)
            failed = [(g, p.returncode) for g, p in zip(groups, procs[1:]) if p.returncode != 0]
            if failed:
                raise ProcessFailed(_who(failed[0][0], cfg), failed[0][1], "ended")
        return done
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            await asyncio.to_thread(_wait_or_kill, p, 10.0)
        if bus is not None:
            await bus.close()


def _who(group: tuple[str, ...], cfg: EpisodeConfig) -> str:
    """How a line names an agent process: its robot's, or the planner's of a whole-team protocol."""
    if len(group) == 1:
        return f"{group[0]}'s agent process"
    return f"the {cfg.protocol} planner's process ({', '.join(group)})"


def _end_in_trace(trace: Path | None) -> EpisodeDone | None:
    """The world's last episode_done as its own trace recorded it, or None (no trace, no end in it)."""
    if trace is None or not trace.is_file():
        return None
    try:
        ends = messages(read_records(trace), EpisodeDone)
    except (OSError, ValueError):
        return None
    return ends[-1] if ends else None


def _wait_or_kill(proc: subprocess.Popen[bytes], timeout: float) -> None:
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
