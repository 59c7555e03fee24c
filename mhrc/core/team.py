"""A team as data: which robots an episode has, of which kinds, in which order (issue 33).

The paper fixes one team, Alice (a mobile manipulator), Bob (a tabletop arm) and David (a mobile
base); `PAPER_TEAM` is that team and the default everywhere. A `TeamSpec` names each robot, its
kind (the world's `RobotKind` ids: `mhrc.world.kinds.KINDS`) and optionally its start pose and
its model (`--llm` spec). The order of `robots` is the execution order of the sequential
schedule (the paper's Algorithm 1). This module checks what can be checked without the world
(names, counts, duplicates, the shape of a file); the world checks the kinds against its robots
and the layout (`mhrc.world.teams.check_team`).

A team comes from `--team`: a shipped configuration's name (`mhrc teams`), a TOML or JSON file
(`[[robots]]` tables with `name`, `kind`, optional `start = [x, y, yaw]` and `llm`; an optional
top-level `name` and `purpose`), or inline, `alice=mobile_manipulator,bob=tabletop_arm,lucy=drone`.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import tomllib
from enum import StrEnum
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from mhrc.core.participants import reserved_why

__all__ = [
    "MAX_COORD",
    "MAX_ROBOTS",
    "MIN_ROBOTS",
    "NAME",
    "PAPER_TEAM",
    "RobotSpec",
    "TeamError",
    "TeamProblem",
    "TeamSpec",
    "checked",
    "from_kinds",
    "load_team_file",
    "parse_inline",
]

NAME = re.compile(r"[a-z][a-z0-9_]{0,31}")  # a robot's name: a key segment, a login, a prompt's word
MIN_ROBOTS, MAX_ROBOTS = 2, 8
MAX_COORD = 1000.0  # m (and rad, for a yaw): far past any layout's walls, and far from a float's overflow


def start_problem(start: object) -> str | None:
    """Why a start pose of three numbers is out of bounds (not finite, or past MAX_COORD), or None;
    its shape is the model's to check. A start past the walls is refused by the world's placement
    ("off the map"); this keeps out what its grid arithmetic cannot take (1e308 overflowed
    converting to a cell)."""
    if not isinstance(start, (list, tuple)):
        return None
    for v in start:
        if isinstance(v, (int, float)) and not isinstance(v, bool) and (not math.isfinite(v) or abs(v) > MAX_COORD):
            return f"{v!r:.40} is not a finite coordinate within {MAX_COORD:g} of the origin"
    return None


class TeamProblem(StrEnum):
    """Why a team was refused (TeamError.code)."""

    BAD_NAME = "bad_name"  # a robot name that is not a lowercase identifier
    BAD_START = "bad_start"  # a start pose that is not three finite numbers within MAX_COORD
    DUPLICATE_NAME = "duplicate_name"
    RESERVED_NAME = "reserved_name"  # a participant's name on the bus other than a robot's (mhrc.core.participants)
    SIZE = "size"  # fewer than MIN_ROBOTS or more than MAX_ROBOTS
    UNKNOWN_KIND = "unknown_kind"
    NO_FINISHER = "no_finisher"  # nobody can place on the goal (no tabletop arm)
    NO_FETCHER = "no_fetcher"  # nobody can bring an object to the finisher (navigate and pick)
    TOO_MANY_ARMS = "too_many_arms"  # more fixed arms than the layout has arm mounts
    NO_ROOM = "no_room"  # more mobile robots than the layout can place
    BAD_FILE = "bad_file"  # a team file that cannot be read or does not hold a team
    UNKNOWN_TEAM = "unknown_team"  # neither a shipped team, nor a file, nor inline robots


class TeamError(ValueError):
    """A team that cannot run: `code` says why, the message names the robot or field."""

    def __init__(self, code: TeamProblem, message: str) -> None:
        super().__init__(message)
        self.code = code


class RobotSpec(BaseModel):
    """One robot of a team: its name, its kind, where it starts (x, y, yaw; by default the
    layout's pose for that name, else one chosen from the seed) and its model (an `--llm` spec)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field(description="a lowercase identifier: a-z first, then a-z, 0-9 or _, at most 32 characters")
    kind: str = Field(description="a robot kind (mhrc teams --kinds)")
    start: tuple[float, float, float] | None = Field(None, description="start pose x, y (m), yaw (rad)")
    llm: str | None = Field(None, description="this robot's model, an --llm spec")

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not NAME.fullmatch(v):
            raise ValueError(
                f"robot name {v!r} is not a lowercase identifier (a-z first, then a-z, 0-9 or _, at most 32 characters)"
            )
        return v

    @field_validator("start")
    @classmethod
    def _start(cls, v: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        if v is not None and (problem := start_problem(v)) is not None:
            raise ValueError(f"start: {problem}")
        return v


class TeamSpec(BaseModel):
    """A team: its name (a shipped configuration's, a file's stem, or `custom`), a one-line
    purpose, and its robots in execution order."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = "custom"
    purpose: str = ""
    robots: tuple[RobotSpec, ...]

    @model_validator(mode="after")
    def _size_and_names(self) -> TeamSpec:
        n = len(self.robots)
        if not MIN_ROBOTS <= n <= MAX_ROBOTS:
            raise ValueError(f"a team has {MIN_ROBOTS} to {MAX_ROBOTS} robots, not {n}")
        seen: set[str] = set()
        for r in self.robots:
            if r.name in seen:
                raise ValueError(f"robot name {r.name!r} appears twice")
            seen.add(r.name)
        return self

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.robots)

    @property
    def kinds(self) -> dict[str, str]:
        """Each robot's kind, by name, in execution order."""
        return {r.name: r.kind for r in self.robots}

    def robot(self, name: str) -> RobotSpec:
        for r in self.robots:
            if r.name == name:
                return r
        raise KeyError(name)

    def digest(self) -> str:
        """A short hash of what the team is (names, kinds, starts, in order; not its name or
        purpose, nor the models): two rows with the same digest ran the same team."""
        body = [[r.name, r.kind, list(r.start) if r.start else None] for r in self.robots]
        return hashlib.sha256(json.dumps(body, separators=(",", ":")).encode()).hexdigest()[:12]

    def without(self, names: set[str]) -> TeamSpec:
        """The team less the robots named (an ablation), under the same name."""
        return self.model_copy(update={"robots": tuple(r for r in self.robots if r.name not in names)})


def checked(data: dict[str, object], where: str) -> TeamSpec:
    """Build a TeamSpec from `data`, refusing with one TeamError line (and its code) what this
    module can check: the robots' count, names and duplicates, then the shape of each field."""
    robots = data.get("robots")
    if not isinstance(robots, list) or not all(isinstance(r, dict) for r in robots):
        raise TeamError(TeamProblem.BAD_FILE, f"{where}: robots must be a list of tables with a name and a kind")
    if not MIN_ROBOTS <= len(robots) <= MAX_ROBOTS:
        raise TeamError(TeamProblem.SIZE, f"{where}: a team has {MIN_ROBOTS} to {MAX_ROBOTS} robots, not {len(robots)}")
    seen: set[object] = set()
    for i, r in enumerate(robots):
        name = r.get("name")
        if not isinstance(name, str) or not NAME.fullmatch(name):
            raise TeamError(
                TeamProblem.BAD_NAME,
                f"{where}: robots.{i}.name: {name!r} is not a lowercase identifier "
                "(a-z first, then a-z, 0-9 or _, at most 32 characters)",
            )
        if (why := reserved_why(name)) is not None:
            raise TeamError(TeamProblem.RESERVED_NAME, f"{where}: robots.{i}.name: no robot may be called that: {why}")
        if name in seen:
            raise TeamError(TeamProblem.DUPLICATE_NAME, f"{where}: robots.{i}.name: {name!r} appears twice")
        seen.add(name)
        if r.get("start") is not None and (problem := start_problem(r["start"])) is not None:
            raise TeamError(TeamProblem.BAD_START, f"{where}: robots.{i}.start: {problem}")
    try:
        return TeamSpec.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err["loc"])
        raise TeamError(TeamProblem.BAD_FILE, f"{where}: {loc}: {err['msg']}") from None


def parse_inline(text: str) -> TeamSpec:
    """`alice=mobile_manipulator,bob=tabletop_arm`: robots in order, each name=kind."""
    robots = []
    for part in (p.strip() for p in text.split(",")):
        name, sep, kind = part.partition("=")
        if not sep or not name.strip() or not kind.strip():
            raise TeamError(TeamProblem.UNKNOWN_TEAM, f"--team: {part!r} is not name=kind")
        robots.append({"name": name.strip(), "kind": kind.strip()})
    return checked({"name": "custom", "robots": robots}, "--team")


def load_team_file(path: Path) -> TeamSpec:
    """A team from a TOML or JSON file (see the module's docstring); named after the file unless
    it names itself."""
    try:
        text = path.read_text(encoding="utf-8")
        data = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise TeamError(TeamProblem.BAD_FILE, f"--team {path}: {str(exc)[:200]}") from None
    except RecursionError:  # the JSON and TOML parsers recurse into nested arrays and tables
        raise TeamError(TeamProblem.BAD_FILE, f"--team {path}: nested too deeply to be a team file") from None
    if not isinstance(data, dict):
        raise TeamError(TeamProblem.BAD_FILE, f"--team {path}: not a table with robots")
    return checked({"name": path.stem, **data}, f"--team {path}")


PAPER_TEAM = TeamSpec(
    name="paper",
    purpose="the paper's team: Alice fetches, Bob finishes at his table, David scouts",
    robots=(
        RobotSpec(name="alice", kind="mobile_manipulator"),
        RobotSpec(name="bob", kind="tabletop_arm"),
        RobotSpec(name="david", kind="mobile_base"),
    ),
)


def from_kinds(name: str, kinds: dict[str, str]) -> TeamSpec:
    """The team a trace records (its name and each robot's kind, in order; mhrc.core.protocol
    TeamRecord), as a TeamSpec without start poses or models: enough to build its world again."""
    if name == PAPER_TEAM.name and kinds == PAPER_TEAM.kinds:
        return PAPER_TEAM
    return TeamSpec(name=name, robots=tuple(RobotSpec(name=n, kind=k) for n, k in kinds.items()))
