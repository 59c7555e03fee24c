"""What a world service is set up with: its `WorldConfig` (the run, the horizon, the time
policy, how long to wait for robots), the simulator it drives as the service needs it
(`SimLike`; world.sim.Sim provides it), and `NobodyAttached`, the start that fails because no
robot attached within the start timeout. The service itself is service.py.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from mhrc.core.deadlines import TOKEN_DEADLINE
from mhrc.core.protocol import (
    Action,
    FurnitureView,
    Message,
    MotionNoise,
    ObjectPose,
    ObjectView,
    Observation,
    RobotPose,
    SkillOutcome,
)
from mhrc.core.protocol.events import DEFAULT_PROTOCOL
from mhrc.core.team import TeamSpec

from .schedulers import TaskResultLike


class SimLike(Protocol):
    """What the service needs of a simulator (world.sim.Sim provides it)."""

    robots: tuple[str, ...]
    task_id: str
    scene_id: str
    seed: int
    n_objects: int
    aids: frozenset[str]
    noise: MotionNoise
    team: TeamSpec

    def capabilities(self, robot: str) -> frozenset[str]: ...
    def finishers(self) -> frozenset[str]: ...
    def execute(self, robot: str, action: Action) -> SkillOutcome: ...
    def observe(self, robot: str, tick: int) -> Observation: ...
    def tell(self, receiver: str, sender: str, text: str) -> None: ...
    def message(self, receiver: str, sender: str, text: str) -> Callable[[], None]: ...
    def evaluate(self) -> TaskResultLike: ...
    def views(self) -> tuple[list[FurnitureView], list[ObjectView]]: ...
    def poses(self) -> tuple[dict[str, RobotPose], dict[str, ObjectPose], dict[str, bool]]: ...
    def lower_bound(self) -> int: ...
    def answer_key(self) -> tuple[list[str], dict[str, str], bool]: ...
    def fire_events(self, tick: int) -> Sequence[Message]: ...


class NobodyAttached(RuntimeError):
    """No robot attached within the start timeout: the episode cannot start, and waiting longer
    was not asked for."""

    def __init__(self, missing: Sequence[str], timeout: float) -> None:
        self.missing = tuple(missing)
        self.timeout = timeout
        super().__init__(
            f"no robot attached within --start-timeout {timeout:g} s ({', '.join(self.missing)} never attached): "
            "start their agents (mhrc agent --robot ROBOT ...), or give them longer with --start-timeout"
        )


@dataclass
class WorldConfig:
    run: str
    horizon: int = 50
    start_timeout: float | None = (
        None  # start with the robots attached by then (NobodyAttached if none is); None: wait for all
    )
    tick_delay: float = 0.0  # pause between scheduler steps, for watching with --gui
    schedule: str = "lockstep"  # the time policy, a name in world.schedulers.SCHEDULERS
    time_scale: float = 0.0  # async: simulated seconds per wall second, 0 as fast as possible
    token_deadline: float = TOKEN_DEADLINE  # s an attached agent has to show its liveliness token (presence.py)
    protocol: str = DEFAULT_PROTOCOL  # how the team decides (mhrc.agents.protocols): recorded in episode_started only
