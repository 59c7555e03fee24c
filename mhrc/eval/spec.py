"""What an evaluation runs, validated once: `EvalSpec` (the grid and how each episode is driven,
as the CLI or a caller gives it), its `EvalIdentity` (what `--resume` must find unchanged) and
the `Plan` that `EvalSpec.validate` returns, every episode's `EpisodeConfig` already built.

The spec is checked in one place (`validate`): each cell of the grid (team, task, scene, object
count) is built once with `EpisodeConfig.build`, the full check (the team against the world's
kinds and the scene's layout, task, scene, scenario, model specs, prompt templates, the protocol
seating the team); the episodes of a cell differ only in their seed. The team is an axis of the
grid like the task and the scene: the paper's team (the default) keys its episodes
`task/scene/objects/seed` as always, any other team `TEAM/task/scene/objects/seed`. So is the
coordination protocol (--protocol): the paper's, `mhrc` (the default), adds nothing to a key, any
other `@PROTOCOL/` before the rest (`@centralized/two_fetchers/pack_objects/kitchen/3/0`; `@`
is no character of a team's name, so no key is two episodes'). Workers receive
those configs inside their `Job` and run them as they are.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, field_validator

from mhrc.agents.llm import DEFAULT_MAX_TOKENS
from mhrc.analysis.values import MAX_COUNT
from mhrc.core.aids import label
from mhrc.core.coordination import DEFAULT_PROTOCOL
from mhrc.core.team import PAPER_TEAM, TeamSpec
from mhrc.eval.jobs import Job
from mhrc.eval.paper import PAPER_OBJECTS
from mhrc.run.config import ConfigError, EpisodeConfig, ProtocolConfigError
from mhrc.world.scenario import load_scenario

__all__ = [
    "EvalIdentity",
    "EvalSpec",
    "Plan",
    "bounded",
    "episode_key",
    "identity_difference",
    "is_paper_team",
    "team_identity",
]

TEAM_KEY = re.compile(r"[A-Za-z0-9_-]{1,64}")  # a team's name as the first part of its episodes' keys
MAX_EPISODES = 1_000_000  # the largest grid an evaluation directory's manifest may describe
Horizon = Annotated[int, Field(strict=True, ge=1, le=MAX_COUNT)]
Bounded = Annotated[int, Field(strict=True, ge=-MAX_COUNT, le=MAX_COUNT)]
Scale = Annotated[float, Field(strict=True, ge=0.0, allow_inf_nan=False)]


def episode_key(
    team: str | None, task: str, scene: str, n_objects: int, seed: int, protocol: str = DEFAULT_PROTOCOL
) -> str:
    """An episode's key: `task/scene/objects/seed`, after `TEAM/` for any team but the paper's (None),
    after `@PROTOCOL/` for any coordination protocol but the paper's."""
    head = "" if protocol == DEFAULT_PROTOCOL else f"@{protocol}/"
    return head + ("" if team is None else f"{team}/") + f"{task}/{scene}/{n_objects}/{seed}"


def is_paper_team(team: TeamSpec) -> bool:
    """The paper's Alice, Bob and David, under the paper's name (its episodes keep their keys)."""
    return team.name == PAPER_TEAM.name and team.digest() == PAPER_TEAM.digest()


def team_identity(team: TeamSpec) -> str:
    """What --resume compares of a team: NAME@DIGEST, and the models a team file gives its robots."""
    models = ", ".join(f"{r.name}={r.llm}" for r in team.robots if r.llm)
    return f"{team.name}@{team.digest()}" + (f" ({models})" if models else "")


class EvalIdentity(BaseModel):
    """What must match for --resume to continue a run: everything that changes the numbers (the
    grid may grow: more trials, repeats, object counts, scenes or tasks). A field's default is
    what a manifest written before the field existed ran with."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    method: str
    ablation: str
    horizon: Horizon
    fidelity: str = "paper"
    noise: str = "on"
    history_cap: Bounded | None = None
    prompts: str | None = None
    mode: str = "free"
    max_tokens: Bounded | None = None
    llm_seed: Bounded | None = None
    schedule: str = "lockstep"
    time_scale: Scale = 0.0
    scenario: str | None = None  # the scenario file's sha256
    teams: tuple[str, ...] = (team_identity(PAPER_TEAM),)  # team_identity of each team, sorted
    protocols: tuple[str, ...] = (DEFAULT_PROTOCOL,)  # the coordination protocols of the grid, sorted

    @field_validator("protocols")
    @classmethod
    def _protocols(cls, v: tuple[str, ...]) -> tuple[str, ...]:
        """Registered protocols only: a manifest naming another is no manifest of an evaluation."""
        from mhrc.agents.protocols import PROTOCOLS

        if unknown := [p for p in v if p not in PROTOCOLS]:
            raise ValueError(f"unknown protocol {unknown[0]!r} (the protocols: {', '.join(PROTOCOLS)})")
        return v


# the option each identity field comes from, where its name is not the field's
IDENTITY_OPTIONS = {
    "method": "--llm",
    "fidelity": "--aids",
    "mode": "--structured",
    "scenario": "--events",
    "teams": "--team",
    "protocols": "--protocol",
}


def identity_difference(before: EvalIdentity, now: EvalIdentity) -> str:
    """What differs between two identities, for a person: each field as its option, with both values."""
    was, new = before.model_dump(), now.model_dump()
    return "; ".join(
        f"{IDENTITY_OPTIONS.get(k, '--' + k.replace('_', '-'))} was {was[k]!r}, now {new[k]!r}"
        for k in was
        if was[k] != new[k]
    )


class EvalSpec(BaseModel):
    """What an evaluation runs: the grid and how each episode is driven. Values are checked by
    `validate`, which names the option, not by the model (a bad value is a usage error)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    tasks: tuple[str, ...]
    scenes: tuple[str, ...]
    objects: tuple[int, ...] = PAPER_OBJECTS
    trials: int = 1  # episodes per (task, scene, object count) in each repeat
    llm: str | None = None
    ablation: str = "none"
    horizon: int = 50
    base_url: str | None = None
    llm_timeout: float | None = None  # None: per spec (mhrc.run.config.EpisodeConfig.timeout_for)
    llm_idle_timeout: float | None = None  # None: mhrc.run.config.IDLE_TIMEOUT
    stream: bool = True  # False: --no-stream
    prompts: str | None = None
    repeats: int = 1  # the grid, run this many times with other seeds
    aids: tuple[str, ...] = ()  # mhrc.core.fidelity names; () is the paper's fidelity
    noise: str = "on"  # the world's motion noise (mhrc.core.fidelity.NOISE): on, the calibration, or off
    history_cap: int | None = None
    max_tokens: int = DEFAULT_MAX_TOKENS
    llm_seed: int | None = None
    structured: bool = False  # JSON decisions (not the paper's free text)
    step_deadline: float | None = None
    schedule: str = "sequential"  # the world's time policy (mhrc.world.schedules); the paper's loop by default
    time_scale: float = 0.0  # async: simulated seconds per wall second, 0 as fast as possible
    # a scenario (world/scenario.py), applied to every episode: a file's path, or a shipped scenario's name, which
    # travels to the workers as the name so that each (a Ray node too) reads the copy installed with its own package
    events: str | None = None
    teams: tuple[TeamSpec, ...] = (PAPER_TEAM,)  # a grid axis (--team, repeatable); the paper's team by default
    # a grid axis (--protocol, repeatable): how each team decides (mhrc.agents.protocols); the paper's by default
    protocols: tuple[str, ...] = (DEFAULT_PROTOCOL,)

    def scenario(self) -> tuple[str, str] | tuple[None, None]:
        """The scenario's short name and sha256 (None, None without one): what rows record of it."""
        if self.events is None:
            return None, None
        sc = load_scenario(self.events)
        return sc.name, sc.sha256

    @property
    def mode(self) -> str:
        """How the model answers: free (the paper's text) or structured (JSON Schema)."""
        return "structured" if self.structured else "free"

    @property
    def method(self) -> str:
        return self.llm or "heuristic"

    @property
    def fidelity(self) -> str:
        return label(self.aids)

    def identity(self, scenario_sha256: str | None = None) -> EvalIdentity:
        """This spec's identity; `scenario_sha256` when the caller has read the scenario already."""
        return EvalIdentity(
            method=self.method,
            ablation=self.ablation,
            horizon=self.horizon,
            fidelity=self.fidelity,
            noise=self.noise,
            history_cap=self.history_cap,
            prompts=self.prompts,
            mode=self.mode,
            max_tokens=self.max_tokens if self.llm else None,
            llm_seed=self.llm_seed,
            schedule=self.schedule,
            time_scale=self.time_scale,
            scenario=scenario_sha256 if scenario_sha256 is not None else self.scenario()[1],
            teams=tuple(sorted(team_identity(t) for t in self.teams)),
            protocols=tuple(sorted(self.protocols)),
        )

    def seed(self, repeat: int, trial: int) -> int:
        """The episode seed of a trial in a repeat: distinct for every (repeat, trial)."""
        return repeat * self.trials + trial

    def episode_values(
        self,
        task: str,
        scene: str,
        n_objects: int,
        team: TeamSpec = PAPER_TEAM,
        protocol: str = DEFAULT_PROTOCOL,
    ) -> dict[str, object]:
        """The EpisodeConfig fields of a cell of the grid (seed 0; no run, port or trace: the process that runs it picks those)."""
        cfg: dict[str, object] = {
            "team": None if team == PAPER_TEAM else team,
            "protocol": None if protocol == DEFAULT_PROTOCOL else protocol,
            "task": task,
            "scene": scene,
            "seed": 0,
            "n_objects": n_objects,
            "horizon": self.horizon,
            "llm": self.llm,
            "ablation": self.ablation,
            "base_url": self.base_url,
            "llm_timeout": self.llm_timeout,
            "prompts": self.prompts,
            "llm_idle_timeout": self.llm_idle_timeout,
            "stream": None if self.stream else False,
            "aids": list(self.aids) or None,
            "noise": None if self.noise == "on" else self.noise,
            "history_cap": self.history_cap,
            "max_tokens": self.max_tokens,
            "llm_seed": self.llm_seed,
            "structured": self.structured or None,
            "step_deadline": self.step_deadline,
            "schedule": self.schedule,
            "time_scale": self.time_scale or None,
            "events": self.events,
        }
        return {k: v for k, v in cfg.items() if v is not None}

    def validate(self) -> Plan:  # type: ignore[override]  # pydantic's deprecated classmethod of the same name
        """The plan of this spec, or ConfigError naming the option: every cell of the grid must be
        a valid episode. The one place the grid is checked."""
        if self.repeats < 1:
            raise ConfigError(f"--repeats: must be at least 1 (got {self.repeats})")
        if self.trials < 1:
            raise ConfigError(f"--trials: must be at least 1 (got {self.trials})")
        if not (self.tasks and self.scenes and self.objects and self.teams):
            raise ConfigError("--tasks, --scenes, --objects and --team must each name at least one value")
        if not self.protocols:
            raise ConfigError("--protocol must name at least one protocol")
        self._check_teams()
        self._check_protocols()
        from mhrc.run.coordinated import check_seating

        cells: dict[tuple[str, str, str, str, int], EpisodeConfig] = {}
        for protocol in self.protocols:
            for team in self.teams:
                for task in self.tasks:
                    for scene in self.scenes:
                        for n in self.objects:
                            if (protocol, team.name, task, scene, n) in cells:
                                continue
                            try:
                                cfg = EpisodeConfig.build(**self.episode_values(task, scene, n, team, protocol))
                                check_seating(cfg, cfg.robots)  # the episode's agents all run in its worker
                            except ProtocolConfigError as exc:  # which team the protocol refused, and why (code)
                                raise ProtocolConfigError(f"{exc} (team {team.name})", exc.code) from None
                            except ConfigError as exc:
                                # a scenario is checked against every task and scene of the grid: say which
                                raise ConfigError(f"{exc} (in {task}/{scene})" if self.events else str(exc)) from None
                            cells[(protocol, team.name, task, scene, n)] = cfg
        scenario, sha256 = self.scenario()
        return Plan(
            spec=self,
            jobs=tuple(self._jobs(cells)),
            scenario=scenario,
            scenario_sha256=sha256,
            identity=self.identity(sha256 or None),
        )

    def _check_teams(self) -> None:
        """Each team's name keys its episodes: a name fit for a key, and no two teams of one name."""
        seen: set[str] = set()
        for team in self.teams:
            if not TEAM_KEY.fullmatch(team.name):
                raise ConfigError(
                    f"--team: a team's name keys its episodes: {team.name!r} must be letters, digits, _ or - "
                    "(rename the file, or give the team a name)"
                )
            if team.name in seen:
                raise ConfigError(
                    f"--team: two teams are named {team.name!r}; each team of the grid needs its own name"
                )
            if team.name == PAPER_TEAM.name and not is_paper_team(team):
                raise ConfigError(
                    f"--team: a team named {PAPER_TEAM.name!r} must be the paper's Alice, Bob and David; name yours otherwise"
                )
            seen.add(team.name)

    def _check_protocols(self) -> None:
        """Each protocol a registered one's name (it keys its episodes), once."""
        from mhrc.agents.protocols import PROTOCOLS

        seen: set[str] = set()
        for protocol in self.protocols:
            if protocol not in PROTOCOLS:
                raise ConfigError(
                    f"--protocol: unknown protocol {protocol!r}: the protocols are {', '.join(PROTOCOLS)}"
                )
            if protocol in seen:
                raise ConfigError(f"--protocol: {protocol!r} is given twice")
            seen.add(protocol)

    def _jobs(self, cells: dict[tuple[str, str, str, str, int], EpisodeConfig]) -> list[Job]:
        """Repeat by repeat (a finished repeat is a whole grid), then protocol, team, task, scene, objects, trial."""
        out = []
        for repeat in range(self.repeats):
            for protocol in self.protocols:
                for team in self.teams:
                    prefix = "" if is_paper_team(team) else team.name
                    for task in self.tasks:
                        for scene in self.scenes:
                            for n in self.objects:
                                for trial in range(self.trials):
                                    seed = self.seed(repeat, trial)
                                    cell = cells[(protocol, team.name, task, scene, n)]
                                    config = cell.model_copy(update={"seed": seed})
                                    key = episode_key(prefix or None, task, scene, n, seed, protocol)
                                    out.append(Job(key=key, config=config, repeat=repeat, trial=trial))
        return out

    def keys(self) -> frozenset[str]:
        """The key of every episode of the grid, without building a config (what rows may hold)."""
        return frozenset(
            episode_key(None if is_paper_team(team) else team.name, task, scene, n, self.seed(repeat, trial), protocol)
            for repeat in range(self.repeats)
            for protocol in self.protocols
            for team in self.teams
            for task in self.tasks
            for scene in self.scenes
            for n in self.objects
            for trial in range(self.trials)
        )

    def jobs(self) -> list[Job]:
        """Every episode of the grid (validates the spec: use `validate().jobs` to keep the plan)."""
        return list(self.validate().jobs)


def bounded(spec: EvalSpec) -> str | None:
    """What of a spec read from a file lies outside the range an evaluation may hold (None: nothing):
    a grid of 10^30 repeats is no grid."""
    for name in ("horizon", "trials", "repeats"):
        if not 1 <= getattr(spec, name) <= MAX_COUNT:
            return f"{name}: {getattr(spec, name)} is outside 1..{MAX_COUNT}"
    if not all(0 <= n <= MAX_COUNT for n in spec.objects):
        return f"objects: {list(spec.objects)} holds a count outside 0..{MAX_COUNT}"
    size = (
        spec.repeats
        * spec.trials
        * len(spec.protocols)
        * len(spec.teams)
        * len(spec.tasks)
        * len(spec.scenes)
        * len(spec.objects)
    )
    if size > MAX_EPISODES:
        return f"a grid of {size} episodes (more than {MAX_EPISODES})"
    for name in ("history_cap", "max_tokens", "llm_seed"):
        value = getattr(spec, name)
        if value is not None and abs(value) > MAX_COUNT:
            return f"{name}: {value} is outside the range of a count"
    return None


@dataclass(frozen=True)
class Plan:
    """A validated evaluation: its spec, every episode's job (config built and checked), the
    scenario every row records and the identity --resume checks."""

    spec: EvalSpec
    jobs: tuple[Job, ...]
    scenario: str | None
    scenario_sha256: str | None
    identity: EvalIdentity


@dataclass(frozen=True)
class RunOptions:
    """Where and how many episodes run at once, checked once, when made (ConfigError naming the option)."""

    workers: int | None = (
        None  # local worker processes; None: the number of cores (not with `ray`: its resources decide)
    )
    concurrency: int | None = (
        None  # episodes each worker runs at once (Ray: an LLM episode takes 1/concurrency of a CPU); None: 1
    )
    ray: str | None = None  # a Ray cluster's address, as ray.init takes it
    shared_out: bool = False  # with `ray`: --out is the same path on every node

    def __post_init__(self) -> None:
        if self.ray is not None and self.workers is not None:
            raise ConfigError(
                "--workers: not with --ray (the Ray cluster's resources say how many episodes run at once)"
            )
        if self.shared_out and self.ray is None:
            raise ConfigError("--shared-out: only with --ray (a local run writes into --out anyway)")
        if self.workers is not None and self.workers < 1:
            raise ConfigError(f"--workers: must be at least 1 (got {self.workers})")
        if self.concurrency is not None and self.concurrency < 1:
            raise ConfigError(f"--concurrency: must be at least 1 (got {self.concurrency})")

    @property
    def processes(self) -> int:
        """Local worker processes."""
        return self.workers or os.cpu_count() or 1
