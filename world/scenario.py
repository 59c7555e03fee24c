"""A scenario: the events the world applies during an episode (issue 25, dynamic episodes).

A scenario file is a JSON list of events, each with the `tick` it fires at and a `kind`:

    relocate     someone else moves a target that is not yet in place to another surface
                 (optional `object`, `to`; by default chosen with the episode's seed)
    breakdown    `robot` can only communicate and wait for `ticks` ticks
    new_target   one more object joins the task (optional `object`, `on`)
    close        a container closes (optional `target`; by default the one opened last)

A scenario is given as a file path or as the name of one shipped with the package
(`world/scenarios/*.json`, listed by `mhrc scenarios`): `resolve_scenario` finds it, an
existing path first. A name travels as a name (to `mhrc eval`'s workers, to a `--processes`
world), so each process reads the copy installed with its own package.

`load_scenario` checks the file alone (its shape and fields); `check_scenario` checks it against
one episode (horizon, robots, the scene's surfaces, the task's possible objects). Both raise
`ScenarioError`, whose message names the event's index and field, e.g.
`events[2].robot: 'eve' is not a robot of this episode`.
"""

from __future__ import annotations

import hashlib
from collections.abc import Collection
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError


class ScenarioError(ValueError):
    """A scenario file that cannot run: the message names the file's event and field."""


class _Event(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    tick: int = Field(
        ge=1, description="the tick it fires at, when that tick opens (async: at tick x step_seconds of simulated time)"
    )


class Relocate(_Event):
    """Someone else moves a target object that is not yet in place to another surface; robots
    learn it only by looking."""

    kind: Literal["relocate"] = "relocate"
    object: str | None = Field(
        None, description="the target to move; None: one chosen with the episode's seed among the unplaced targets"
    )
    to: str | None = Field(None, description="the furniture to put it on; None: one chosen with the episode's seed")


class Breakdown(_Event):
    """`robot` loses every skill but communicate and wait for `ticks` ticks."""

    kind: Literal["breakdown"] = "breakdown"
    robot: str
    ticks: int = Field(ge=1)


class NewTarget(_Event):
    """One more object joins the task, spawned on a surface."""

    kind: Literal["new_target"] = "new_target"
    object: str | None = Field(
        None,
        description="the object to add; None: one chosen with the episode's seed among the task's objects not in the scene",
    )
    on: str | None = Field(None, description="the furniture it appears on; None: one chosen with the episode's seed")


class Close(_Event):
    """A container closes, hiding what is inside again."""

    kind: Literal["close"] = "close"
    target: str | None = Field(None, description="the container; None: the one opened most recently")


ScenarioEventSpec = Annotated[Union[Relocate, Breakdown, NewTarget, Close], Field(discriminator="kind")]
_EVENTS: TypeAdapter[list[ScenarioEventSpec]] = TypeAdapter(list[ScenarioEventSpec])
KINDS = ("relocate", "breakdown", "new_target", "close")


class Scenario(BaseModel):
    """The events of one scenario file, in file order, with the file's sha256 and short name (its stem)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str
    sha256: str
    events: list[ScenarioEventSpec]
    source: str = Field("", description="the file as it was given (for messages)")


def shipped_scenarios() -> dict[str, Path]:
    """The scenarios shipped with the package, by name (the file's stem), in name order."""
    folder = Path(str(resources.files("mhrc.world").joinpath("scenarios")))
    return {p.stem: p for p in sorted(folder.glob("*.json"))}


def resolve_scenario(arg: Path | str) -> Path:
    """The file `--events ARG` means: ARG itself when it is a file, else the shipped scenario named
    ARG; else ScenarioError naming the shipped ones (so a typo is refused before anything starts)."""
    path = Path(arg)
    if path.is_file():
        return path
    shipped = shipped_scenarios()
    if str(arg) in shipped:
        return shipped[str(arg)]
    if path.exists():
        raise ScenarioError(
            f"--events: {arg} is a directory; give a scenario file (a JSON list of events) or a shipped scenario's name"
        )
    raise ScenarioError(
        f"--events: {arg} is neither a file nor a shipped scenario; give a scenario file's path or one of "
        f"{', '.join(shipped) or '(none installed)'} (mhrc scenarios lists them)"
    )


def load_scenario(path: Path | str) -> Scenario:
    """Read and validate a scenario given by path or shipped name (its shape only: `check_scenario`
    checks it against an episode)."""
    source = str(path)
    path = resolve_scenario(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(f"--events: cannot read {path}: {exc.strerror or exc}") from None
    try:
        events = _EVENTS.validate_json(data)
    except ValidationError as exc:
        raise ScenarioError(f"--events {source}: {_where(exc)}") from None
    return Scenario(name=path.stem, sha256=hashlib.sha256(data).hexdigest(), events=events, source=source)


def _where(exc: ValidationError) -> str:
    """The first error as `events[i].field: what is wrong` (the union's kind tag left out of the path)."""
    err = exc.errors()[0]
    loc = list(err["loc"])
    msg = err["msg"].removeprefix("Value error, ")
    if not loc:
        return f"a scenario is a JSON list of events ({msg})"
    index, rest = loc[0], [str(p) for p in loc[1:] if str(p) not in KINDS]
    if err["type"] == "union_tag_invalid" or (err["type"] == "union_tag_not_found" and not rest):
        rest = ["kind"]
        msg = f"must be one of {', '.join(KINDS)}" + (
            f", not {err['input'].get('kind')!r}"
            if isinstance(err.get("input"), dict) and "kind" in err["input"]
            else ""
        )
    field = ".".join(rest) or "event"
    return f"events[{index}].{field}: {msg}"


def describe(event: ScenarioEventSpec) -> str:
    """What one event does, in a sentence (for `mhrc scenarios NAME` and the docs)."""
    if isinstance(event, Relocate):
        what = event.object or "a target not yet in place (chosen with the episode's seed)"
        where = event.to or "another surface (chosen with the seed)"
        return f"someone moves {what} to {where}; robots learn it only by looking"
    if isinstance(event, Breakdown):
        return (
            f"{event.robot} breaks down for {event.ticks} tick(s), until tick {event.tick + event.ticks}: it can only "
            "communicate and wait; teammates learn it only from its messages"
        )
    if isinstance(event, NewTarget):
        what = event.object or "one more object (chosen with the seed among the task's objects not in the scene)"
        on = event.on or "a surface chosen with the seed"
        return f"{what} joins the task, on {on}; Bob's task changes, the others learn it from him"
    target = event.target or "the container opened most recently"
    return f"{target} closes, hiding what is inside again (skipped when nothing is open)"


@dataclass(frozen=True)
class EpisodeFacts:
    """What `check_scenario` needs of an episode, all known without building it."""

    horizon: int
    robots: tuple[str, ...]
    surfaces: frozenset[str]  # furniture objects can be put on (relocate `to`, new_target `on`)
    containers: frozenset[str]  # furniture that opens and closes
    objects: frozenset[str]  # every object name the task can have


def check_scenario(scenario: Scenario, facts: EpisodeFacts, *, where: str = "") -> None:
    """Raise ScenarioError naming the first event field this episode cannot honour. `where`
    (e.g. "in pack_objects/kitchen") is added to the message for a grid of episodes."""
    suffix = f" {where}" if where else ""

    def bad(i: int, field: str, why: str) -> ScenarioError:
        return ScenarioError(f"--events {scenario.source or scenario.name}: events[{i}].{field}: {why}{suffix}")

    for i, ev in enumerate(scenario.events):
        if ev.tick >= facts.horizon:
            raise bad(
                i, "tick", f"{ev.tick} is past the horizon ({facts.horizon} ticks: the last is {facts.horizon - 1})"
            )
        if isinstance(ev, Breakdown) and ev.robot not in facts.robots:
            raise bad(i, "robot", f"{ev.robot!r} is not a robot of this episode ({', '.join(facts.robots)})")
        if isinstance(ev, (Relocate, NewTarget)) and ev.object is not None and ev.object not in facts.objects:
            raise bad(i, "object", f"{ev.object!r} is not an object this task can have ({_some(facts.objects)})")
        if isinstance(ev, Relocate) and ev.to is not None and ev.to not in facts.surfaces:
            raise bad(i, "to", f"{ev.to!r} is not a surface of this scene ({_some(facts.surfaces)})")
        if isinstance(ev, NewTarget) and ev.on is not None and ev.on not in facts.surfaces:
            raise bad(i, "on", f"{ev.on!r} is not a surface of this scene ({_some(facts.surfaces)})")
        if isinstance(ev, Close) and ev.target is not None and ev.target not in facts.containers:
            raise bad(i, "target", f"{ev.target!r} is not a container of this scene ({_some(facts.containers)})")


def _some(names: Collection[str]) -> str:
    shown = sorted(names)
    return ", ".join(shown[:12]) + (", ..." if len(shown) > 12 else "")
