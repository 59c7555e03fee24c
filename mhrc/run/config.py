"""One episode's configuration (`EpisodeConfig`), checked before anything starts: a bad
value raises `ConfigError` naming its option."""

from __future__ import annotations

import socket
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from mhrc.agents.llm import (
    DEFAULT_IDLE_TIMEOUT,
    DEFAULT_MAX_TOKENS,
    DEFAULT_TIMEOUT,
    check_spec,
    robot_specs,
    split_url,
)
from mhrc.core.aids import (  # not via mhrc.core.fidelity, which builds the wire's models
    AidsError,
    NoiseError,
    NoiseSetting,
    label,
    parse_aids,
    parse_noise,
)
from mhrc.core.coordination import DEFAULT_PROTOCOL
from mhrc.core.deadlines import ATTACH_TIMEOUT, TOKEN_DEADLINE
from mhrc.core.endpoints import endpoint, free_port
from mhrc.core.keys import check_id, new_run_id
from mhrc.core.logs import get_logger
from mhrc.core.team import PAPER_TEAM, TeamSpec
from mhrc.core.writable import unwritable
from mhrc.run.errors import (
    ConfigError as ConfigError,  # defined apart: the CLI catches it without this module's imports
)
from mhrc.run.errors import ModelServerDown as ModelServerDown
from mhrc.world.scenario import Scenario, check_scenario, load_scenario
from mhrc.world.schedules import SCHEDULES as SCHEDULES  # the schedulers by name, without importing them

if TYPE_CHECKING:
    from mhrc.agents.llm.openai_client import ClientOptions
    from mhrc.agents.llm_policy import PolicyOptions
    from mhrc.agents.protocols import CoordinationProtocol, Refusal
    from mhrc.core.security import Credentials
    from mhrc.world.sim import Sim

log = get_logger("mhrc.run.config")


ROBOTS = PAPER_TEAM.names  # the paper's team, the default (--team chooses another)


class ProtocolConfigError(ConfigError):
    """--protocol names no protocol, or one that cannot run this episode: `code` says which."""

    def __init__(self, message: str, code: Refusal) -> None:
        super().__init__(message)
        self.code = code


OPTIONS = {"n_objects": "--objects", "llm_timeout": "--llm-timeout"}
# s to the first token of a reply from a model server: about 3x the slowest first token measured on this
# machine's CPU with 3 slots (42 s: three robots' prompts of ~2,000 tokens read at once by a 270M model;
# bench/results/local_model.json); hosted APIs answer in seconds, and a server silent that long is down
SERVER_TIMEOUT = DEFAULT_TIMEOUT
IDLE_TIMEOUT = DEFAULT_IDLE_TIMEOUT  # s between chunks of a streamed reply
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
    attach_timeout: float = Field(
        ATTACH_TIMEOUT,
        gt=0,
        allow_inf_nan=False,
        description="seconds an agent waits for the world to answer its attach: at the start, and when the world falls silent",
    )
    tick_delay: float = Field(0.0, ge=0)
    schedule: Literal["sequential", "lockstep", "async"] = Field(
        "lockstep", description='the world\'s time policy (docs/architecture.md, "Time")'
    )
    time_scale: float = Field(
        0.0, ge=0, allow_inf_nan=False, description="async: simulated seconds per wall second; 0: as fast as possible"
    )
    token_deadline: float = Field(
        TOKEN_DEADLINE,
        gt=0,
        allow_inf_nan=False,
        description="seconds an attached agent has to show its liveliness "
        "token before the world detaches it (world/presence.py)",
    )
    llm: str | None = Field(None, description="model spec (provider:model); None: the heuristic policy")
    ablation: Literal["none", "no_feedback", "no_history", "no_mobile"] = "none"
    team: TeamSpec = Field(
        default_factory=lambda: PAPER_TEAM,
        description="the robots, their kinds and order (mhrc.core.team; --team); the paper's Alice, Bob and David by default",
    )
    prompts: Path | None = Field(None, description="directory of the user's own prompt templates")
    base_url: str | None = None
    llm_timeout: float | None = Field(
        None,
        gt=0,
        description="seconds to an LLM reply's first token, prompt processing included (the whole reply "
        "when it is not streamed); a timeout is retried once; None: 120, 600 for gguf: models",
    )
    llm_idle_timeout: float | None = Field(
        None, gt=0, description="seconds a streamed LLM reply may go without a chunk; None: 30"
    )
    stream: bool = Field(True, description="stream LLM replies (False: --no-stream, for servers that cannot)")
    max_tokens: int = Field(
        DEFAULT_MAX_TOKENS, ge=1, description="completion tokens per LLM call, sent on every request"
    )
    llm_seed: int | None = Field(
        None, ge=0, description="sampling seed sent on every LLM request (servers that honour one)"
    )
    structured: bool = Field(
        False, description="LLM replies follow a JSON Schema of the step's valid actions (not the paper's)"
    )
    step_deadline: float | None = Field(
        None,
        gt=0,
        description="seconds one robot's LLM step may take, retries included, at least --llm-timeout; "
        "None: no bound but the call's own (a stalled stream ends after --llm-idle-timeout, one that "
        "keeps producing at --max-tokens)",
    )
    aids: tuple[str, ...] = Field(
        (), description="aids that make the episode easier than the paper's (mhrc.core.fidelity); none: the paper's"
    )
    noise: NoiseSetting = Field(
        "on",
        description="the world's motion noise: on, the calibration (mhrc.core.fidelity), or off (none; recorded as a setting of its own)",
    )
    history_cap: int | None = Field(
        None,
        gt=0,
        description="characters the LLM prompt may take (histories shortened to fit); None: whole histories, as the paper",
    )
    events: Path | None = Field(
        None, description="a scenario file: events the world applies during the episode (world/scenario.py)"
    )
    protocol: str = Field(
        DEFAULT_PROTOCOL,
        description="how the team decides: a coordination protocol (mhrc.agents.protocols; docs/protocols.md); "
        "the paper's, mhrc, by default",
    )
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

    @field_validator("noise", mode="before")
    @classmethod
    def _noise(cls, v: object) -> NoiseSetting:
        try:
            return parse_noise(v if v is None else str(v))
        except NoiseError as exc:
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
            if why := unwritable(cfg.trace):  # before anything starts: not a traceback from the recorder
                raise ConfigError(f"--trace: {why}")
        if cfg.time_scale and cfg.schedule != "async":
            raise ConfigError(
                f"--time-scale: only the async schedule has a clock against wall time (got --schedule {cfg.schedule})"
            )
        from mhrc.world.teams import check_team

        try:
            check_team(cfg.team)  # its kinds, a finisher, a fetcher: before the imports below
            from mhrc.world.checks import check_episode  # task and scene names, without building: the registries
            from mhrc.world.layouts import get_layout
            from mhrc.world.placement import check_placement  # numpy

            check_episode(task=cfg.task, scene=cfg.scene, n_objects=cfg.n_objects)
            layout = get_layout(cfg.scene)  # a .json scene is read and validated once
            check_team(cfg.team, layout)  # and the layout's arm mounts
            check_placement(layout, cfg.team, cfg.seed)  # room for every robot, before anything starts
            cfg.scenario()
            if any(cfg.robot_specs().values()):
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
                        load_template(robot, part, cfg.prompts, team=cfg.team)
        except (ValueError, FileNotFoundError) as exc:
            raise ConfigError(str(exc)) from None
        cfg.coordination()  # ProtocolConfigError, with its refusal's code
        return cfg

    def coordination(self) -> CoordinationProtocol:
        """The episode's protocol; ConfigError (--protocol) for an unknown one or one that cannot
        run this team (its refusal's code is the error's `code`)."""
        from mhrc.agents.protocols import ProtocolRefused, protocol  # the registry: the wire's models with it

        try:
            p = protocol(self.protocol)
            refused = p.refusal(self.team, llm=any(self.robot_specs().values()))
        except ProtocolRefused as exc:
            refused = exc
        if refused is not None:
            raise ProtocolConfigError(f"--protocol: {refused}", refused.code)
        return p

    def check_replays(self, robots: Sequence[str]) -> None:
        """Each replay: spec's trace read as the robot's agent will read it (its records, the robot's
        prompts, the templates they were rendered from): ConfigError before anything is written,
        instead of each agent failing on it once the run has started."""
        for robot in robots:
            spec = self.robot_specs().get(robot)
            if spec is None or not spec.startswith("replay:"):
                continue
            from mhrc.agents.llm_policy import LLMPolicy  # here: a run without a replay needs neither
            from mhrc.agents.replay import ReplayClient, ReplayMismatch

            try:
                LLMPolicy(robot, ReplayClient(spec.removeprefix("replay:"), robot), **self.policy_options(spec))
            except (ValueError, OSError, ReplayMismatch) as exc:
                raise ConfigError(f"--llm: {robot}'s replay: {exc}") from None

    def scenario(self) -> Scenario | None:
        """The --events file, read and checked against this episode (ScenarioError naming the event
        and field); None without one."""
        if self.events is None:
            return None
        from mhrc.world.dynamics import episode_facts  # reads the task and layout, builds nothing

        scenario = load_scenario(self.events)
        check_scenario(
            scenario, episode_facts(task=self.task, scene=self.scene, horizon=self.horizon, robots=self.robots)
        )
        return scenario

    def sim(self, seed: int | None = None, *, visuals: bool = False) -> Sim:
        """The world this configuration describes, built (with `seed`, another seed than its own):
        the world's side of `mhrc up` (mhrc.run.serve) and the environment (mhrc.env) build it here,
        so both build the same one. `visuals`: for a world a camera renders (Sim's `visuals`: the
        environment's frames; the world service's is never drawn, and the GUI always has them)."""
        from mhrc.world.sim import Sim  # here, not at the top: the CLI reads configurations without PyBullet

        return Sim(
            task=self.task,
            scene=self.scene,
            seed=self.seed if seed is None else seed,
            n_objects=self.n_objects,
            gui=self.gui,
            team=self.team,
            robots=self.robots,
            aids=self.aids,
            scenario=self.scenario(),
            noise=self.noise,
            visuals=visuals,
        )

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
        from mhrc.core.security import check_for, load  # here: the open bus needs neither

        creds = load(self.credentials_file(user))
        check_for(creds, run=self.run, user=user)
        return creds

    def with_credentials(self, directory: Path | None = None) -> EpisodeConfig:
        """A copy with fresh credentials for this run (default: next to the trace, runs/RUN/credentials;
        also runs/RUN/credentials for a trace that is a device, such as /dev/null or /dev/full: never into /dev)."""
        trace = self.trace if self.trace is not None and (self.trace.is_file() or not self.trace.exists()) else None
        where = directory or ((trace.parent if trace is not None else Path("runs") / self.run) / "credentials")
        from mhrc.core.security import make_run_credentials

        make_run_credentials(self.run, self.team.names, where)
        return self.model_copy(update={"credentials": where})

    @property
    def robots(self) -> tuple[str, ...]:
        """The robots in this episode, in execution order: the team's (no_mobile leaves out the
        robots that only navigate, the paper's David)."""
        if self.ablation != "no_mobile":
            return self.team.names
        from mhrc.world.teams import scouts

        left_out = scouts(self.team)
        return tuple(r for r in self.team.names if r not in left_out)

    def robot_specs(self) -> dict[str, str | None]:
        """Each robot's model spec (None: the heuristic policy): `--llm` for every robot it
        covers (mhrc.agents.llm.robot_specs), the team file's `llm` for a robot it leaves out."""
        chosen = dict.fromkeys(self.robots) if self.llm is None else robot_specs(self.llm, self.robots)
        own = {r.name: r.llm for r in self.team.robots}
        return {r: spec if spec is not None else own.get(r) for r, spec in chosen.items()}

    def timeout_for(self, spec: str | None) -> float:
        """Seconds per LLM request for a robot driven by `spec` (its own spec, before gguf: is served)."""
        if self.llm_timeout is not None:
            return self.llm_timeout
        return LOCAL_TIMEOUT if spec is not None and spec.startswith("gguf:") else SERVER_TIMEOUT

    def policy_options(self, spec: str | None = None) -> PolicyOptions:
        """LLMPolicy switches for the ablation (the heuristic policy ignores them), for a robot
        driven by `spec`."""
        return {
            "feedback": self.ablation != "no_feedback",
            "history": self.ablation != "no_history",
            "teammates_absent": tuple(r for r in self.team.names if r not in self.robots),
            "prompts_dir": self.prompts,
            "team": self.team,
            "prompt_cap_chars": self.history_cap,
            "reach_labels": "reach_labels" in self.aids,
            "prompt_hints": "prompt_hints" in self.aids,
            "feedback_advice": "feedback_advice" in self.aids,
            "structured": self.structured,
            "step_deadline": self.step_deadline,
            "max_tokens": self.max_tokens,
        }

    def client_options(self, spec: str | None = None) -> ClientOptions:
        """OpenAIChatClient settings of a robot driven by `spec`."""
        return {
            "timeout": self.timeout_for(spec),
            "idle_timeout": self.llm_idle_timeout or IDLE_TIMEOUT,
            "stream": self.stream,
            "max_tokens": self.max_tokens,
            "seed": self.llm_seed,
        }

    @property
    def fidelity(self) -> str:
        return label(self.aids)


def check_model_servers(cfg: EpisodeConfig, robots: Sequence[str]) -> None:
    """ModelServerDown when nothing listens (connection refused) at the server a robot's model
    spec names: said at once, in one line, instead of every robot retrying into the void. A
    server that does not answer the connection (a slow network, a name that does not resolve)
    is left to the agents' own retries."""
    from urllib.parse import urlsplit

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
