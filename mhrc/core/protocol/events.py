"""The world's events on world/event (`kind` discriminates the union) and its state on request."""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import Field, TypeAdapter, ValidationError

from mhrc.core.coordination import DEFAULT_PROTOCOL as DEFAULT_PROTOCOL  # the wire's name for it, too
from mhrc.core.protocol.base import MAX_NAME, Message, ProtocolError, _Model, _reason
from mhrc.core.protocol.observation import FurnitureView, ObjectView

# --------------------------------------------------------------------------- world events


class Metrics(_Model):
    """Per-episode metrics, as the paper defines them (see mhrc.analysis.metrics)."""

    success: bool
    partial_success: float = Field(ge=0.0, le=1.0)
    placed: int
    total: int
    temporal_steps: int
    action_steps: int = Field(description="actions of all robots, `wait` excluded")
    action_steps_per_robot: dict[str, int]
    failed_actions: dict[str, int] = Field(default_factory=dict, description="skill -> failures")
    messages: int = 0
    wall_time: float = 0.0
    sim_time: float = 0.0
    lower_bound: int | None = Field(None, description="a lower bound on TS for this episode (mhrc/world/bound.py)")
    makespan: float = Field(
        0.0, ge=0.0, description="simulated seconds from the start to the end of the episode on the world's clock"
    )


class MotionNoise(_Model):
    """The motion noise a world draws from (mhrc/world/skills: navigation.py, manipulation.py).
    mhrc's calibration, not the paper's: the paper's Table III reports navigation that ends off
    target and placements that fail, but no rates. The defaults are the calibration (`--noise
    on`); `--noise off` and the exact_motion aid draw none (all zero)."""

    setting: Literal["on", "off"] = Field(
        "on", description="`on`: the calibration; `off`: no noise (--noise off, or the exact_motion aid)"
    )
    navigation_slip: float = Field(
        0.03,
        ge=0.0,
        le=1.0,
        description="the chance that a navigate or move slips 0.11-0.3 m off its goal (beyond 0.1 m it fails off target)",
    )
    navigation_sigma: float = Field(
        0.015, ge=0.0, description="m: the Rayleigh scale of an ordinary stop's error (mean 1.9 cm)"
    )
    release_slip: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="the chance that a released object slips 2-4 cm on the suction cup as it is let go",
    )
    release_sigma: float = Field(0.003, ge=0.0, description="m: the Rayleigh scale of an ordinary release's error")


class TeamRecord(_Model):
    """The team an episode ran (mhrc.core.team.TeamSpec), as traces and rows record it."""

    name: str = Field(description="the team's name: a shipped configuration's (mhrc teams), a file's stem, or custom")
    digest: str = Field(description="TeamSpec.digest(): a short hash of the robots' names, kinds and start poses")
    kinds: dict[str, str] = Field(description="robot -> its kind, in execution order")


class EpisodeStarted(Message):
    kind: Literal["episode_started"] = "episode_started"
    run: str
    task: str
    scene: str
    seed: int
    n_objects: int
    robots: list[str]
    horizon: int
    scheduler: Literal["sequential", "lockstep", "async"] = "lockstep"
    time_scale: float | None = Field(
        None, ge=0.0, description="async: simulated seconds per wall second, 0 as fast as possible"
    )
    step_seconds: float | None = Field(
        None,
        gt=0.0,
        description="async: the simulated seconds one step stands for: the horizon is horizon x step_seconds, TS is makespan / step_seconds rounded up",
    )
    lower_bound: int | None = None
    fidelity: str = Field(
        "paper", description="`paper`, or `aids:` and the aids this episode ran with (mhrc.core.fidelity)"
    )
    aids: list[str] = Field(default_factory=list)
    noise: MotionNoise = Field(
        default_factory=MotionNoise,
        description="the motion noise this episode's world drew from (an event without it: the calibration, the defaults)",
    )
    team: TeamRecord | None = Field(
        None,
        description="the team this episode ran (an event without it: the paper's Alice, Bob and David, those of them in `robots`)",
    )
    protocol: str = Field(
        DEFAULT_PROTOCOL,
        max_length=MAX_NAME,
        pattern=r"^[a-z0-9_-]+$",
        description="how the team decided: a coordination protocol's name (mhrc.agents.protocols; an event without it: "
        "the paper's, `mhrc`)",
    )


class TickClosed(Message):
    kind: Literal["tick"] = "tick"
    tick: int = Field(description="the tick whose actions just executed")
    actions: dict[str, str] = Field(description="robot -> action call")
    outcomes: dict[str, bool] = Field(description="robot -> succeeded")
    placed: int
    total: int


class RobotAttached(Message):
    kind: Literal["robot_attached"] = "robot_attached"
    robot: str
    agent_id: str
    tick: int


class RobotDetached(Message):
    kind: Literal["robot_detached"] = "robot_detached"
    robot: str
    tick: int
    reason: str
    agent_id: str | None = None  # the agent let go (None from worlds before it was sent): it may attach again


class EpisodeDone(Message):
    kind: Literal["episode_done"] = "episode_done"
    run: str
    reason: Literal["success", "horizon", "no_agents", "stopped"]
    metrics: Metrics
    final_results: dict[str, str] = Field(
        default_factory=dict,
        description="robot -> goal id of the last result the world published to it: "
        "results travel on other keys, so an agent that sees this event first still waits for that result",
    )
    targets: list[str] = Field(
        default_factory=list,
        description="the task's target objects, in task order: said only once the episode is over (for reports)",
    )
    goals: dict[str, str] = Field(
        default_factory=dict, description="target -> the fixture it had to end on (for reports)"
    )
    ordered: bool = Field(False, description="whether the targets had to reach their goals in order (a sandwich)")


class RobotPose(_Model):
    """Where a robot is: its base (a fixed arm: its arm's base) and what it holds."""

    x: float
    y: float
    yaw: float = 0.0
    holding: str | None = None


class ObjectPose(_Model):
    x: float
    y: float
    z: float
    on: str | None = None
    inside: bool = False
    held_by: str | None = None


class Snapshot(Message):
    """Ground truth after the world executed actions (and once at the start, with no goals):
    every robot's pose, every object's position, every container's state. For viewers and
    videos (mhrc show); agents never see it in their observations."""

    kind: Literal["snapshot"] = "snapshot"
    tick: int = Field(description="the tick the actions were executed at (async: the acting robot's own tick)")
    goals: list[str] = Field(
        default_factory=list,
        description="goal ids of the actions just executed, in order; their results say who did what",
    )
    robots: dict[str, RobotPose]
    objects: dict[str, ObjectPose]
    open: dict[str, bool] = Field(default_factory=dict, description="openable furniture -> open")


class ScenarioEvent(Message):
    """A scenario event fired (`--events`, mhrc/world/scenario.py): what it changed, or why it was
    skipped (its object already in place, nothing open to close). Robots are not told: they
    learn it by looking, or from their teammates."""

    kind: Literal["scenario_event"] = "scenario_event"
    scenario: str = Field(description="the scenario's short name (its file's stem)")
    sha256: str = Field(description="the sha256 of the scenario file's bytes")
    index: int = Field(ge=0, description="the event's index in the scenario file")
    event: Literal["relocate", "breakdown", "new_target", "close"]
    tick: int = Field(description="the tick it fired at (the file's tick)")
    applied: bool
    skipped: str | None = Field(None, description="why it could not apply (None when applied)")
    changed: dict[str, str] = Field(
        default_factory=dict,
        description="what exactly changed, e.g. object, from, to (relocate); robot, until (breakdown); object, on, total (new_target); container (close)",
    )
    text: str = Field("", description="the same in one sentence, for people")


WorldEvent = Annotated[
    Union[EpisodeStarted, TickClosed, RobotAttached, RobotDetached, EpisodeDone, Snapshot, ScenarioEvent],
    Field(discriminator="kind"),
]
WORLD_EVENT_ADAPTER: TypeAdapter[WorldEvent] = TypeAdapter(WorldEvent)


class WorldState(Message):
    """Answer of the `world/state` queryable: a snapshot for late joiners and observers."""

    kind: Literal["world_state"] = "world_state"
    run: str
    task: str
    scene: str
    seed: int
    tick: int
    horizon: int
    started: bool
    done: bool
    attached: dict[str, str] = Field(description="robot -> agent id")
    robots: list[str]
    furniture: list[FurnitureView]
    objects: list[ObjectView]
    placed: int
    total: int


def decode_event(data: bytes | str) -> WorldEvent:
    try:
        return WORLD_EVENT_ADAPTER.validate_json(data)
    except ValidationError as exc:
        raise ProtocolError(_reason(exc)) from None
