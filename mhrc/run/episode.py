"""Running one episode: the world and the agents as asyncio tasks in one process, or as
separate OS processes, on one Zenoh bus.

The world's session is a Zenoh router listening on `tcp/HOST:PORT`; every agent (here or in
another process) connects to it as a client, so any participant's messages reach every
other one, and the recorder on the world's session sees them all.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import socket
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable, Sequence
from typing import TYPE_CHECKING, Any, Literal
from pathlib import Path

import structlog
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from mhrc.core.bus import Bus, BusError, BusRefused, check_listen, endpoint, free_port
from mhrc.core.fidelity import AidsError, label, parse_aids
from mhrc.core.keys import Keys, check_id, new_run_id
from mhrc.core.protocol import EpisodeDone, EpisodeStarted, ProtocolError, decode_event

if TYPE_CHECKING:
    from mhrc.core.security import Credentials

log = structlog.get_logger("mhrc.run.episode")

ROBOTS = ("alice", "bob", "david")
SCHEDULES = ("sequential", "lockstep", "async")  # the names of world.schedulers.SCHEDULERS (not imported: assembling code stays light)


class ConfigError(ValueError):
    """A configuration value that cannot work; the message names the field."""


class ModelServerDown(ConfigError):
    """Nothing listens where a robot's model server should be (connection refused): no step could
    ever be planned, so the run does not start."""


class ProcessFailed(RuntimeError):
    """A process of `mhrc up --processes` failed the run: the world's ended before the episode
    did, or an agent's before the episode started (the world would wait for its robot forever).
    With a positive exit code the process has said why on stderr itself; a negative one is the
    signal that killed it."""

    def __init__(self, who: str, returncode: int, before: str) -> None:
        self.who = who
        self.returncode = returncode
        how = f"was killed by signal {-returncode}" if returncode < 0 else f"exited with code {returncode}"
        super().__init__(f"{who} {how} before the episode {before}")


OPTIONS = {"n_objects": "--objects", "llm_timeout": "--llm-timeout"}
DEFAULT_MAX_TOKENS = 1024  # mirrors mhrc.agents.llm.DEFAULT_MAX_TOKENS (not imported: the world needs no agent code)
# s to the first token of a reply from a model server: about 3x the slowest first token measured on this
# machine's CPU with 3 slots (42 s: three robots' prompts of ~2,000 tokens read at once by a 270M model;
# bench/results/local_model.json); hosted APIs answer in seconds, and a server silent that long is down
SERVER_TIMEOUT = 120.0  # mirrors mhrc.agents.llm.DEFAULT_TIMEOUT
IDLE_TIMEOUT = 30.0  # s between chunks of a streamed reply; mirrors mhrc.agents.llm.DEFAULT_IDLE_TIMEOUT
# s to the first token from an in-process gguf: model: a local model is the CPU's, often larger than 270M (a 10x
# larger model reads the prompt about 10x slower); with --no-stream, to the whole reply; max_tokens bounds a reply
LOCAL_TIMEOUT = 600.0


def option_name(field: str) -> str:
    """The command-line option a config field comes from (n_objects -> --objects)."""
    return OPTIONS.get(field, "--" + field.replace("_", "-"))


class EpisodeConfig(BaseModel):
    """What one episode runs: validated before anything starts."""

    model_config = ConfigDict(extra="forbid")

    task: str = "pack_objects"
    scene: str = "kitchen"
    seed: int = Field(0, ge=0)
    n_objects: int = Field(4, ge=3, le=6)
    horizon: int = Field(50, ge=1, le=1000)
    run: str = Field(default_factory=new_run_id)
    host: str = "127.0.0.1"
    port: int = Field(0, ge=0, le=65535, description="0: pick a free port")
    trace: Path | None = None
    gui: bool = False
    start_timeout: float | None = Field(None, gt=0)
    tick_delay: float = Field(0.0, ge=0)
    schedule: Literal["sequential", "lockstep", "async"] = Field("lockstep", description="the world's time policy (DESIGN.md, \"Time\")")
    time_scale: float = Field(0.0, ge=0, allow_inf_nan=False, description="async: simulated seconds per wall second; 0: as fast as possible")
    llm: str | None = Field(None, description="model spec (provider:model); None: the heuristic policy")
    ablation: Literal["none", "no_feedback", "no_history", "no_mobile"] = "none"
    prompts: Path | None = Field(None, description="directory of the user's own prompt templates")
    base_url: str | None = None
    llm_timeout: float | None = Field(None, gt=0, description="seconds to an LLM reply's first token, prompt processing included (the whole reply "
                                      "when it is not streamed); a timeout is retried once; None: 120, 600 for gguf: models")
    llm_idle_timeout: float | None = Field(None, gt=0, description="seconds a streamed LLM reply may go without a chunk; None: 30")
    stream: bool = Field(True, description="stream LLM replies (False: --no-stream, for servers that cannot)")
    max_tokens: int = Field(DEFAULT_MAX_TOKENS, ge=1, description="completion tokens per LLM call, sent on every request")
    llm_seed: int | None = Field(None, ge=0, description="sampling seed sent on every LLM request (servers that honour one)")
    structured: bool = Field(False, description="LLM replies follow a JSON Schema of the step's valid actions (not the paper's)")
    step_deadline: float | None = Field(None, gt=0, description="seconds one robot's LLM step may take, retries included, at least --llm-timeout; "
                                        "None: no bound but the call's own (a stalled stream ends after --llm-idle-timeout, one that "
                                        "keeps producing at --max-tokens)")
    aids: tuple[str, ...] = Field((), description="aids that make the episode easier than the paper's (mhrc.core.fidelity); none: the paper's")
    history_cap: int | None = Field(None, gt=0, description="characters the LLM prompt may take (histories shortened to fit); None: whole histories, as the paper")
    credentials: Path | None = Field(
        None,
        description="the run's credentials (mhrc.core.security): the directory of every participant's files, or one participant's "
        "file; the bus is then TLS with a login per participant and the world's access control; None: the open tcp bus",
    )

    @field_validator("aids", mode="before")
    @classmethod
    def _aids(cls, v: object) -> tuple[str, ...]:
        try:
            return parse_aids(v)  # type: ignore[arg-type]
        except AidsError as exc:
            raise ValueError(str(exc)) from None

    @field_validator("run")
    @classmethod
    def _run_id(cls, v: str) -> str:
        check_id(v, "run id")
        return v

    @classmethod
    def build(cls, **values: object) -> EpisodeConfig:
        """Validate, raising ConfigError that names the offending field."""
        try:
            cfg = cls(**values)
        except ValidationError as exc:
            err = exc.errors()[0]
            field = ".".join(str(p) for p in err["loc"]) or "config"
            msg = err["msg"].removeprefix("Value error, ")
            if msg.startswith("--"):  # the validator already names the option
                raise ConfigError(msg) from None
            raise ConfigError(f"{option_name(field)}: {msg} (got {err.get('input')!r})") from None
        if cfg.trace is not None:
            from mhrc.core.trace import unwritable

            if why := unwritable(cfg.trace):  # before anything starts: not a traceback from the recorder
                raise ConfigError(f"--trace: {why}")
        if cfg.time_scale and cfg.schedule != "async":
            raise ConfigError(f"--time-scale: only the async schedule has a clock against wall time (got --schedule {cfg.schedule})")
        from mhrc.world.sim import check_episode  # validates task and scene names without building

        try:
            check_episode(task=cfg.task, scene=cfg.scene, n_objects=cfg.n_objects)
            if cfg.llm is not None:
                from mhrc.agents.llm import check_spec
                from mhrc.agents.llm_policy import load_template

                for robot, spec in cfg.robot_specs().items():
                    if spec is None:
                        continue
                    check_spec(spec, cfg.base_url)
                    if cfg.step_deadline is not None and cfg.step_deadline < cfg.timeout_for(spec):
                        raise ConfigError(
                            f"--step-deadline: {cfg.step_deadline:g} s is shorter than the first-token timeout of {robot}'s model "
                            f"({cfg.timeout_for(spec):g} s, --llm-timeout): the step would end before a slow server could answer; "
                            "give a longer --step-deadline or a shorter --llm-timeout"
                        )
                    for part in ("system", "user"):
                        load_template(robot, part, cfg.prompts)
        except (ValueError, FileNotFoundError) as exc:
            raise ConfigError(str(exc)) from None
        return cfg

    def resolved(self) -> EpisodeConfig:
        """A copy with a concrete port and trace path."""
        port = self.port or free_port(self.host)
        trace = self.trace or Path("runs") / self.run / "trace.jsonl"
        return self.model_copy(update={"port": port, "trace": trace})

    @property
    def endpoint(self) -> str:
        return endpoint(self.host, self.port, tls=self.credentials is not None)

    def credentials_file(self, user: str) -> Path:
        """The credentials file of `user` (the world, a robot, the observer)."""
        if self.credentials is None:
            raise ConfigError("this episode has no credentials (the open bus)")
        return self.credentials / f"{user}.json" if self.credentials.is_dir() else self.credentials

    def participant(self, user: str) -> Credentials | None:
        """`user`'s credentials, checked to be of this run and this user; None on the open bus."""
        if self.credentials is None:
            return None
        from mhrc.core.security import check_for, load

        creds = load(self.credentials_file(user))
        check_for(creds, run=self.run, user=user)
        return creds

    def with_credentials(self, directory: Path | None = None) -> EpisodeConfig:
        """A copy with fresh credentials for this run (default: next to the trace, runs/RUN/credentials)."""
        from mhrc.core.security import make_run_credentials

        where = directory or ((self.trace.parent if self.trace else Path("runs") / self.run) / "credentials")
        make_run_credentials(self.run, ROBOTS, where)
        return self.model_copy(update={"credentials": where})

    @property
    def robots(self) -> tuple[str, ...]:
        """The robots in this episode (no_mobile leaves David out)."""
        return tuple(r for r in ROBOTS if not (r == "david" and self.ablation == "no_mobile"))

    def robot_specs(self) -> dict[str, str | None]:
        """Each robot's model spec (None: the heuristic policy); see mhrc.agents.llm.robot_specs."""
        if self.llm is None:
            return dict.fromkeys(self.robots)
        from mhrc.agents.llm import robot_specs

        return robot_specs(self.llm, self.robots)

    def timeout_for(self, spec: str | None) -> float:
        """Seconds per LLM request for a robot driven by `spec` (its own spec, before gguf: is served)."""
        if self.llm_timeout is not None:
            return self.llm_timeout
        return LOCAL_TIMEOUT if spec is not None and spec.startswith("gguf:") else SERVER_TIMEOUT

    def policy_options(self, spec: str | None = None) -> dict[str, Any]:
        """LLMPolicy switches for the ablation (the heuristic policy ignores them), for a robot
        driven by `spec`."""
        return {
            "feedback": self.ablation != "no_feedback",
            "history": self.ablation != "no_history",
            "teammates_absent": tuple(r for r in ROBOTS if r not in self.robots),
            "prompts_dir": self.prompts,
            "prompt_cap_chars": self.history_cap,
            "reach_labels": "reach_labels" in self.aids,
            "prompt_hints": "prompt_hints" in self.aids,
            "structured": self.structured,
            "step_deadline": self.step_deadline,
            "max_tokens": self.max_tokens,
        }

    def client_options(self, spec: str | None = None) -> dict[str, Any]:
        """OpenAIChatClient settings of a robot driven by `spec`."""
        return {
            "timeout": self.timeout_for(spec), "idle_timeout": self.llm_idle_timeout or IDLE_TIMEOUT, "stream": self.stream,
            "max_tokens": self.max_tokens, "seed": self.llm_seed,
        }  # fmt: skip

    @property
    def fidelity(self) -> str:
        return label(self.aids)


EventHook = Callable[[Bus, str], None]  # (bus, run) -> subscribes an observer


async def serve_world(
    cfg: EpisodeConfig,
    *,
    observe: EventHook | None = None,
    connect: str | None = None,
    login: Credentials | None = None,
    on_service: Callable[[Any], None] | None = None,
) -> EpisodeDone:
    """Build the scene, open the world's bus (a router on cfg.endpoint, or with `connect` a
    client of a router that already exists, logged in with `login` if given: an evaluation
    worker's), record, and run the episode. `on_service` gets the WorldService once it exists
    (the in-process runner stops it when an agent fails for good)."""
    from mhrc.world.service import WorldConfig, WorldService
    from mhrc.world.sim import Sim

    from mhrc.core.trace import Recorder

    sim = await asyncio.to_thread(
        Sim, task=cfg.task, scene=cfg.scene, seed=cfg.seed, n_objects=cfg.n_objects, gui=cfg.gui, robots=cfg.robots, aids=cfg.aids
    )
    bus = None
    recorder = None
    world: WorldService | None = None
    try:
        security = login if connect and login is not None else cfg.participant("world")
        bus = await (
            open_client(connect, 30.0, security=security) if connect else Bus.open(mode="router", listen=[cfg.endpoint], security=security)
        )
        if cfg.trace is not None:
            recorder = Recorder(bus, cfg.run, cfg.trace).start()
        if observe is not None:
            observe(bus, cfg.run)
        world = WorldService(
            bus,
            sim,
            WorldConfig(
                run=cfg.run, horizon=cfg.horizon, start_timeout=cfg.start_timeout, tick_delay=cfg.tick_delay, schedule=cfg.schedule,
                time_scale=cfg.time_scale,
            ),  # fmt: skip
        )
        if on_service is not None:
            on_service(world)
        try:
            return await world.run()
        except asyncio.CancelledError:
            world.stop()
            raise
        finally:
            await asyncio.sleep(0.2)  # let the last results and the done event leave
    finally:
        if recorder is not None:
            recorder.close(until_done=2.0 if world is not None and world.done is not None else 0.0)
        if bus is not None:
            await bus.close()
        await asyncio.to_thread(sim.close)


async def open_client(connect: str, timeout: float, *, security: Credentials | None = None) -> Bus:
    """A client session to `connect` (logged in with `security`), retrying while the world is
    still starting up; a world that refuses the session (BusRefused) is not retried."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    refused_at = None
    while True:
        try:
            return await Bus.open(mode="client", connect=[connect], security=security)
        except BusRefused as exc:
            refused_at = loop.time() if refused_at is None else refused_at
            if exc.final or loop.time() - refused_at > 3.0 or loop.time() >= deadline:
                raise
            await asyncio.sleep(0.2)
        except BusError:
            if loop.time() >= deadline:
                raise
            await asyncio.sleep(0.2)


async def run_agent(
    robot: str,
    run: str,
    connect: str,
    *,
    llm: str | None = None,
    base_url: str | None = None,
    client_options: dict[str, Any] | None = None,
    attach_timeout: float = 30.0,
    security: Credentials | None = None,
    on_error: Callable[[BaseException], None] | None = None,
    **policy_options: Any,
) -> EpisodeDone | None:
    """Attach an agent for `robot` to the world at `connect` and play until the episode ends:
    the heuristic policy, or with `llm` (one robot's spec) an LLMPolicy on that model. A
    `gguf:PATH` spec gets a one-slot local server of its own for as long as the agent runs.
    `on_error` hears an error that ends the agent while its session is still open: before the
    world sees the robot vanish."""
    from mhrc.agents.agent import RobotAgent
    from mhrc.agents.heuristic import heuristic_policy

    if security is not None:
        from mhrc.core.security import check_for

        check_for(security, run=run, user=robot)
    async with contextlib.AsyncExitStack() as stack:
        if llm is None:
            policy = heuristic_policy(robot)
        else:
            from mhrc.agents.llm import make_client
            from mhrc.agents.llm_policy import LLMPolicy
            from mhrc.agents.replay import ReplayClient

            if llm.startswith("replay:"):
                policy = LLMPolicy(robot, ReplayClient(llm.removeprefix("replay:"), robot), **policy_options)  # type: ignore[assignment]
            else:
                if llm.startswith("gguf:"):
                    llm = (await stack.enter_async_context(local_models({robot: llm}, (client_options or {}).get("seed"))))[robot]
                client = make_client(llm, base_url=base_url, **(client_options or {}))
                stack.push_async_callback(client.aclose)
                policy = LLMPolicy(robot, client, **policy_options)  # type: ignore[assignment]
        bus = await open_client(connect, attach_timeout, security=security)
        try:
            agent = RobotAgent(bus, policy, run=run, robot=robot, attach_timeout=attach_timeout, endpoint=connect,  # type: ignore[arg-type]
                               security=security)
            return await agent.run()
        except Exception as exc:
            if on_error is not None:
                on_error(exc)
            raise
        finally:
            await bus.close()


@contextlib.asynccontextmanager
async def local_models(specs: dict[str, str | None], seed: int | None = None) -> AsyncIterator[dict[str, str | None]]:
    """Serve every `gguf:PATH` spec in-process (mhrc.agents.local): one llama.cpp server per
    model file with one slot per robot on it, so the robots decode in parallel; yields the specs
    with each gguf one replaced by `llamacpp:MODEL@URL` of its server. The servers stop on exit."""
    paths = sorted({s.removeprefix("gguf:") for s in specs.values() if s and s.startswith("gguf:")})
    if not paths:
        yield specs
        return
    from mhrc.agents.local import LocalModelServer

    async with contextlib.AsyncExitStack() as stack:
        served: dict[str, str] = {}
        for path in paths:
            slots = sum(1 for s in specs.values() if s == f"gguf:{path}")
            server = await stack.enter_async_context(LocalModelServer(path, slots=slots, seed=seed))
            served[path] = f"llamacpp:{server.model}@{server.base_url}"
            log.info("local model serving", path=path, slots=slots, url=server.base_url)
        yield {r: served[s.removeprefix("gguf:")] if s and s.startswith("gguf:") else s for r, s in specs.items()}


async def find_run(bus: Bus, timeout: float = 5.0) -> str:
    """The run id of the only world alive on this bus (raises if there is none or several).

    Asks again for a while: a freshly connected session may not see the tokens at once."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        runs = sorted({key.split("/")[1] for key in await bus.alive("mhrc/*/alive/world", timeout=1.0)})
        if runs or loop.time() >= deadline:
            break
        await asyncio.sleep(0.3)
    if len(runs) != 1:
        found = ", ".join(runs) if runs else "none"
        raise ConfigError(f"pass --run: expected exactly one world on the bus, found {found}")
    return runs[0]


async def attach_agent(
    robot: str,
    connect: str,
    run: str | None,
    attach_timeout: float = 30.0,
    llm: str | None = None,
    base_url: str | None = None,
    client_options: dict[str, Any] | None = None,
    security: Credentials | None = None,
    **policy_options: Any,
) -> EpisodeDone | None:
    """`mhrc agent`: find the run if not given (the credentials' run, or the only world alive),
    then play `robot` (heuristic policy, or `llm`)."""
    if run is None and security is not None:
        run = security.run
    if run is None:
        bus = await open_client(connect, attach_timeout)
        try:
            run = await find_run(bus)
        finally:
            await bus.close()
    return await run_agent(
        robot, run, connect, llm=llm, base_url=base_url, client_options=client_options, attach_timeout=attach_timeout, security=security,
        **policy_options,
    )  # fmt: skip


async def up_in_process(
    cfg: EpisodeConfig,
    *,
    observe: EventHook | None = None,
    robots: tuple[str, ...] | None = None,
    connect: str | None = None,
    login: Credentials | None = None,
) -> EpisodeDone:
    """World and the given robots' agents (default: the episode's) as asyncio tasks of this
    process; with `connect`, all of them join that router's bus instead of the world listening,
    each logged in with `login` when given (an evaluation worker's credentials)."""
    robots = cfg.robots if robots is None else robots
    async with local_models({r: cfg.robot_specs()[r] for r in robots}, cfg.llm_seed) as specs:
        return await _run_in_process(cfg, specs, observe=observe, robots=robots, connect=connect, login=login)


async def _run_in_process(
    cfg: EpisodeConfig,
    specs: dict[str, str | None],
    *,
    observe: EventHook | None,
    robots: tuple[str, ...],
    connect: str | None,
    login: Credentials | None = None,
) -> EpisodeDone:
    login = login if connect else None
    listening = asyncio.Event()
    started = asyncio.Event()  # the world started the episode: a robot whose agent fails now is only detached
    services: list[Any] = []  # the WorldService, once built
    failures: list[BaseException] = []  # an agent's error that ends the run: a model that cannot answer at all

    def on_open(bus: Bus, run: str) -> None:
        if observe is not None:
            observe(bus, run)

        def on_event(sample: Any) -> None:
            with contextlib.suppress(ProtocolError):
                if isinstance(decode_event(sample.payload), EpisodeStarted):
                    started.set()

        bus.subscribe(Keys(run).world_event, on_event)
        listening.set()

    def on_agent_error(exc: BaseException) -> None:
        """Heard while the failing agent's session is still open: stop the world first, so that
        its robot is not reported as vanished and no episode is scored for a run that failed."""
        if _is_fatal(exc):
            failures.append(exc)
            for service in services:
                service.stop()

    world = asyncio.create_task(serve_world(cfg, observe=on_open, connect=connect, login=login, on_service=services.append), name="world")
    ready = asyncio.create_task(listening.wait())
    await asyncio.wait({world, ready}, return_when=asyncio.FIRST_COMPLETED)
    if world.done():  # the world could not start (its port is taken, ...): say so now, no agent is left connecting
        ready.cancel()
        return world.result()
    own = cfg.robot_specs()  # before gguf: specs became their local servers' URLs
    agents = [
        asyncio.create_task(
            run_agent(
                r, cfg.run, connect or cfg.endpoint, llm=specs[r], base_url=cfg.base_url, client_options=cfg.client_options(own[r]),
                security=login or cfg.participant(r), on_error=on_agent_error, **cfg.policy_options(own[r]),
            ),
            name=f"agent-{r}",
        )
        for r in robots
    ]  # fmt: skip
    try:
        pending = {world, *agents}
        while world in pending:
            finished, pending = await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
            if failures:  # a model that cannot answer at all: stop now, not at the horizon
                raise failures[0]
            early = [t.exception() for t in agents if t in finished and t.exception() is not None]
            if early and not started.is_set():  # an agent gave up before the start (e.g. its attach timed out):
                raise early[0]  # type: ignore[misc]  # the world would wait for its robot forever
            if world not in finished and not any(t in pending for t in agents):
                errors = [t.exception() for t in agents if t.exception() is not None]
                if errors:  # every agent is gone and nobody else will attach: stop the world
                    raise errors[0]  # type: ignore[misc]
        done = world.result()
    finally:
        for t in agents:
            if not t.done():
                t.cancel()
        results = await asyncio.gather(*agents, return_exceptions=True)
        for r, res in zip(robots, results):
            if isinstance(res, BaseException) and not isinstance(res, asyncio.CancelledError) and not (failures and _is_fatal(res)):
                log.warning("agent ended with an error", robot=r, error=str(res))  # (the run's own failure is raised, not logged)
        if not world.done():
            world.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await world
    return done


def check_model_servers(cfg: EpisodeConfig, robots: Sequence[str]) -> None:
    """ModelServerDown when nothing listens (connection refused) at the server a robot's model
    spec names: said at once, in one line, instead of every robot retrying into the void. A
    server that does not answer the connection (a slow network, a name that does not resolve)
    is left to the agents' own retries."""
    from urllib.parse import urlsplit

    from mhrc.agents.llm import check_spec, split_url

    servers: dict[str, tuple[str, list[str]]] = {}  # url -> (where it came from, its robots)
    specs = cfg.robot_specs()
    for robot in robots:
        spec = specs.get(robot)
        if spec is None or spec.startswith(("gguf:", "replay:")):
            continue
        bare, own = split_url(spec)
        url = check_spec(spec, cfg.base_url)[1]
        if own:
            advice = f"start the server there, or fix the @URL in --llm {spec!r}"
        elif cfg.base_url:
            advice = "start the server there, or point --base-url at one"
        else:
            advice = f"start {bare.partition(':')[0]} there, or pass --base-url for a server elsewhere"
        servers.setdefault(url, (advice, []))[1].append(robot)
    for url, (advice, users) in servers.items():
        parts = urlsplit(url)
        try:
            port = parts.port or (443 if parts.scheme == "https" else 80)
            with socket.create_connection((parts.hostname or "", port), timeout=2.0):
                pass
        except ConnectionRefusedError:
            raise ModelServerDown(
                f"nothing listens at {url}, the model server of {', '.join(users)} (connection refused): {advice}"
            ) from None
        except (OSError, ValueError):
            continue


def _is_fatal(exc: BaseException | None) -> bool:
    from mhrc.agents.llm import LLMFatalError

    return isinstance(exc, LLMFatalError)


def _child_env() -> dict[str, str]:
    from mhrc.run.lifeline import child_env

    env = child_env()  # the world and agents die with this process, even after a SIGKILL
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def _child_stdout() -> int | None:
    """Children print to this process's stderr: stdout is for `--json` output alone."""
    try:
        return sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        return None


def world_command(cfg: EpisodeConfig) -> list[str]:
    cmd = [
        sys.executable, "-m", "mhrc", "world",
        "--task", cfg.task, "--scene", cfg.scene, "--seed", str(cfg.seed), "--objects", str(cfg.n_objects),
        "--horizon", str(cfg.horizon), "--run", cfg.run, "--host", cfg.host, "--port", str(cfg.port), "--quiet",
        "--ablation", cfg.ablation, "--schedule", cfg.schedule,
    ]  # fmt: skip
    if cfg.trace is not None:
        cmd += ["--trace", str(cfg.trace)]
    if cfg.aids:
        cmd += ["--aids", ",".join(cfg.aids)]
    if cfg.tick_delay:
        cmd += ["--tick-delay", str(cfg.tick_delay)]
    if cfg.start_timeout is not None:
        cmd += ["--start-timeout", str(cfg.start_timeout)]
    if cfg.time_scale:
        cmd += ["--time-scale", str(cfg.time_scale)]
    if cfg.credentials is not None:
        cmd += ["--credentials", str(cfg.credentials_file("world"))]
    else:  # said, so that a $MHRC_CREDENTIALS of another run is not picked up
        cmd += ["--insecure"]
    return cmd


def agent_command(robot: str, cfg: EpisodeConfig, spec: str | None = None) -> list[str]:
    """`mhrc agent` for `robot`, driven by `spec` (its model, already resolved: no gguf) or the heuristic policy."""
    cmd = [sys.executable, "-m", "mhrc", "agent", "--robot", robot, "--run", cfg.run, "--connect", cfg.endpoint]
    if cfg.credentials is not None:
        cmd += ["--credentials", str(cfg.credentials_file(robot))]
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
    cfg: EpisodeConfig, specs: dict[str, str | None], *, observe: EventHook | None, robots: tuple[str, ...], quiet: bool = False
) -> EpisodeDone:
    stdout = subprocess.DEVNULL if quiet else _child_stdout()
    procs: list[subprocess.Popen[bytes]] = []
    bus = None
    try:
        check_listen(cfg.host, cfg.port, cfg.endpoint.split("/", 1)[0])  # a port taken is one line now, not a world process failing behind a client that waits
        world = subprocess.Popen(world_command(cfg), env=_child_env(), stdout=stdout)
        procs.append(world)
        await asyncio.to_thread(wait_for_port, cfg.host, cfg.port, 60.0, world)
        bus = await open_client(cfg.endpoint, 10.0, security=cfg.participant("observer"))
        done_fut: asyncio.Future[EpisodeDone] = asyncio.get_running_loop().create_future()
        started = asyncio.Event()
        from mhrc.core.keys import Keys

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
        exits: dict[asyncio.Future[Any], str] = {asyncio.ensure_future(asyncio.to_thread(world.wait)): "the world process"}
        for r in robots:
            agent = subprocess.Popen(agent_command(r, cfg, specs[r]), env=_child_env(), stdout=stdout)
            procs.append(agent)
            exits[asyncio.ensure_future(asyncio.to_thread(agent.wait))] = f"{r}'s agent process"
        watched: set[asyncio.Future[Any]] = {done_fut, *exits}
        while not done_fut.done():
            finished, watched = await asyncio.wait(watched, return_when=asyncio.FIRST_COMPLETED)
            for fut in finished - {done_fut}:
                code, who = fut.result(), exits[fut]
                if fut is next(iter(exits)) and not done_fut.done():
                    if code == 0:  # it ended the episode: its last event may still be on the way
                        with contextlib.suppress(TimeoutError):
                            await asyncio.wait_for(asyncio.shield(done_fut), 5.0)
                    if not done_fut.done():
                        raise ProcessFailed(who, code, "ended")
                if code != 0 and not started.is_set() and not done_fut.done():  # as up_in_process: its robot would be waited for forever
                    raise ProcessFailed(who, code, "started")
        done = done_fut.result()
        for p in procs:
            await asyncio.to_thread(_wait_or_kill, p, 20.0)
        if done.reason == "no_agents":  # as up_in_process: every agent gone, with an error, is the run's failure
            failed = [(r, p.returncode) for r, p in zip(robots, procs[1:]) if p.returncode != 0]
            if failed:
                raise ProcessFailed(f"{failed[0][0]}'s agent process", failed[0][1], "ended")
        return done
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            await asyncio.to_thread(_wait_or_kill, p, 10.0)
        if bus is not None:
            await bus.close()


def _wait_or_kill(proc: subprocess.Popen[bytes], timeout: float) -> None:
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
